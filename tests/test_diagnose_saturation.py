"""Saturation of the inputs in time records (issue 13, item 7).

- A saturation needs no port: on a model that is not square and has no sensor collocated
  with an input (no port can be located for friction or a spring), the linear model
  driven by the clipped recorded input is still its simulation model.
- A slight saturation of a closed loop's command (a peak or two clipped) leaves no
  distortion on the unexcited lines and a period-synchronous residual within noise; what
  shows is a drift of the from-rest simulation far above the noise floor estimated from
  the record's periods.
- The finding's ``level`` is the spec's: the share of the output power that the element
  adds to the linear model's response (what a generator computes with the truth).

Oracles: records simulated here with scipy (exact ZOH by ``scipy.signal.cont2discrete`` /
``scipy.linalg.expm``, the clipping applied in the loop written here), not with the
diagnosis code's own simulation.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from workbench.core.lti import relative_error_time
from workbench.io.formats import TimeData


def _multisine(rng, period: int, n_u: int, k_max: int) -> np.ndarray:
    """(period, n_u) random-phase odd multisine, about a quarter of the odd lines left out."""
    k = np.arange(1, k_max, 2)
    k = k[rng.random(k.size) > 0.25]
    t = np.arange(period)
    u = np.stack(
        [
            np.cos(2 * np.pi * np.outer(t, k) / period + rng.uniform(0, 2 * np.pi, k.size)).sum(1)
            for _ in range(n_u)
        ],
        1,
    )
    return u / u.std(0)


# ------------------------------------------------------------------ open loop, no port
FS_OPEN = 1000.0


def _three_modes():
    """2 inputs x 3 outputs, three modes (3, 11, 37 Hz); the third mode is seen with the
    opposite sign at every sensor, so no sensor-actuator pair has every driving-point
    residue positive (no collocated pair, no port)."""
    f = np.array([3.0, 11.0, 37.0])
    z = np.array([0.03, 0.02, 0.02])
    b = np.array([[1.0, 0.6], [0.8, 0.5], [0.5, 0.9]])  # (mode, input)
    c = np.array([[1.0, 0.7, 0.4], [0.5, 0.9, 1.0], [-0.9, -0.6, -0.8]])  # (mode, output)
    n = f.size
    A, B, C = np.zeros((2 * n, 2 * n)), np.zeros((2 * n, 2)), np.zeros((3, 2 * n))
    for k in range(n):
        w = 2 * np.pi * f[k]
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[0, 1], [-w * w, -2 * z[k] * w]]
        B[2 * k + 1] = b[k]
        C[:, 2 * k] = c[k]
    return A, B, C, np.zeros((3, 2))


@pytest.fixture(scope="module")
def open_loop_case():
    """Open-loop periodic record, each input clipped at its 0.93 quantile (7 % of samples)."""
    rng = np.random.default_rng(1)
    A, B, C, D = _three_modes()
    period, n_per = 1000, 6
    u = np.tile(_multisine(rng, period, 2, 150), (n_per, 1))
    levels = np.quantile(np.abs(u), 0.93, axis=0)
    Ad, Bd, Cd, _, _ = scipy.signal.cont2discrete((A, B, C, D), 1 / FS_OPEN, method="zoh")

    def simulate(uu):
        x, y = np.zeros(A.shape[0]), np.zeros((uu.shape[0], 3))
        for k in range(uu.shape[0]):
            y[k] = Cd @ x
            x = Ad @ x + Bd @ uu[k]
        return y

    y0 = simulate(np.clip(u, -levels, levels))
    y_lin = simulate(u)
    y = y0 + 2e-3 * y0.std(0) * rng.standard_normal(y0.shape)
    data = TimeData(fs=FS_OPEN, u=u, y=y, period=period)
    model = control.ss(A, B, C, D)

    from workbench.diagnosis import diagnose

    return dict(
        model=model, data=data, levels=levels, y0=y0, y_lin=y_lin, diag=diagnose(model, data)
    )


def test_saturation_is_fitted_on_a_model_without_ports(open_loop_case):
    """Before: no collocated pair, so no element at all (the record was answered with no
    finding, compare failing at z_mean 37)."""
    from workbench.diagnosis.diagnose import base_model
    from workbench.diagnosis.nonlinear import collocated_pairs

    c = open_loop_case
    assert collocated_pairs(base_model(c["model"], c["data"])) == []  # no port can be located
    floor = relative_error_time(c["data"].y, c["y0"])
    top = c["diag"].findings[0]
    assert top.effect == "nonlinearity", [f.effect for f in c["diag"].findings]
    assert top.parameters["element"] == "saturation"
    np.testing.assert_allclose(top.parameters["saturation"], c["levels"], rtol=0.01)
    assert top.error_after <= 1.2 * floor, (top.error_after, floor)  # measured 1.00x
    assert top.outputs == (0, 1, 2)  # an input's saturation shows at every sensor
    assert "No port could be located" in top.explanation


def test_saturation_level_is_the_output_share_the_element_adds(open_loop_case):
    """The spec's level, "the share of output power not explained by a linear model", as the
    generators compute it with the truth: ||y_true - y_true_linear||^2 / ||y||^2. Before, the
    finding carried the detector's estimate there (distortion on the unexcited lines)."""
    c = open_loop_case
    y = c["data"].y
    truth = np.sum((c["y0"] - c["y_lin"]) ** 2) / np.sum(y**2)
    top = c["diag"].findings[0]
    assert top.parameters["level"] == pytest.approx(truth, rel=0.05)  # measured 0.1 % off
    assert "evidence_level" in top.parameters


# ------------------------------------------------------------------ closed loop, drift only
FS_LOOP = 2000.0


def _closed_loop_slightly_clipped(seed: int = 3, margin: float = 0.99993, noise_rel: float = 2e-3):
    """Two free masses (2 kg, 5 kg) under PID control (20 Hz), periodic multisine r (10 N
    rms), the command clipped at ``margin`` times each input's largest steady-state |u| of
    the same record unclipped (a peak or two clipped in the whole record). Exact ZOH by
    scipy's matrix exponential, output noise ``noise_rel`` of the output's rms.
    Returns (model, data, levels, noise-free y)."""
    rng = np.random.default_rng(seed)
    m = np.array([2.0, 5.0])
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [np.zeros((2, 4))]])
    B = np.vstack([np.zeros((2, 2)), np.diag(1 / m)])
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    E = scipy.linalg.expm(np.block([[A, B], [np.zeros((2, 6))]]) / FS_LOOP)
    Ad, Bd = E[:4, :4], E[:4, 4:]
    w = 2 * np.pi * 20.0
    kp, kd = m * w**2, 2 * 0.7 * m * w
    ki = kp * w / 10
    period, n_per = 1000, 5
    r = 10.0 * np.tile(_multisine(rng, period, 2, 300), (n_per, 1))
    noise = rng.standard_normal(r.shape)

    def run(levels, sd):
        x, y_prev, integ = np.zeros(4), np.zeros(2), np.zeros(2)
        u, y0, y = np.zeros_like(r), np.zeros_like(r), np.zeros_like(r)
        for k in range(r.shape[0]):
            y0[k] = C @ x
            y[k] = y0[k] + sd * noise[k]
            integ += y[k] / FS_LOOP
            u[k] = r[k] - kp * y[k] - kd * (y[k] - y_prev) * FS_LOOP - ki * integ
            y_prev = y[k]
            x = Ad @ x + Bd @ np.clip(u[k], -levels, levels)
        return u, y, y0

    free = np.full(2, np.inf)
    sd = noise_rel * run(free, 0.0)[2].std(0)
    levels = margin * np.abs(run(free, sd)[0][period:]).max(axis=0)
    u, y, y0 = run(levels, sd)
    data = TimeData(fs=FS_LOOP, u=u, y=y, r=r, loop="closed", period=period)
    return control.ss(A, B, C, 0), data, levels, y0


def test_slight_saturation_in_a_closed_loop_shows_as_a_drift():
    """Before: "none" at 3.8x the floor (nothing detected: no distortion on the unexcited
    lines, the period-synchronous residual within the PERIODIC_NL limit); with the linear
    model's from-rest drift measured against the noise floor estimated from the periods,
    the saturation at 1.00x."""
    from workbench.diagnosis import detect, diagnose
    from workbench.diagnosis.diagnose import DRIFT_RATIO, PERIODIC_NL
    from workbench.sim import simulate_zoh

    model, data, levels, y0 = _closed_loop_slightly_clipped()
    floor = relative_error_time(data.y, y0)
    y_lin = simulate_zoh(model, data.u, data.fs)
    # the case is what it is meant to be: only the drift shows
    raw = detect.nonlinearity(data, None)
    assert raw.f_stat < 2.0, raw  # no distortion on the unexcited lines
    assert detect.periodic_misfit(data, y_lin) < PERIODIC_NL
    assert relative_error_time(data.y, y_lin) > DRIFT_RATIO * detect.noise_floor(data, y_lin)
    diag = diagnose(model, data)
    top = diag.findings[0]
    assert top.effect == "nonlinearity", [f.effect for f in diag.findings]
    assert top.parameters["element"] == "saturation", top.parameters["element_errors"]
    # a saturation that leaves only the noise is fitted first, and friction and the spring
    # at the ports (hundreds of nonlinear simulations) are then not fitted
    assert set(top.parameters["element_errors"]) == {"saturation"}
    # the level is steep in the error (a from-rest rigid body): 1e-3 off is ~50x the floor
    np.testing.assert_allclose(top.parameters["saturation"], levels, rtol=1e-4)
    assert top.error_after <= 1.2 * floor, (top.error_after, floor)  # measured 1.00x


def test_noise_floor_from_the_periods():
    """A periodic response, a slow decaying transient and white noise: the spread of the
    periods about their mean is the noise plus the transient; with a model output holding
    the transient the estimate is the noise's error, ||noise|| / ||y||."""
    from workbench.diagnosis.detect import noise_floor

    rng = np.random.default_rng(7)
    fs, period, n_per = 1000.0, 500, 6
    t = np.arange(period * n_per) / fs
    periodic = np.tile(_multisine(rng, period, 2, 100), (n_per, 1))
    transient = 3.0 * np.exp(-t / 0.8)[:, None] * np.sin(2 * np.pi * 1.3 * t)[:, None]
    noise = 0.01 * rng.standard_normal(periodic.shape)
    y_clean = periodic + transient
    data = TimeData(fs=fs, u=periodic, y=y_clean + noise, period=period)
    truth = np.linalg.norm(noise) / np.linalg.norm(data.y)
    assert noise_floor(data, y_clean) == pytest.approx(truth, rel=0.05)
    # the record alone: the unsettled transient counts as spread (an upper bound)
    assert noise_floor(data) > 3 * truth
    # the smaller of the two spreads is taken
    assert noise_floor(data, np.zeros_like(y_clean)) == pytest.approx(noise_floor(data))
