"""Minimality (Lemma 1/2) on good models and on models built to violate each lemma; CLI."""

from __future__ import annotations

import json

import control
import numpy as np
import pytest

from workbench.cli.main import main
from workbench.core.errors import InputError
from workbench.io.formats import TimeData, save_measurement, save_model
from workbench.modal.minimality import check_minimality
from workbench.modal.model import ModalModel, Mode


def stage_like(n_rigid: int = 3) -> ModalModel:
    """n_rigid rigid DOFs (b_k, c_k along DOF k) and two flexible modes, 3 inputs/outputs."""
    modes = [
        Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=0.5 * np.eye(3)[k], c=0.5 * np.eye(3)[k])
        for k in range(n_rigid)
    ]
    modes += [
        Mode(
            kind="flexible", freq_hz=913.8, damping=0.0091, b=[0.3, -0.2, 0.1], c=[0.1, 0.4, -0.2]
        ),
        Mode(
            kind="flexible", freq_hz=1032.0, damping=0.0095, b=[0.1, 0.3, 0.5], c=[-0.3, 0.2, 0.2]
        ),
    ]
    return ModalModel(modes=tuple(modes), D=np.zeros((3, 3)))


def replace_mode(model: ModalModel, k: int, **changes) -> ModalModel:
    m = model.modes[k]
    fields = dict(kind=m.kind, freq_hz=m.freq_hz, damping=m.damping, b=m.b, c=m.c) | changes
    modes = list(model.modes)
    modes[k] = Mode(**fields)
    return ModalModel(modes=tuple(modes), D=model.D)


def test_good_model_is_minimal_with_clear_margins():
    report = check_minimality(stage_like())
    assert report.minimal and report.failures == ()
    for c in report.checks:
        assert c.ctrb_lemma > 0.1 and c.obsv_lemma > 0.1
        assert c.ctrb_pbh > 1e-3 and c.obsv_pbh > 1e-6
        if c.kind == "rigid":
            assert c.ctrb_gram is None and c.group == (1, 2, 3)
        else:
            assert c.ctrb_gram > 0.01 and c.obsv_gram > 0.01
    # (the Kalman rank test [B, AB, ...] is useless here: A^9 B spans 1e32 against 0.5)


def test_zero_b_fails_lemma_1_for_that_mode_only():
    report = check_minimality(replace_mode(stage_like(), 3, b=np.zeros(3)))
    assert not report.controllable and report.observable
    (f,) = report.failures
    assert (f.mode, f.property, f.severity) == (4, "controllability", "fails")
    assert "Lemma 1: b_4 = 0" in f.criterion and "damp" in f.meaning
    assert report.checks[3].ctrb_pbh < 1e-12  # PBH agrees
    assert report.checks[3].ctrb_gram == 0.0  # and the Gramian
    assert "mode 4 (flexible, 913.80 Hz) fails controllability" in report.text()


def test_parallel_rigid_b_fails_lemma_1_naming_both_modes():
    model = replace_mode(stage_like(), 1, b=2.0 * stage_like().modes[0].b)
    report = check_minimality(model)
    assert not report.controllable and report.observable
    assert sorted(f.mode for f in report.failures) == [1, 2]
    assert all("linearly dependent" in f.criterion for f in report.failures)
    assert "modes [2]" in report.failures[0].criterion
    assert report.checks[0].ctrb_pbh < 1e-12  # PBH at s = 0 agrees


def test_zero_c_fails_lemma_2():
    report = check_minimality(replace_mode(stage_like(), 4, c=np.zeros(3)))
    assert report.controllable and not report.observable
    (f,) = report.failures
    assert (f.mode, f.property) == (5, "observability")
    assert "Lemma 2: c_5 = 0" in f.criterion and "observer" in f.meaning
    assert report.checks[4].obsv_pbh < 1e-12


def test_nearly_uncontrollable_mode_is_weak_not_failing():
    report = check_minimality(replace_mode(stage_like(), 3, b=1e-5 * np.ones(3)))
    assert report.minimal
    (f,) = report.failures
    # margin = |b_4| / max_j |b_j|, the largest being mode 5's [0.1, 0.3, 0.5]
    assert f.severity == "weak"
    assert f.margin == pytest.approx(np.sqrt(3) * 1e-5 / np.linalg.norm([0.1, 0.3, 0.5]), rel=1e-9)
    data = json.loads(report.to_json())
    assert data["minimal"] is True and data["failures"][0]["severity"] == "weak"


def test_bad_input():
    with pytest.raises(InputError, match="expected a ModalModel"):
        check_minimality(stage_like().to_statespace())


# ---------------------------------------------------------------------- CLI
def test_cli_minimality(tmp_path, capsys):
    path = tmp_path / "bad.npz"
    save_model(path, replace_mode(stage_like(), 3, b=np.zeros(3)).to_statespace())
    assert main(["minimality", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["controllable"] is False and out["failures"][0]["mode"] == 4


def test_cli_identify_end_to_end(tmp_path, capsys):
    """Closed-loop record of a known 4th-order system -> identify -> modal file -> modes."""
    rng = np.random.default_rng(7)
    w = 2 * np.pi * np.array([40.0, 110.0])
    A = np.zeros((4, 4))
    for k in range(2):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[0, 1], [-(w[k] ** 2), -2 * 0.05 * w[k]]]
    sysc = control.ss(
        A, [[0, 0], [1, 0.3], [0, 0], [0.2, 1]], 1e3 * np.array([[1, 0, 0.5, 0], [0.3, 0, 1, 0]]), 0
    )
    fs = 1000.0
    sysd = control.c2d(sysc, 1 / fs)
    Ad, Bd, Cd = (np.asarray(x) for x in (sysd.A, sysd.B, sysd.C))
    N = 4000
    r = rng.standard_normal((N, 2))
    x = np.zeros(4)
    u = np.zeros((N, 2))
    y = np.zeros((N, 2))
    for k in range(N):
        y[k] = Cd @ x + 1e-3 * rng.standard_normal(2)
        u[k] = r[k] - 2.0 * y[k]
        x = Ad @ x + Bd @ u[k]
    data_path = tmp_path / "d.npz"
    save_measurement(data_path, TimeData(fs=fs, u=u, y=y, r=r, loop="closed"))
    out, modal = tmp_path / "m.npz", tmp_path / "modal.npz"
    argv = ["identify", str(data_path), "--method", "cl-moesp", "--block-rows", "10"]
    assert (
        main(
            argv + ["--out", str(out), "--modal", str(modal), "--sv-plot", str(tmp_path / "sv.png")]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "suggested order 4" in text
    assert main(["modes", str(modal), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["modes"]
    assert [r["kind"] for r in rows] == ["flexible", "flexible"]
    # named tolerance: identified frequencies within 0.5 % of 40 and 110 Hz
    assert [r["freq_hz"] for r in rows] == pytest.approx([40.0, 110.0], rel=5e-3)
    # bad input: exit 2, one line
    assert main(argv + ["--out", str(data_path)]) == 2
    assert main(["identify", str(out), "--out", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("error: ") for line in err)
