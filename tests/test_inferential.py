"""Inferential control (controllers.inferential) against oracles.

Oracles: the observer's error recursion (with a perfect model and noise-free
data the estimate of the unmeasured point equals the true one exactly, and from
a wrong start the error is ``Cz (A - L C)^k e0``); modal_sf.bandwidth_lqg (the
design with no weight on z is that rigid-body LQG); the design model's own output
map (z_rows at a measured sensor is its row of C); workbench.loop's S = (I + G K)^-1
for the closed loop of point_loop; the true beam (plants/) for the tuned design,
through workbench.testing. The FE model here is the beam's at the design-side
prior and at the true parameters (a perfect FE model: the oracle case).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from controllers.inferential import (
    design_inferential,
    measured_model,
    pad_controller,
    point_loop,
    point_model,
    z_estimator,
    z_rows,
)
from controllers.modal_sf import bandwidth_lqg, observer_controller
from plants.beam import BeamConfig, beam, beam_fe_file, beam_prior_config
from workbench.core.errors import InputError
from workbench.core.lti import frf
from workbench.core.model import LTIModel

FS = 2048.0  # the beam's rate (plants.beam)
MEASURED = ("s1", "s2", "s5")  # seed 001: s3, s4 held out
Z = "s3"
# a setting inside tune_inferential's grid (0.63 f1 of the beam's 35 Hz mode)
SETTING = dict(bandwidth_hz=22.0, z_weight=30.0, z_damping=10.0, flexible_observer=3.0)


@functools.cache
def _modal(which: str = "prior"):
    cfg = beam_prior_config() if which == "prior" else BeamConfig()
    return point_model(beam_fe_file(cfg, damping=0.01), measured=MEASURED, z=Z, max_freq_hz=1024)


@functools.cache
def _design(z_integral: bool = True, delay: int = 1):
    return design_inferential(
        _modal(), FS, measured=MEASURED, z=Z, loop_delay_samples=delay,
        observer_ratio=5.0, rigid_damping=1.0, z_integral=z_integral, **SETTING,
    )  # fmt: skip


def _perfect_loop(d, x0, xhat0, n: int):
    """The design model itself as the plant (outputs y, z), closed with the estimator.

    Returns (z, z_hat), each (n,): the true point and its estimate.
    """
    dm = d.dm
    Pp, Gp, Cp, Dp = dm.plant  # plant + delay line, input u[k]
    k1 = Pp.shape[0]
    est = z_estimator(d)
    A, B, C = (np.asarray(x, float) for x in (est.A, est.B, est.C))
    x = np.array(x0, float)
    xc = np.zeros(A.shape[0])
    xc[:k1] = xhat0
    z = np.empty(n)
    zh = np.empty(n)
    for k in range(n):
        out = C @ xc  # [u; z_hat]
        u = out[:-1]
        zh[k] = out[-1]
        y = Cp @ x + Dp @ u
        z[k] = d.Cz[0, :k1] @ x + d.Dz[0] @ u
        xc = A @ xc + B @ (-y)  # e = r - y at r = 0
        x = Pp @ x + Gp @ u
    return z, zh


@pytest.mark.parametrize("z_integral", [True, False], ids=["z-integral", "no-z-integral"])
def test_perfect_model_estimate_equals_true_z(z_integral):
    d = _design(z_integral)
    k1 = d.dm.n - d.dm.n_i
    rng = np.random.default_rng(3)
    x0 = np.zeros(k1)
    x0[: d.dm.n_p] = rng.standard_normal(d.dm.n_p) * 1e-6  # every mode deflected
    z, zh = _perfect_loop(d, x0, x0, 400)
    assert np.max(np.abs(z)) > 1e-7  # a real trajectory
    # the error recursion starts at zero and stays there: exact to rounding
    np.testing.assert_allclose(zh, z, rtol=0, atol=1e-9 * np.max(np.abs(z)))


def test_estimate_error_follows_the_observer_recursion():
    d = _design()
    dm = d.dm
    k1 = dm.n - dm.n_i
    rng = np.random.default_rng(4)
    x0 = np.zeros(k1)
    x0[: dm.n_p] = rng.standard_normal(dm.n_p) * 1e-6
    n = 300
    z, zh = _perfect_loop(d, x0, np.zeros(k1), n)
    # e[k+1] = (Ad - L C) e[k] on the plant states; z_hat - z = -Cz_p e (the delay line is known)
    Ad, C = dm.Phi[: dm.n_p, : dm.n_p], dm.C[:, : dm.n_p]
    F = Ad - d.L @ C
    e = x0[: dm.n_p].copy()
    pred = np.empty(n)
    for k in range(n):
        pred[k] = -d.Cz[0, : dm.n_p] @ e
        e = F @ e
    np.testing.assert_allclose(zh - z, pred, rtol=0, atol=1e-9 * np.max(np.abs(pred)))
    assert np.max(np.abs(np.linalg.eigvals(F))) < 1.0


@pytest.mark.parametrize(
    "kw",
    [dict(z_integral=True), dict(z_integral=True, z_resonance=10.0), dict(z_integral=False)],
    ids=["z-integral", "z-integral+resonance", "plain"],
)
def test_closed_loop_poles_separate(kw):
    """Controller on its own design model: poles eig(Phi - Gamma K), eig(Ad - L C) and 0."""
    from workbench.sim import closed_loop_matrices

    d = design_inferential(
        _modal(), FS, measured=MEASURED, z=Z, loop_delay_samples=1, observer_ratio=5.0,
        rigid_damping=1.0, **SETTING, **kw,
    )  # fmt: skip
    dm = d.dm
    Pp, Gp, Cp, Dp = dm.plant  # the delay line inside: no loop delay on top
    c = d.controller
    A = closed_loop_matrices((Pp, Gp, Cp, Dp), (c.A, c.B, c.C, c.D))[0]
    got = np.linalg.eigvals(A)
    Ad, C = dm.Phi[: dm.n_p, : dm.n_p], dm.C[:, : dm.n_p]
    # the controller's copy of the delay line is exact: its error is a shift (poles at 0)
    want = np.concatenate(
        [
            np.linalg.eigvals(d.Phi - d.Gamma @ d.K),
            np.linalg.eigvals(Ad - d.L @ C),
            np.zeros(dm.n_d),
        ]
    )
    assert got.size == want.size
    # match each wanted pole to the nearest obtained one (pairs are conjugate-symmetric)
    for p in want:
        assert np.min(np.abs(got - p)) < 1e-6, p
    assert np.max(np.abs(got)) < 1.0


def test_no_weight_on_z_is_the_rigid_body_modal_lqg():
    d = design_inferential(
        _modal(), FS, measured=MEASURED, z=Z, loop_delay_samples=1, bandwidth_hz=20.0,
        rigid_damping=1.5, integral_ratio=0.1, z_weight=0.0, z_damping=0.0,
        observer_ratio=8.0, flexible_observer=0.0, z_integral=False,
    )  # fmt: skip
    K, L = bandwidth_lqg(
        d.dm, bandwidth_hz=20.0, observer_ratio=8.0, integral_ratio=0.1, flexible=0.0,
        rigid_damping=1.5,
    )  # fmt: skip
    ref = observer_controller(d.dm, K, L)
    for name in "ABC":
        a, b = getattr(d.controller, name), getattr(ref, name)
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-9 * np.max(np.abs(b)))


def test_z_rows_at_a_measured_sensor_is_its_output_row():
    d = _design()
    Cz, Dz = z_rows(_modal(), d.dm, "s2")
    np.testing.assert_allclose(Cz[0], d.dm.C[1], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(Dz[0], d.dm.D[1], rtol=1e-12, atol=1e-15)


def test_point_loop_matches_the_sensitivity_of_workbench_loop():
    from workbench.loop import loop_frf

    d = _design()
    plant = _modal("true").to_lti()
    meas = measured_model(_modal("true"), MEASURED).to_lti()
    f = np.array([2.0, 20.0, 35.0, 150.0])
    H = frf(point_loop(plant, d.controller, measured=MEASURED, z=Z, loop_delay_samples=1), f)
    _, L = loop_frf(meas, d.controller, f, loop_delay_samples=1)
    S = np.linalg.inv(np.eye(3) + L)
    # a common setpoint on every output: the measured errors are S 1
    np.testing.assert_allclose(H[:, 1:4, 0], S @ np.ones(3), rtol=1e-8)


def test_pad_controller_ignores_the_unmeasured_outputs():
    d = _design()
    K5 = pad_controller(d.controller, MEASURED, ["s1", "s2", "s3", "s4", "s5"])
    assert K5.n_y == 5 and K5.n_u == 3
    np.testing.assert_array_equal(K5.B[:, [2, 3]], 0.0)
    np.testing.assert_array_equal(K5.B[:, [0, 1, 4]], d.controller.B)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(z="s1"), "not measured"),
        (dict(z="s9"), "s9"),
        (dict(z_weight=-1.0), "z_weight"),
    ],
    ids=["z-measured", "z-unknown", "negative-weight"],
)
def test_bad_input_refused(kw, match):
    args = dict(measured=MEASURED, z=Z, loop_delay_samples=1, bandwidth_hz=20.0)
    args.update(kw)
    with pytest.raises(InputError, match=match):
        design_inferential(_modal(), FS, **args)


def test_design_on_the_true_beam_is_stable_with_margins():
    """The fixed setting on the perfect FE model: stable on the true beam, |S_ii| <= 2."""
    from workbench.testing import assert_margins, assert_stable

    d = design_inferential(
        _modal("true"), FS, measured=MEASURED, z=Z, loop_delay_samples=1,
        observer_ratio=5.0, rigid_damping=1.0, **SETTING,
    )  # fmt: skip
    lin = beam().linear_model()
    truth = LTIModel.from_statespace(lin[[0, 1, 4], :])
    assert_stable(truth, d.controller, loop_delay_samples=1)
    # bound: 6 dB (issue 10) + 2 %: the setting is a scan point, not the tuned one
    assert_margins(truth, d.controller, s_peak_max=2.04, loop_delay_samples=1)


@pytest.mark.parametrize(
    "table, match",
    [
        ({"designs": ["lqg"]}, "designs"),
        ({"models": ["truth"]}, "models"),
        ({"z": "s9"}, "s9"),
        ({"ms_max": 0.5}, "ms_max"),
        ({"scan": {"speed": 1.0}}, "speed"),
        ({"zz": 1}, "zz"),
        ({"designs": ["pid-notch", "youla-band"], "youla": {"nois_rel": 1e-3}}, "nois_rel"),
        ({"designs": ["pid-notch", "youla-band"], "youla": {"k_std": -1}}, "k_std"),
        ({"designs": ["pid-notch", "youla-band"], "youla": {"rms_factor": 0}}, "rms_factor"),
        ({"designs": ["pid-notch", "youla-band"], "youla": {"n_basis": 2.5}}, "n_basis"),
        ({"youla": {"df_hz": "x"}}, "df_hz"),
    ],
    ids=[
        "design",
        "model",
        "z",
        "ms_max",
        "scan-key",
        "unknown-key",
        "youla-key",
        "youla-k_std",
        "youla-rms_factor",
        "youla-n_basis",
        "youla-type",
    ],  # fmt: skip
)
def test_stage_refuses_a_bad_table_before_any_work(tmp_path, table, match):
    import plants
    from workbench.cli.inferential_stages import stage_inferential
    from workbench.cli.pipeline import RunState
    from workbench.io.scenario import Scenario

    st = RunState(
        scenario=Scenario(name="t", seed=0, results=tmp_path), out=tmp_path,
        rng=np.random.default_rng(0),
    )  # fmt: skip
    st.plant = plants.get_plant("beam")
    with pytest.raises(InputError, match=match):
        stage_inferential(st, dict(table))
    assert not list(tmp_path.iterdir())
