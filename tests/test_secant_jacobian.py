"""The time-domain fits' secant Jacobian (:class:`workbench.diagnosis.fit._SecantJacobian`).

Broyden's update makes the Jacobian exact along the accepted step; difference quotients
come back after a rejected step and at the start; and a fit on a simulated record of a
known modal model reaches the optimum the difference-quotient search reaches (the same
parameters within a small fraction of their std, the same std). Only a structure that asks
(``secant``: a coupled suspension, started at its rigid fit's optimum) takes them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_time_fast_paths import _model

import workbench.diagnosis.fit as fit_engine
from workbench.diagnosis.effects import ActuatorDynamics, ModalModes, SensorDynamics
from workbench.diagnosis.fit import _SecantJacobian, finite_difference_jacobian, fit
from workbench.diagnosis.problem import TimeProblem
from workbench.io.formats import TimeData
from workbench.modal import simulate as S


def _rosenbrock(x):
    return np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0], 0.3 * x[0] * x[1]])


def test_secant_update_is_exact_along_the_step():
    lo, hi = np.full(2, -5.0), np.full(2, 5.0)
    sec = _SecantJacobian(_rosenbrock, lo, hi)
    x0 = np.array([-1.2, 1.0])
    r0 = sec.fun(x0)
    J0 = sec(x0).copy()  # the update is in place
    assert sec.fresh
    assert np.allclose(J0, finite_difference_jacobian(_rosenbrock, x0, r0, lo, hi))
    x1 = x0 + np.array([0.05, -0.02])
    r1 = sec.fun(x1)
    J1 = sec(x1)  # one evaluation since the last Jacobian: an accepted step, updated
    assert not sec.fresh
    assert np.allclose(J1 @ (x1 - x0), r1 - r0, rtol=0, atol=1e-12)
    # across the step the update leaves J's action unchanged
    ortho = np.array([0.02, 0.05])
    assert np.allclose(J1 @ ortho, J0 @ ortho, rtol=0, atol=1e-12)


def test_secant_difference_quotients_after_a_rejected_step_and_in_a_row():
    lo, hi = np.full(2, -5.0), np.full(2, 5.0)
    sec = _SecantJacobian(_rosenbrock, lo, hi)
    x = np.array([-1.2, 1.0])
    sec.fun(x)
    sec(x)
    sec.fun(x + 0.3)  # rejected
    x = x + np.array([0.01, 0.01])
    sec.fun(x)  # accepted: two evaluations since the Jacobian
    sec(x)
    assert sec.fresh
    for k in range(sec.MAX_UPDATES + 1):
        x = x + 0.01
        sec.fun(x)
        sec(x)
        assert sec.fresh == (k == sec.MAX_UPDATES)


def _record(model, truth, rng, fs=4096.0, n=6000, noise=2e-3):
    u = rng.standard_normal((n, model.n_u))
    y = S.simulate(truth, u, fs)
    y = y + noise * np.sqrt(np.mean(y**2)) * rng.standard_normal(y.shape)
    return TimeProblem(TimeData(fs=fs, u=u, y=y), transient=False)


CASES = {
    "moved modes": (  # six parameters: each flexible mode's frequency and damping
        ModalModes(),
        lambda m: replace(
            m,
            modes=(m.modes[0].moved(36.0, 0.025), m.modes[1].moved(186.0, 0.013)) + m.modes[2:],
        ),
    ),
    "actuator lags": (
        ActuatorDynamics(),
        lambda m: replace(m, tau_in=1 / (2 * np.pi * np.array([700.0, 350.0, 1200.0]))),
    ),
    "sensor lags": (
        SensorDynamics(),
        lambda m: replace(m, tau_out=1 / (2 * np.pi * np.array([500.0, 900.0, 300.0]))),
    ),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_secant_fit_reaches_the_difference_quotient_optimum(name, monkeypatch):
    structure, truth_of = CASES[name]
    rng = np.random.default_rng(5)
    model = _model(rng, n_u=3)
    problem = _record(model, truth_of(model), rng)
    assert len(structure.bounds(problem, model)[0]) >= fit_engine.SECANT_MIN_THETA
    monkeypatch.setattr(type(structure), "secant", True, raising=False)
    out = {}
    for mode in ("2-point", "secant"):
        monkeypatch.setattr(fit_engine, "TIME_JACOBIAN", mode)
        out[mode] = fit(structure, problem, model)
    ref, sec = out["2-point"], out["secant"]
    assert np.all(np.isfinite(ref.theta_std)) and np.all(ref.theta_std > 0)
    # the same optimum: parameters within a tenth of their std, the cost to a small share
    # of one observation's noise variance
    assert np.all(np.abs(sec.theta - ref.theta) <= 0.1 * ref.theta_std)
    assert sec.cost <= ref.cost + 0.05 * ref.sigma2
    # the std from difference quotients at the optimum in both (the two ends a few
    # hundredths of a std apart: a weakly determined lag's std moves by several %)
    assert np.allclose(sec.theta_std, ref.theta_std, rtol=0.15)


def test_only_a_structure_started_at_an_optimum_asks_for_secant_updates():
    from workbench.diagnosis.effects import CoupledSuspension, RigidSuspension

    assert CoupledSuspension().secant
    for s in (RigidSuspension(), ActuatorDynamics(), SensorDynamics(), ModalModes()):
        assert not getattr(s, "secant", False)
