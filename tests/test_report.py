"""``workbench report`` and the page ``workbench run`` writes (issue 11, reports out).

A small fake results folder (a matplotlib PNG, JSON figures, a text table,
summary.json, the scenario's copy) is read back from the page with the standard
library's HTML parser: every figure and every table is there, every ``<img>`` is
a valid PNG. A real browser (headless Chromium) loads the page when it is
installed; CI does not install it, so that test is skipped there.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from workbench.cli.main import main
from workbench.report import PACKAGES, PNG_SIGNATURE, write_report

SCENARIO_TEXT = '[scenario]\nname = "fake"\nseed = 42  # a < b & "c"\n\n[plant]\nname = "beam"\n'

SUMMARY = {
    "plant": {"name": "beam", "fs_hz": 2048.0, "n_u": 3, "n_y": 5},
    "frf": {"method": "multisine", "n_lines": 57, "band_hz": [20.0, 604.0]},
    "modes": {"text": " mode  freq (Hz)\n    1     35.03\n    2    115.23"},
    "scenario": {
        "name": "fake",
        "seed": 42,
        "file": "/nonexistent/fake.toml",
        "description": "a fake run <for> the report",
        "stage_seconds": {"plant": 0.5, "frf": 1.25},
    },
}
MODES = {
    "modes": [
        {"kind": "flexible", "freq_hz": 35.03, "damping": 0.005},
        {"kind": "flexible", "freq_hz": 115.23, "damping": 0.006},
    ],
    "note": "<script>alert(1)</script>",
}
FINDINGS = {
    "error_before": 0.83,
    "findings": [{"effect": "missing_mode", "matrix": [[1, 2], [3, 4]]}],
}
TABLE_TXT = (
    " mode  kind       freq (Hz)\n    1  rigid           0.00\n    2  flexible      913.80\n"
)


def _png(path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3, 2), dpi=50)
    ax.semilogy([1, 2, 3], [1, 10, 100])
    ax.set_title(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


@pytest.fixture
def folder(tmp_path) -> Path:
    """A results folder as ``workbench run`` leaves it (report.html aside)."""
    out = tmp_path / "results"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps(SUMMARY, indent=2))
    (out / "modes.json").write_text(json.dumps(MODES))
    (out / "compare_before").mkdir()
    (out / "compare_before" / "findings.json").write_text(json.dumps(FINDINGS))
    (out / "minimality.txt").write_text(TABLE_TXT)
    (out / "scenario.toml").write_text(SCENARIO_TEXT)
    (out / "frf.npz").write_bytes(b"PK\x03\x04 not read, only listed")
    _png(out / "frf_measured.png", "measured FRF")
    _png(out / "compare_before" / "error_map.png", "error map")
    return out


class _Page(HTMLParser):
    """The parts of the page the tests check: images, tables, preformatted blocks, tags."""

    def __init__(self):
        super().__init__()
        self.images: list[dict] = []
        self.sources: dict[str, list[str]] = {}  # data-source -> tags carrying it
        self.ids: set[str] = set()
        self.starts: list[str] = []
        self.depth: dict[str, int] = {}
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.starts.append(tag)
        if tag in ("table", "details", "figure", "pre", "section"):
            self.depth[tag] = self.depth.get(tag, 0) + 1
        if tag == "img":
            self.images.append(a)
        if "data-source" in a:
            self.sources.setdefault(a["data-source"], []).append(tag)
        if "id" in a:
            self.ids.add(a["id"])

    def handle_endtag(self, tag):
        if tag in self.depth:
            self.depth[tag] -= 1

    def handle_data(self, data):
        self.text.append(data)


def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    page.close()
    return page


def _digests(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_every_figure_and_table_is_on_the_page(folder, capsys):
    from PIL import Image

    (folder / "report.png").write_bytes((folder / "frf_measured.png").read_bytes())  # screenshot
    assert main(["report", str(folder), "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == f"wrote {folder / 'report.html'} (2 figures, 4 tables)" and err == ""
    page = _parse(folder / "report.html")
    assert all(v == 0 for v in page.depth.values()), page.depth  # every block closed

    # figures: every PNG of the folder (subfolders too), never the page's own screenshot
    assert sorted(i["data-source"] for i in page.images) == [
        "compare_before/error_map.png",
        "frf_measured.png",
    ]
    for img in page.images:
        head, b64 = img["src"].split(",", 1)
        assert head == "data:image/png;base64"
        data = base64.b64decode(b64, validate=True)
        assert data.startswith(PNG_SIGNATURE)
        assert data == (folder / img["data-source"]).read_bytes()
        with Image.open(io.BytesIO(data)) as im:
            im.verify()
        with Image.open(io.BytesIO(data)) as im:
            im.load()
            assert im.format == "PNG" and im.size == (150, 100)

    # tables: every JSON file as a table, every text table as preformatted text
    for name in ("summary.json", "modes.json", "compare_before/findings.json"):
        assert page.sources.get(name) == ["table"], name
    assert page.sources.get("minimality.txt") == ["pre"]
    text = "".join(page.text)
    assert TABLE_TXT.rstrip() in text
    assert "missing_mode" in text and "115.23" in text and "0.006" in text  # records, matrix
    assert "<script>alert(1)</script>" in text and "script" not in page.starts  # escaped

    # the scenario file, seed, timings, versions, the digest, the file list
    assert SCENARIO_TEXT in text
    assert {"seed", "timings-table", "versions-table", "digest", "files-table"} <= page.ids
    assert "a fake run <for> the report" in text
    assert "1.25" in text and "1.75" in text  # the frf stage's seconds and the total
    for label, _ in PACKAGES:
        assert label in text
    assert "the environment that built this page" in text  # no versions.toml in this folder
    assert "frf.npz" in text


def test_the_runs_versions_and_a_broken_png(folder):
    (folder / "versions.toml").write_text('[versions]\nnumpy = "9.9.9"\nworkbench = "0.0.1"\n')
    (folder / "broken.png").write_bytes(b"not a png")
    done = write_report(folder)
    page = _parse(done["path"])
    text = "".join(page.text)
    assert "9.9.9" in text and "of the run (versions.toml)" in text
    assert "broken.png: not a PNG file, not shown" in text
    assert len(page.images) == 2 and done["figures"] == 3


@pytest.mark.parametrize("kind", ["empty", "missing", "file", "not_summary"])
def test_a_folder_that_is_not_a_results_folder_is_refused(tmp_path, capsys, kind):
    target = tmp_path / "x"
    if kind == "empty":
        target.mkdir()
    elif kind == "file":
        target.write_text("hello")
    elif kind == "not_summary":
        target.mkdir()
        (target / "summary.json").write_text("[1, 2]")
    assert main(["report", str(target)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: "), err
    assert str(target) in err
    assert not any(p.suffix == ".html" for p in tmp_path.rglob("*"))


def test_the_report_never_overwrites_an_input(folder, capsys):
    before = _digests(folder)
    for name in ("summary.json", "frf_measured.png", "minimality.txt", "scenario.toml", "frf.npz"):
        assert main(["report", str(folder), "--out", str(folder / name), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "refusing to write the output over an input file" in err
        assert len(err.strip().splitlines()) == 1
    assert main(["report", str(folder), "--out", str(folder), "--quiet"]) == 2  # a folder
    capsys.readouterr()
    assert _digests(folder) == before  # nothing written, nothing changed
    # a good run leaves every input as it was, no temporary file, and rebuilds the same page
    assert main(["report", str(folder), "--quiet"]) == 0
    after = _digests(folder)
    assert after.pop("report.html") and after == before
    first = (folder / "report.html").read_bytes()
    other = folder.parent / "elsewhere" / "page.html"
    assert main(["report", str(folder), "--out", str(other), "--quiet"]) == 0
    assert other.read_bytes() == first
    assert not [p for p in folder.parent.rglob(".*") if p.is_file()]


SMALL_SCENARIO = """
[scenario]
name = "report_small"
seed = 3

[plant]
name = "beam"

[experiment]
kind = "open_loop_multisine"
period = 512
periods = 2

[frf]
method = "multisine"
"""


def test_run_writes_the_report_and_report_rebuilds_it(tmp_path, capsys):
    scenario = tmp_path / "small.toml"
    scenario.write_text(SMALL_SCENARIO)
    out = tmp_path / "res"
    assert main(["run", str(scenario), "--results", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert f"report: {out / 'report.html'}" in printed
    assert (out / "scenario.toml").read_text() == SMALL_SCENARIO
    assert "[versions]" in (out / "versions.toml").read_text()
    page = _parse(out / "report.html")
    assert [i["data-source"] for i in page.images] == ["frf_measured.png"]
    text = "".join(page.text)
    assert SMALL_SCENARIO in text and "of the run (versions.toml)" in text
    assert {"plant", "experiment", "frf"} <= set(json.loads((out / "summary.json").read_text()))
    first = (out / "report.html").read_bytes()
    (out / "report.html").unlink()
    # from the folder alone: the scenario file gone, the page comes back the same
    scenario.unlink()
    assert main(["report", str(out), "--quiet"]) == 0
    assert (out / "report.html").read_bytes() == first


# ------------------------------------------------------------------ a real browser
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

#: appended to a copy of the page: writes how many images the browser decoded into the DOM
PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var p = document.createElement('p');
  p.id = 'probe';
  p.textContent = 'loaded ' + ok + ' of ' + imgs.length;
  document.body.appendChild(p);
});
</script>"""


def _chromium(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",  # root in a container
        "--disable-gpu",
        "--hide-scrollbars",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
        *args,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="chromium not installed (apt-get install chromium; .ci/run installs it as root)",
)
def test_every_figure_loads_in_headless_chromium(folder, tmp_path):
    from PIL import Image

    done = write_report(folder)
    page = done["path"]
    # the probe page sits next to the report (same file:// origin) and adds one broken image:
    # the count must see the report's images load and the broken one fail
    probe = folder / "probe.html"
    broken = '<img alt="broken" src="data:image/png;base64,iVBORw0KGgoAAAA=">'
    probe.write_text(page.read_text().replace("</body>", broken + PROBE + "</body>"))
    res = _chromium(tmp_path, "--virtual-time-budget=10000", "--dump-dom", probe.as_uri())
    assert res.returncode == 0, res.stderr[-2000:]
    n = done["figures"]
    assert f'<p id="probe">loaded {n} of {n + 1}</p>' in res.stdout, res.stdout[-500:]

    shot = folder / "report.png"
    res = _chromium(tmp_path, "--window-size=1280,1600", f"--screenshot={shot}", page.as_uri())
    assert res.returncode == 0, res.stderr[-2000:]
    with Image.open(shot) as im:
        assert im.size == (1280, 1600)
        lo, hi = im.convert("L").getextrema()
        assert hi - lo > 100  # not a blank page
    # the screenshot is kept with the results and never becomes a figure of the page
    assert write_report(folder)["figures"] == n
