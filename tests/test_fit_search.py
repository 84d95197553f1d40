"""How fit() searches: a lag's search in ``log theta``, a later start stopped in the first
start's basin, and the time-domain simulation's per-filter outputs kept between evaluations.

Each is a speed measure that must not move the optimum: the same parameters within a small
fraction of their std as the plain search, the same findings.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_time_fast_paths import _model

import workbench.diagnosis.fit as fit_engine
from workbench.diagnosis.effects import ActuatorDynamics, SensorDynamics, _Lag
from workbench.diagnosis.fit import _Basin, fit
from workbench.diagnosis.problem import TimeProblem
from workbench.io.formats import TimeData
from workbench.modal import simulate as S

FS = 4096.0


def _record(truth, rng, n=6000, noise=2e-3):
    u = rng.standard_normal((n, truth.n_u))
    y = S.simulate(truth, u, FS)
    y = y + noise * np.sqrt(np.mean(y**2)) * rng.standard_normal(y.shape)
    return TimeProblem(TimeData(fs=FS, u=u, y=y), transient=False)


def _counted(monkeypatch, problem) -> dict:
    """``problem.residual``'s evaluations, counted as they run (``["n"]``)."""
    calls = {"n": 0}
    residual = problem.residual

    def counted(model_):
        calls["n"] += 1
        return residual(model_)

    monkeypatch.setattr(problem, "residual", counted)
    return calls


def _lagged(side: str):
    """A model, its truth with lags on two of three channels (none on the middle one)."""
    rng = np.random.default_rng(11)
    model = _model(rng, n_y=3, n_u=3)
    tau = 1 / (2 * np.pi * np.array([450.0, np.inf, 900.0]))
    truth = replace(model, **({"tau_in": tau} if side == "in" else {"tau_out": tau}))
    return model, _record(truth, rng), tau


@pytest.mark.parametrize("structure", [ActuatorDynamics(), SensorDynamics()])
def test_a_lag_searched_in_log_theta_ends_where_the_linear_search_ends(structure, monkeypatch):
    model, problem, tau = _lagged(structure.side)
    logged = fit(structure, problem, model)
    monkeypatch.setattr(_Lag, "log_floor", None)  # the search in theta itself
    linear = fit(structure, problem, model)
    assert np.all(np.isfinite(linear.theta_std[[0, 2]]))
    # the same optimum, or a better one: the linear search stops ~1 noise variance above
    # the log search's cost (it creeps along the unlagged channel's floor), within half a
    # std of it on the lagged channels
    assert np.all(np.abs(logged.theta - linear.theta)[[0, 2]] <= 0.5 * linear.theta_std[[0, 2]])
    assert logged.cost <= linear.cost + 0.05 * linear.sigma2
    # and the truth: the cutoffs within 3 std
    scale = 2 * np.pi * problem.band_hz[1]
    truth = tau * scale
    assert np.all(np.abs(logged.theta - truth)[[0, 2]] <= 3 * logged.theta_std[[0, 2]])
    report, _ = structure.report(logged, problem, model)
    cut = report["cutoff_hz"]
    assert cut[0] is not None and cut[2] is not None
    # the unlagged channel: no lag, or one the data do not tell from none
    assert cut[1] is None or logged.theta[1] <= 3 * logged.theta_std[1]


def test_a_second_start_in_the_first_starts_basin_is_stopped_with_the_same_result(monkeypatch):
    model, problem, _ = _lagged("in")
    structure = ActuatorDynamics()
    n = 3
    # two starts on either side of the optimum, more than 5 % of the bounds apart (fit's
    # distinct starts): both end at it
    starts = [np.full(n, 0.3), np.full(n, 0.1 * structure.bounds(problem, model)[1][0])]
    calls = _counted(monkeypatch, problem)
    stopped = fit(structure, problem, model, starts=starts)
    n_stopped = calls["n"]
    calls["n"] = 0
    monkeypatch.setattr(_Basin, "of", classmethod(lambda cls, *a: None))
    full = fit(structure, problem, model, starts=starts)
    n_full = calls["n"]
    # the full second search ended at the first's optimum: the stopped one is the same fit
    assert np.all(np.abs(stopped.theta - full.theta) <= 0.1 * full.theta_std)
    assert stopped.cost <= full.cost + 0.05 * full.sigma2
    assert n_stopped < n_full


def test_the_basin_is_one_std_about_the_optimum_at_its_cost():
    rng = np.random.default_rng(3)
    J = rng.standard_normal((400, 2))
    r = rng.standard_normal(400)
    res = fit_engine.scipy.optimize.OptimizeResult(
        x=np.array([1.0, 2.0]), fun=r, jac=J, success=True
    )
    basin = _Basin.of(res, 2, 400)
    sigma = np.sqrt(basin.sigma2)
    # one std along the first direction of J: |J d| = sigma
    d = np.array([1.0, 0.0]) * sigma / np.linalg.norm(J[:, 0])
    with pytest.raises(fit_engine._SameBasin):
        basin.check(res.x + 0.9 * d, r)
    basin.check(res.x + 1.1 * d, r)  # outside: the search goes on
    basin.check(res.x, r + 3 * sigma / np.sqrt(400) * np.sign(r))  # its cost well above
    # a search stopped by its evaluations' limit is no optimum
    assert (
        _Basin.of(fit_engine.scipy.optimize.OptimizeResult(**{**res, "success": False}), 2, 400)
        is None
    )


def test_a_lag_moved_on_one_input_refilters_that_input_only(monkeypatch):
    rng = np.random.default_rng(7)
    tau = 1 / (2 * np.pi * np.array([800.0, 300.0, 1500.0]))
    model = _model(rng, n_y=3, n_u=3, tau_in=tau)
    u = rng.standard_normal((2000, 3))
    mode = model.modes[1]
    den, (N0, N1) = mode.denominator(), mode.numerator()
    plain = S.mixed_inputs(model, den, N0, N1, u, FS)
    outputs: dict = {}
    kept = S.mixed_inputs(model, den, N0, N1, u, FS, outputs=outputs)
    assert np.array_equal(kept, plain)
    runs = {"n": 0}
    iir = S.iir_streams

    def counted(*a):
        runs["n"] += 1
        return iir(*a)

    monkeypatch.setattr(S, "iir_streams", counted)
    moved = replace(model, tau_in=tau * np.array([1.0, 1.0001, 1.0]))
    again = S.mixed_inputs(moved, den, N0, N1, u, FS, outputs=outputs)
    assert runs["n"] == 1  # the moved input's filter; the other two were kept
    assert np.array_equal(again, S.mixed_inputs(moved, den, N0, N1, u, FS))


def test_a_search_stalled_far_above_a_rivals_cost_is_given_up_at_its_best_point():
    """fit's ``bar``: a search whose best cost stays above HOPELESS_RATIO bars, falling less
    than HOPELESS_FALL-fold over HOPELESS_STEPS steps' evaluations, is given up with the
    best point it reached; one still falling fast enough, or below the limit, goes on."""
    n_theta, bar = 2, 1.0
    window = fit_engine.HOPELESS_STEPS * (n_theta + 1)
    r_of = lambda c: np.array([np.sqrt(c)])  # noqa: E731 (a residual of cost c)

    stalled = fit_engine._Progress(bar, n_theta)
    costs = 1e3 * (1 + 0.01 * np.arange(window + 1))[::-1]  # creeping down 1 % in all
    with pytest.raises(fit_engine._Hopeless) as stop:
        for k, c in enumerate(costs):
            stalled.check(np.array([k, 0.0]), r_of(c))
    assert stop.value.result.x[0] == window  # the last and best point
    assert np.isclose(2 * stop.value.result.cost, costs[-1])
    assert str(stop.value.result.message).startswith(fit_engine.ABANDONED)

    falling = fit_engine._Progress(bar, n_theta)  # halving every HOPELESS_STEPS / 2 steps
    for k in range(4 * window):
        falling.check(np.zeros(2), r_of(1e9 * 0.5 ** (2 * k / window)))
    near = fit_engine._Progress(bar, n_theta)  # stalled, but within the limit
    for k in range(4 * window):
        near.check(np.zeros(2), r_of(0.99 * fit_engine.HOPELESS_RATIO * bar))


def test_a_fit_given_a_bar_it_cannot_approach_is_abandoned_above_the_full_fits_cost(
    monkeypatch,
):
    """The same structure fitted with and without a bar far below anything it reaches
    (one step's window: its first Jacobian's differences stall): the given-up fit is
    marked, its stds NaN, its cost no lower than the full fit's, in fewer evaluations."""
    model, problem, _ = _lagged("in")
    structure = SensorDynamics()
    calls = _counted(monkeypatch, problem)
    full = fit(structure, problem, model, n_starts=1)
    n_full, calls["n"] = calls["n"], 0
    assert not full.abandoned and full.status == "ok"
    monkeypatch.setattr(fit_engine, "HOPELESS_STEPS", 1)
    given_up = fit(structure, problem, model, n_starts=1, bar=1e-6 * full.cost)
    assert given_up.abandoned and np.all(np.isnan(given_up.theta_std))
    assert given_up.cost >= full.cost - 0.05 * full.sigma2
    assert calls["n"] < n_full
    # a bar it reaches: the search runs to its end
    calls["n"] = 0
    kept = fit(structure, problem, model, n_starts=1, bar=full.cost)
    assert not kept.abandoned and np.isclose(kept.cost, full.cost)


def test_a_mismatch_far_inside_the_grids_finest_step_is_screened_at_its_gauss_newton_point():
    """The 180 Hz mode (damping 0.005) 0.02 % low, z0 / 25, below the grid's finest step
    (z0 / 16): the screen's Gauss-Newton point from the model as given lands within a quarter
    of the shift of the truth (one step in a curved valley), and costs less than every point
    of the grid."""
    from workbench.diagnosis.effects import ModalMismatch

    rng = np.random.default_rng(5)
    model = _model(rng, n_y=3, n_u=2)
    mode = model.modes[1]
    f_true = mode.freq_hz * (1 - 2e-4)
    truth = replace(
        model, modes=(model.modes[0], mode.moved(f_true, mode.damping)) + model.modes[2:]
    )
    problem = _record(truth, rng, noise=1e-4)
    structure = ModalMismatch(index=1)
    grid = structure.grid(problem, model)
    near = structure._near(problem, model)
    assert len(near) == 2 and all(any(np.array_equal(p, g) for g in grid) for p in near)
    f_near = np.exp(near[0][0])
    assert abs(f_near - f_true) < 0.25 * abs(mode.freq_hz - f_true)

    def cost(theta):
        return problem.cost(structure.build(theta, problem, model).model)

    assert cost(near[0]) < min(cost(g) for g in grid[: -len(near)])
