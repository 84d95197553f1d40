"""An output that cannot be written is refused in one line, exit 2, before any work (issue 13).

Every command that writes is given an output whose parent is a file (the
folder cannot be made), and inputs that do not exist: the refusal must name
the output, not the missing input, which shows the output was checked first.
Nothing may be written. File outputs given an existing folder, and folder
outputs (``--plots``) given an existing file, are refused the same way.
"""

from __future__ import annotations

import pytest

from workbench.cli.main import main

#: command -> argv with OUT (a file output) or DIR (a folder output); the inputs do not exist
WRITERS = {
    "compare-json": "compare --model m.npz --data d.npz --json OUT",
    "compare-plots": "compare --model m.npz --data d.npz --plots DIR",
    "diagnose-json": "diagnose --model m.npz --data d.npz --json OUT",
    "diagnose-plots": "diagnose --model m.npz --data d.npz --plots DIR",
    "augment-out": "augment --model m.npz --data d.npz --effect time_delay --out OUT",
    "augment-plots": "augment --model m.npz --data d.npz --effect time_delay --plots DIR",
    "identify-out": "identify d.npz --out OUT",
    "identify-json": "identify d.npz --out x.npz --json OUT",
    "frf-out": "frf d.npz --out OUT",
    "design-out": "design --model m.npz --method pid-notch --out OUT",
    "design-json": "design --model m.npz --method pid-notch --json OUT",
    "loop-json": "loop --plant wafer_stage --controller k.npz --json OUT",
    "loop-plots": "loop --plant wafer_stage --controller k.npz --plots DIR",
    "modalfit-out": "modalfit f.npz --out OUT",
    "modalfit-plots": "modalfit f.npz --out x.npz --plots DIR",
    "update-out": "update --fe fe.npz --data f.npz --out OUT",
    "update-json": "update --fe fe.npz --data f.npz --out x.npz --json OUT",
    "update-plots": "update --fe fe.npz --data f.npz --out x.npz --plots DIR",
    "predict-out": "predict --fe fe.npz --data f.npz --out OUT",
    "simulate-out": "simulate wafer_stage --out OUT",
    "modes-plot": "modes m.npz --plot OUT",
    "regress-out": "regress s.toml --baseline base --out DIR",
}


def _run(capsys, tmp_path, line, out, folder):
    argv = [
        str(tmp_path / a) if a.endswith((".npz", ".toml")) or a == "base" else a
        for a in line.split()
    ]
    argv = [str(out) if a in ("OUT", "DIR") else a for a in argv]
    rc = main(argv)
    cap = capsys.readouterr()
    return rc, cap.err.strip().splitlines()


@pytest.mark.parametrize("name", list(WRITERS))
def test_output_under_a_file_is_refused_first(tmp_path, capsys, name):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder\n")
    line = WRITERS[name]
    folder = "DIR" in line
    out = blocker / "sub" / ("plots" if folder else "out.npz")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    rc, err = _run(capsys, tmp_path, line, out, folder)
    assert rc == 2, err
    assert len(err) == 1, err
    assert str(out) in err[0] and "is a file" in err[0], err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing written


@pytest.mark.parametrize(
    "name", ["compare-json", "diagnose-json", "augment-out", "frf-out", "design-out"]
)
def test_file_output_that_is_a_folder_is_refused(tmp_path, capsys, name):
    out = tmp_path / "a_folder"
    out.mkdir()
    rc, err = _run(capsys, tmp_path, WRITERS[name], out, False)
    assert rc == 2 and len(err) == 1 and "existing folder" in err[0], err


@pytest.mark.parametrize("name", ["compare-plots", "diagnose-plots", "loop-plots"])
def test_folder_output_that_is_a_file_is_refused(tmp_path, capsys, name):
    out = tmp_path / "a_file.png"
    out.write_text("x")
    rc, err = _run(capsys, tmp_path, WRITERS[name], out, True)
    assert rc == 2 and len(err) == 1 and "existing file" in err[0], err


def test_run_results_folder_under_a_file_is_refused(tmp_path, capsys):
    from pathlib import Path

    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "wafer_stage_demo.toml"
    rc = main(["run", str(scenario), "--results", str(blocker / "res"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "is a file" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]
