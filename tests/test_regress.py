"""``workbench regress``: a rerun passes, a moved figure fails by name, bad input exits 2."""

from __future__ import annotations

import json
import shutil

import pytest

from workbench.cli.commands.regress import Tolerances, compare_folders, tolerances_from_table
from workbench.cli.main import main
from workbench.core.errors import InputError

# a small, fast scenario: an open-loop multisine on the beam and its FRF (a second or two)
SCENARIO = """
[scenario]
name = "regress_small"
seed = 11

[plant]
name = "beam"

[experiment]
kind = "open_loop_multisine"
period = 512
periods = 2

[frf]
method = "multisine"
"""


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    folder = tmp_path_factory.mktemp("regress")
    scenario = folder / "small.toml"
    scenario.write_text(SCENARIO)
    base = folder / "baseline"
    assert main(["run", str(scenario), "--results", str(base), "--quiet"]) == 0
    return scenario, base


def test_identical_rerun_passes(baseline, tmp_path, capsys):
    scenario, base = baseline
    status = main(["regress", str(scenario), "--baseline", str(base), "--out", str(tmp_path / "r")])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "no regression" in out


def test_a_moved_figure_fails_and_is_named(baseline, tmp_path, capsys):
    scenario, base = baseline
    edited = tmp_path / "edited"
    shutil.copytree(base, edited)
    summary = json.loads((edited / "summary.json").read_text())
    old = summary["experiment"]["y_rms"][1]
    summary["experiment"]["y_rms"][1] = old * 1.01  # 1 % off: far beyond rel 1e-6
    (edited / "summary.json").write_text(json.dumps(summary))
    status = main(
        ["regress", str(scenario), "--baseline", str(edited), "--out", str(tmp_path / "r")]
    )
    out = capsys.readouterr().out
    assert status == 1
    lines = [x for x in out.splitlines() if x.startswith("REGRESSION")]
    assert len(lines) == 1, out
    assert "summary.json: experiment.y_rms.1: baseline" in lines[0]
    assert repr(old * 1.01) in lines[0] and repr(old) in lines[0]


def test_missing_baseline_is_bad_input(baseline, tmp_path, capsys):
    scenario, _ = baseline
    status = main(["regress", str(scenario), "--baseline", str(tmp_path / "nope")])
    err = capsys.readouterr().err
    assert status == 2
    assert "--baseline: expected an earlier results folder" in err
    assert len(err.strip().splitlines()) == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["regress", str(scenario), "--baseline", str(empty)]) == 2


def _write(folder, name, payload):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(json.dumps(payload))


def test_tolerances_per_key_ignore_and_non_finite(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "x.json", {"f": [1.0, 2.0], "g": {"h": 1e-9}, "s": "inf", "ok": True, "t": "note"})
    _write(b, "x.json", {"f": [1.0, 2.001], "g": {"h": 1.1e-9}, "s": "inf", "ok": True, "t": "x"})
    problems, n = compare_folders(a, b, Tolerances())
    assert n == 5  # the strings that are not numbers are no figures
    assert [p.split(":")[1].strip() for p in problems] == ["f.1", "g.h"]
    # per-key tolerances (the longest pattern wins) and ignore patterns
    tol = tolerances_from_table(
        {"tolerances": {"x.json:f.*": {"rel": 1e-2}, "x.json:g.h": {"rel": 0.2}}}
    )
    assert compare_folders(a, b, tol)[0] == []
    tol = tolerances_from_table(
        {"ignore": ["x.json:g.*"], "tolerances": {"x.json:*": {"rel": 1e-2}}}
    )
    assert compare_folders(a, b, tol) == ([], 4)
    # booleans and non-finite figures must match exactly; a vanished figure is a regression
    _write(b, "x.json", {"f": [1.0, 2.0], "g": {"h": 1e-9}, "s": "nan", "ok": False})
    problems, _ = compare_folders(a, b, Tolerances())
    assert [p.split(":")[1].strip() for p in problems] == ["s", "ok"]
    _write(b, "x.json", {"f": [1.0], "g": {"h": 1e-9}, "s": "inf", "ok": True})
    assert "f.1: baseline 2.0, missing from the rerun" in compare_folders(a, b, Tolerances())[0][0]


def test_bad_regress_table():
    with pytest.raises(InputError, match=r"\[regress\] has unknown key 'rtol'"):
        tolerances_from_table({"rtol": 1.0})
    with pytest.raises(InputError, match="expected FILE:KEY"):
        tolerances_from_table({"tolerances": {"crossover": {"rel": 1.0}}})
    with pytest.raises(InputError, match="expected a number >= 0"):
        tolerances_from_table({"rel": -1})
