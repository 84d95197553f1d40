"""One self-contained HTML page per results folder (``report.html``).

``workbench run`` calls :func:`write_run_report` at the end of a successful run;
``workbench report RESULTS_DIR`` calls :func:`write_report` to rebuild the page
from the folder alone. The page holds:

- the scenario's name, description, seed and the run's digest (the text
  ``workbench run`` prints);
- the stage timings (``summary.json``'s ``scenario.stage_seconds``);
- every PNG figure of the folder (subfolders too), embedded as base64 ``<img>``;
- every ``*.txt`` table as preformatted text and every JSON file as a table of
  its figures (dotted keys, matrices as small tables);
- the scenario file's text (``scenario.toml``, the copy the run keeps);
- the package versions of the run (``versions.toml``, written by the run; a
  folder without it shows the versions of the environment building the page,
  and says so);
- a list of every file in the folder (the ``.npz`` data are listed, not embedded).

Standard library only: ``html.escape`` and string building, no template engine
and no script. The page is written atomically; it never overwrites a file the
report reads.
"""

from __future__ import annotations

import base64
import html
import json
import math
import platform
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

from workbench.core import atomic
from workbench.core.errors import InputError

REPORT_NAME = "report.html"
#: the copy of the scenario file the run keeps in its results folder
SCENARIO_COPY = "scenario.toml"
#: the package versions of the run, written by the run (TOML: not a JSON figure for regress)
VERSIONS_NAME = "versions.toml"
#: a screenshot of the page (the browser test saves one next to it): never a figure
SCREENSHOT_NAME = "report.png"
#: (label, distribution) of the versions the report names
PACKAGES = (
    ("numpy", "numpy"),
    ("scipy", "scipy"),
    ("control", "control"),
    ("cvxpy", "cvxpy"),
    ("casadi", "casadi"),
    ("matplotlib", "matplotlib"),
    ("workbench", "motion-workbench"),
)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

_MAX_LIST = 200  # scalars shown in full up to this length; longer lists are abbreviated
_MAX_MATRIX = 24  # rows / columns of a matrix shown as a small table
_MAX_ROWS = 2000  # rows of one JSON table


# ---------------------------------------------------------------- environment
def package_versions() -> dict[str, str]:
    """Versions of Python and the packages a run depends on (``"not installed"`` if absent).

    The workbench's entry adds the git commit of its checkout when it is one
    (``+ local changes`` when the checkout differs from it).
    """
    from importlib import metadata

    out = {"python": platform.python_version()}
    for label, dist in PACKAGES:
        try:
            out[label] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[label] = "not installed"
    commit = _git_commit(Path(__file__).resolve().parent)
    if commit:
        out["workbench"] += f" (git {commit})"
    return out


def _git_commit(folder: Path) -> str | None:
    """The short commit of the checkout holding ``folder``, or None (no git, not a checkout)."""
    if not (folder.parent / ".git").exists():
        return None
    try:
        head = subprocess.run(
            ["git", "-C", str(folder), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
        )
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(folder), "diff", "--quiet", "HEAD", "--", "."],
            capture_output=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + (" + local changes" if dirty.returncode == 1 else "")


# ---------------------------------------------------------------- the run's side
def write_run_report(
    results: str | Path, scenario_file: str | Path, *, progress: bool = False
) -> list[str]:
    """At the end of ``workbench run``: keep the scenario and versions, write the page.

    Writes ``scenario.toml`` (a copy of ``scenario_file``, unless it is that
    file), ``versions.toml`` (:func:`package_versions`) and ``report.html``
    into ``results``, each atomically; returns the names written.
    """
    folder = Path(results)
    written = []
    source = Path(scenario_file)
    copy = folder / SCENARIO_COPY
    if source.resolve() != copy.resolve():
        atomic.write_text(copy, source.read_text(encoding="utf-8", errors="replace"))
        written.append(SCENARIO_COPY)
    lines = ["# package versions of the run that wrote this folder (read by workbench report)"]
    lines += ["[versions]"] + [f"{k} = {json.dumps(v)}" for k, v in package_versions().items()]
    atomic.write_text(folder / VERSIONS_NAME, "\n".join(lines) + "\n")
    written.append(VERSIONS_NAME)
    write_report(folder, progress=progress)
    written.append(REPORT_NAME)
    return written


# ---------------------------------------------------------------- reading a folder
def check_results_folder(results: str | Path) -> dict:
    """The folder's ``summary.json``; a folder ``workbench run`` did not write is refused.

    Raises :class:`InputError` (one line) for a path that is not a folder, a
    folder without ``summary.json`` or one whose ``summary.json`` is not the
    run's summary (a JSON object with a ``scenario`` table).
    """
    folder = Path(results)
    if not folder.is_dir():
        what = "an existing file" if folder.exists() else "no such folder"
        raise InputError(f"{results}: expected a results folder of workbench run, got {what}")
    path = folder / "summary.json"
    if not path.is_file():
        raise InputError(
            f"{results}: not a results folder (no summary.json; workbench run writes one)"
        )
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a JSON file ({exc})") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("scenario"), dict):
        raise InputError(
            f"{path}: expected the summary of workbench run (an object with a 'scenario' table)"
        )
    return summary


def report_inputs(results: str | Path) -> list[Path]:
    """Every file the report reads or lists: the folder's files, HTML and hidden ones aside."""
    folder = Path(results)
    out = []
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if any(part.startswith(".") for part in rel.parts) or not path.is_file():
            continue
        if path.suffix.lower() in (".html", ".htm") or rel.as_posix() == SCREENSHOT_NAME:
            continue
        out.append(path)
    return out


def read_results(results: str | Path) -> dict[str, Any]:
    """What the page shows, read from the folder (:func:`check_results_folder` first).

    Returns a dict: ``summary``, ``figures`` [(relative name, PNG bytes or
    None if not a PNG)], ``text_tables`` [(name, text)], ``json_tables``
    [(name, object, or None and an error)], ``scenario`` (text, source note),
    ``versions`` (dict, source note), ``files`` [(name, size)].
    """
    folder = Path(results)
    summary = check_results_folder(folder)
    figures, text_tables, json_tables, files = [], [], [], []
    for path in report_inputs(folder):
        rel = path.relative_to(folder).as_posix()
        files.append((rel, path.stat().st_size))
        suffix = path.suffix.lower()
        if suffix == ".png":
            data = path.read_bytes()
            figures.append((rel, data if data.startswith(PNG_SIGNATURE) else None))
        elif suffix == ".txt":
            text_tables.append((rel, path.read_text(encoding="utf-8", errors="replace")))
        elif suffix == ".json":
            try:
                json_tables.append((rel, json.loads(path.read_text(encoding="utf-8")), None))
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                json_tables.append((rel, None, f"not a JSON file ({exc})"))
    # summary.json first: the run's own figures lead
    json_tables.sort(key=lambda t: (t[0] != "summary.json", t[0]))
    return {
        "folder": folder,
        "summary": summary,
        "figures": figures,
        "text_tables": text_tables,
        "json_tables": json_tables,
        "scenario": _scenario_text(folder, summary),
        "versions": _versions(folder),
        "files": files,
    }


def _scenario_text(folder: Path, summary: dict) -> tuple[str | None, str]:
    """(text, where it came from): the folder's copy, else the file summary.json names."""
    copy = folder / SCENARIO_COPY
    if copy.is_file():
        return copy.read_text(encoding="utf-8", errors="replace"), SCENARIO_COPY
    named = summary["scenario"].get("file")
    if named and Path(named).is_file():
        text = Path(named).read_text(encoding="utf-8", errors="replace")
        return text, f"{named} (not in the results folder: read where the run found it)"
    return None, "the results folder holds no copy of the scenario file" + (
        f" and {named} is gone" if named else ""
    )


def _versions(folder: Path) -> tuple[dict[str, str], str]:
    """(versions, where they came from): the run's ``versions.toml``, else this environment."""
    path = folder / VERSIONS_NAME
    if path.is_file():
        try:
            table = tomllib.loads(path.read_text(encoding="utf-8")).get("versions")
        except (tomllib.TOMLDecodeError, UnicodeDecodeError):
            table = None
        if isinstance(table, dict):
            return {str(k): str(v) for k, v in table.items()}, "the run (versions.toml)"
    return package_versions(), (
        "the environment that built this page (the folder has no versions.toml of its run)"
    )


# ---------------------------------------------------------------- writing
def write_report(
    results: str | Path, out: str | Path | None = None, *, progress: bool = False
) -> dict[str, Any]:
    """Build the page of a results folder and write it atomically.

    Parameters
    ----------
    results : path
        A folder ``workbench run`` wrote.
    out : path, optional
        The page (default ``results/report.html``). Refused when it names a file
        the report reads (:func:`workbench.core.atomic.check_output`).
    progress : bool
        Progress lines on stderr.

    Returns ``{"path", "figures", "tables"}``: the page and what it holds.
    """
    folder = Path(results)
    check_results_folder(folder)
    out = Path(out) if out is not None else folder / REPORT_NAME
    atomic.check_output(out, report_inputs(folder), what="report")
    t0 = time.perf_counter()
    if progress:
        print(f"report {out} ...", file=sys.stderr, flush=True)
    contents = read_results(folder)
    atomic.write_text(out, render_report(contents))
    n_tables = len(contents["text_tables"]) + len(contents["json_tables"])
    if progress:
        print(f"report done in {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    return {"path": out, "figures": len(contents["figures"]), "tables": n_tables}


_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; padding: 0 1em;
       color: #222; }
h1 { margin-bottom: 0.2em; } h2 { border-bottom: 1px solid #ccc; margin-top: 2em; }
pre { background: #f6f6f6; padding: 0.6em; overflow-x: auto; font-size: 0.85em; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
th { background: #f0f0f0; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
table.matrix td { border: none; text-align: right; padding: 0 0.4em; }
td pre { margin: 0; padding: 0.2em; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 0.9em; color: #555; } .note { color: #a33; }
nav a { margin-right: 1em; } details { margin: 0.8em 0; } summary { cursor: pointer; }
"""


def render_report(contents: dict[str, Any]) -> str:
    """The page (HTML text) of :func:`read_results`'s contents."""
    summary = contents["summary"]
    sc = summary["scenario"]
    name = str(sc.get("name", "?"))
    e = _esc
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<meta name="generator" content="workbench report">',
        f"<title>{e(name)}: workbench report</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>Scenario {e(name)}</h1>",
    ]
    if sc.get("description"):
        parts.append(f'<p class="description">{e(sc["description"])}</p>')
    parts.append(
        '<p>seed <b id="seed">'
        + e(sc.get("seed", "?"))
        + "</b> &middot; results folder <code>"
        + e(contents["folder"])
        + "</code>"
        + (f" &middot; scenario file <code>{e(sc['file'])}</code>" if sc.get("file") else "")
        + "</p>"
    )
    parts.append(
        "<nav>"
        + "".join(
            f'<a href="#{a}">{t}</a>'
            for a, t in (
                ("summary", "Summary"),
                ("timings", "Timings"),
                ("figures", "Figures"),
                ("tables", "Tables"),
                ("scenario", "Scenario file"),
                ("versions", "Versions"),
                ("files", "Files"),
            )
        )
        + "</nav>"
    )
    parts += _summary_section(summary)
    parts += _timings_section(sc.get("stage_seconds") or {})
    parts += _figures_section(contents["figures"])
    parts += _tables_section(contents["text_tables"], contents["json_tables"])
    text, source = contents["scenario"]
    parts.append(f'<h2 id="scenario">Scenario file</h2><p>from {e(source)}</p>')
    if text is not None:
        parts.append(f'<pre id="scenario-text">{e(text)}</pre>')
    versions, vsource = contents["versions"]
    parts.append(f'<h2 id="versions">Package versions</h2><p>of {e(vsource)}</p>')
    parts.append(
        '<table id="versions-table"><tr><th>package</th><th>version</th></tr>'
        + "".join(f"<tr><td>{e(k)}</td><td>{e(v)}</td></tr>" for k, v in versions.items())
        + "</table>"
    )
    parts.append('<h2 id="files">Files</h2><table id="files-table">')
    parts.append("<tr><th>file</th><th>bytes</th></tr>")
    parts += [f'<tr><td>{e(f)}</td><td class="num">{n}</td></tr>' for f, n in contents["files"]]
    parts.append("</table></body></html>")
    return "\n".join(parts) + "\n"


def _summary_section(summary: dict) -> list[str]:
    from workbench.digest import run_digest  # the text workbench run prints

    try:
        digest = run_digest(summary)
    except Exception as exc:  # a summary of an unknown shape: the JSON table still shows it
        digest = f"(no digest: {type(exc).__name__})"
    return ['<h2 id="summary">Summary</h2>', f'<pre id="digest">{_esc(digest)}</pre>']


def _timings_section(seconds: dict) -> list[str]:
    out = ['<h2 id="timings">Stage timings</h2>']
    vals = {k: v for k, v in seconds.items() if isinstance(v, int | float)}
    if not vals:
        return out + ["<p>no stage timings in summary.json</p>"]
    total = sum(vals.values())
    out.append('<table id="timings-table"><tr><th>stage</th><th>seconds</th><th>share</th></tr>')
    for k, v in vals.items():
        share = f"{100 * v / total:.0f} %" if total > 0 else "-"
        out.append(
            f'<tr><td>{_esc(k)}</td><td class="num">{v:.2f}</td><td class="num">{share}</td></tr>'
        )
    out.append(f'<tr><th>total</th><th class="num">{total:.2f}</th><th></th></tr></table>')
    return out


def _figures_section(figures: list[tuple[str, bytes | None]]) -> list[str]:
    out = ['<h2 id="figures">Figures</h2>']
    if not figures:
        return out + ["<p>no figures in the results folder</p>"]
    for k, (rel, data) in enumerate(figures):
        fid = f"figure-{k}-{_slug(rel)}"
        if data is None:
            out.append(f'<p class="note" id="{fid}">{_esc(rel)}: not a PNG file, not shown</p>')
            continue
        b64 = base64.b64encode(data).decode("ascii")
        out.append(
            f'<figure id="{fid}"><img src="data:image/png;base64,{b64}" '
            f'alt="{_esc(rel)}" data-source="{_esc(rel)}">'
            f"<figcaption>{_esc(rel)}</figcaption></figure>"
        )
    return out


def _tables_section(text_tables, json_tables) -> list[str]:
    out = ['<h2 id="tables">Tables</h2>']
    for rel, text in text_tables:
        out.append(f'<h3 id="table-{_slug(rel)}">{_esc(rel)}</h3>')
        out.append(f'<pre class="table" data-source="{_esc(rel)}">{_esc(text.rstrip())}</pre>')
    for rel, obj, error in json_tables:
        out.append(f'<details id="table-{_slug(rel)}"><summary>{_esc(rel)}</summary>')
        if error is not None:
            out.append(f'<p class="note" data-source="{_esc(rel)}">{_esc(error)}</p></details>')
            continue
        rows = _flatten(obj, "", rel)
        shown = rows[:_MAX_ROWS]
        out.append(f'<table class="json" data-source="{_esc(rel)}">')
        out.append("<tr><th>key</th><th>value</th></tr>")
        out += [f"<tr><td>{_esc(k or '(value)')}</td>{cell}</tr>" for k, cell in shown]
        out.append("</table>")
        if len(rows) > len(shown):
            out.append(f"<p>{len(rows) - len(shown)} more rows: see {_esc(rel)}</p>")
        out.append("</details>")
    if not text_tables and not json_tables:
        out.append("<p>no tables in the results folder</p>")
    return out


# ---------------------------------------------------------------- JSON as rows
def _is_scalar(v) -> bool:
    return v is None or isinstance(v, bool | int | float | str)


def _fmt(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else str(v)
    return str(v)


def _cell(v) -> str:
    """A ``<td>`` for one scalar value (multi-line strings as preformatted text)."""
    if isinstance(v, str) and "\n" in v:
        return f"<td><pre>{_esc(v)}</pre></td>"
    num = isinstance(v, int | float) and not isinstance(v, bool)
    return f'<td class="num">{_esc(_fmt(v))}</td>' if num else f"<td>{_esc(_fmt(v))}</td>"


def _flatten(obj, key: str, source: str) -> list[tuple[str, str]]:
    """(dotted key, ``<td>`` HTML) rows of a JSON value: scalars, lists, matrices, objects."""
    join = (lambda k: f"{key}.{k}") if key else (lambda k: str(k))
    if isinstance(obj, dict):
        rows = []
        for k, v in obj.items():
            rows += _flatten(v, join(k), source)
        return rows or [(key, "<td>{}</td>")]
    if not isinstance(obj, list):
        return [(key, _cell(obj))]
    if not obj:
        return [(key, "<td>[]</td>")]
    if all(_is_scalar(v) for v in obj):
        vals = [_fmt(v) for v in obj]
        if len(vals) > _MAX_LIST:
            vals = vals[:10] + ["..."] + vals[-3:]
            note = f" ({len(obj)} values, all in {source})"
        else:
            note = ""
        return [(key, f"<td>[{_esc(', '.join(vals))}]{_esc(note)}</td>")]
    if all(isinstance(r, list) and r and all(_is_scalar(v) for v in r) for r in obj):
        n_cols = max(len(r) for r in obj)
        if len(obj) <= _MAX_MATRIX and n_cols <= _MAX_MATRIX:
            body = "".join(
                "<tr>" + "".join(f"<td>{_esc(_fmt(v))}</td>" for v in r) + "</tr>" for r in obj
            )
            return [(key, f'<td><table class="matrix">{body}</table></td>')]
        return [(key, f"<td>{len(obj)} x {n_cols} matrix (in {_esc(source)})</td>")]
    if len(obj) > _MAX_LIST:
        return [(key, f"<td>{len(obj)} items (in {_esc(source)})</td>")]
    if all(isinstance(r, dict) and r and all(map(_is_scalar, r.values())) for r in obj):
        # records (a mode table, the updated parameters): one row each, one column per key
        cols = list(dict.fromkeys(k for r in obj for k in r))
        head = "<tr>" + "".join(f"<th>{_esc(c)}</th>" for c in cols) + "</tr>"
        body = "".join("<tr>" + "".join(_cell(r.get(c, "")) for c in cols) + "</tr>" for r in obj)
        return [(key, f'<td><table class="records">{head}{body}</table></td>')]
    rows = []
    for i, v in enumerate(obj):
        rows += _flatten(v, join(i), source)
    return rows


def _esc(v) -> str:
    return html.escape(str(v), quote=True)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]+", "-", text).strip("-") or "x"
