"""CLI exit-status policy: bad input is one line and status 2, never a traceback;
data warnings are 'warning:' lines with status 0."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import SHARED_EXAMPLES, one_line, require_shared

from workbench.cli.main import main

EXAMPLES = SHARED_EXAMPLES


@pytest.mark.parametrize(
    "argv",
    [
        ["no-such-command"],
        ["info"],
        ["compare", "--data", "x.npz"],
        ["compare", "--model", "m.npz", "--data", "d.npz", "--window", "nine"],
    ],
    ids=["unknown-command", "info-no-file", "compare-no-model", "compare-bad-option"],
)
def test_usage_errors_exit_2_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "error:" in one_line(capsys.readouterr().err)


def test_compare_with_measurement_as_model_is_refused(capsys):
    require_shared()
    m = str(EXAMPLES / "example_beam_none_frf" / "measurement.npz")
    assert main(["compare", "--model", m, "--data", m]) == 2
    line = one_line(capsys.readouterr().err)
    assert m in line and "expected a model file" in line


def test_compare_with_model_as_data_is_refused(capsys):
    require_shared()
    m = str(EXAMPLES / "example_beam_none_frf" / "nominal_model.npz")
    assert main(["compare", "--model", m, "--data", m]) == 2
    line = one_line(capsys.readouterr().err)
    assert m in line and "missing key 'kind'" in line


def test_compare_bad_delay_in_model_file(tmp_path, capsys):
    require_shared()
    arrays = dict(np.load(EXAMPLES / "example_beam_none_frf" / "nominal_model.npz"))
    arrays["delay_s"] = np.array([1e-4, 2e-4])
    np.savez(tmp_path / "m.npz", **arrays)
    d = str(EXAMPLES / "example_beam_none_frf" / "measurement.npz")
    assert main(["compare", "--model", str(tmp_path / "m.npz"), "--data", d]) == 2
    assert "key 'delay_s'" in one_line(capsys.readouterr().err)


def test_negative_delay_option_is_refused(capsys):
    require_shared()
    folder = EXAMPLES / "example_beam_none_frf"
    argv = ["compare", "--model", str(folder / "nominal_model.npz"), "--data"]
    assert main(argv + [str(folder / "measurement.npz"), "--delay-s=-1e-3"]) == 2
    assert "delay_s" in one_line(capsys.readouterr().err)


def test_warning_is_one_line_and_exit_zero_in_subprocess(tmp_path):
    rng = np.random.default_rng(3)
    u = rng.standard_normal((500, 2))
    u[:, 1] = 0.0  # a constant input
    np.savez(tmp_path / "c.npz", kind="time", fs=100.0, u=u, y=u[:, :1] * 2, loop="open")
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "info", str(tmp_path / "c.npz")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0
    line = one_line(proc.stderr)
    assert line.startswith("warning: ") and "input 'u1' (channel 1) is constant" in line
    assert "kind: time" in proc.stdout


def test_closed_pipe_is_not_an_internal_error():
    """``workbench compare ... | head -1``: the reader leaves early; no 'internal error'."""
    import subprocess
    import sys

    folder = require_shared(EXAMPLES / "example_stage_missing_frf")
    cmd = [sys.executable, "-m", "workbench", "compare", "--model"]
    cmd += [str(folder / "nominal_model.npz"), "--data", str(folder / "measurement.npz")]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)
    p.stdout.close()  # the reader is gone before the first line: every write hits EPIPE
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) in (0, 141)
    assert "internal error" not in err and "Traceback" not in err
