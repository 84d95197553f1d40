"""An added term's cost and residual on a record from rest, without building the model.

On a time record simulated from rest (no start fitted) and without output coupling, a mode
or an upper residual added to a model changes its output by the term's filtered inputs
mixed by its numerators, which its linear fit formed as regressors: the cost is the misfit's
norm minus what the normal equations say (``added_term_cost``), the residual is the
misfit minus the term's output (``added_term_residual``). They are checked here against
the model built and simulated (an independent path: the compiled recursion of
:func:`workbench.modal.simulate.mixed_inputs`), and the screen and the fit that use them
against the same screen and fit on the built model.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_time_fast_paths import _model

from workbench.diagnosis.effects import AliasedMode, MissingMode, UpperResidual, _Lines
from workbench.diagnosis.fit import fit, screen
from workbench.diagnosis.problem import TimeProblem, make_problem
from workbench.io.formats import TimeData
from workbench.modal import simulate as S
from workbench.modal.model import Mode

FS = 4096.0


def _case(seed=3, n=5000, noise=2e-3, **kw):
    """A model, a record of it with one more mode (410 Hz), the problem (from rest)."""
    rng = np.random.default_rng(seed)
    model = _model(rng, n_y=3, n_u=2, **kw)
    extra = Mode("flexible", 410.0, 0.012, rng.standard_normal(2), rng.standard_normal(3))
    truth = replace(model, modes=model.modes + (extra,))
    u = rng.standard_normal((n, 2))
    y = S.simulate(truth, u, FS)
    y = y + noise * np.sqrt(np.mean(y**2)) * rng.standard_normal(y.shape)
    return model, TimeProblem(TimeData(fs=FS, u=u, y=y), transient=False)


THETAS = [np.log([410.0, 0.012]), np.log([150.0, 0.05]), np.log([1500.0, 0.002])]


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"delay": 1.7 / FS},
        {"tau_in": np.array([0.0, 1 / (2 * np.pi * 700)])},
        {"T_in": np.array([[1.0, 0.05], [-0.03, 1.0]])},
    ],
)
def test_a_missing_modes_cost_and_residual_are_the_built_models(kw):
    model, problem = _case(**kw)
    structure = MissingMode()
    lines = structure.lines(problem, model)
    assert lines is not None
    for theta in THETAS:
        r_model = problem.residual(structure.build(theta, problem, model).model)
        cost = float(r_model @ r_model)
        # the residue is the rank-one projection of the linear fit, not the LS solution
        # itself: the normal equations' cost holds for any coefficients
        assert lines.cost(theta) == pytest.approx(cost, rel=1e-9)
        r = lines.residual(theta)
        assert r.shape == r_model.shape
        assert np.max(np.abs(r - r_model)) <= 1e-8 * np.max(np.abs(r_model))


@pytest.mark.parametrize("n_poles", [1, 2])
@pytest.mark.parametrize("late", [False, True])
def test_an_upper_residuals_residual_is_the_built_models(late, n_poles):
    model, problem = _case()
    structure = UpperResidual(late=late, n_poles=n_poles)
    lines = structure.lines(problem, model)
    for theta in structure.grid(problem, model)[:: 5 if n_poles == 1 else 61]:
        r_model = problem.residual(structure.build(theta, problem, model).model)
        r = lines.residual(theta)
        assert np.max(np.abs(r - r_model)) <= 1e-8 * np.max(np.abs(r_model))


def test_the_cost_of_another_terms_numerators_falls_back_to_its_output():
    """The normal equations kept are the last linear fit's: a cost asked for another
    denominator, or for another model, is formed from the term's output instead."""
    model, problem = _case()
    rng = np.random.default_rng(5)
    den_fitted, den_asked = (
        Mode("flexible", f, 0.01, np.zeros(2), np.zeros(3)).denominator() for f in (300.0, 800.0)
    )
    problem.fit_new_term(model, den_fitted)
    N0, N1 = rng.standard_normal((3, 2)) * 1e5, rng.standard_normal((3, 2)) * 1e2
    mode = Mode("flexible", 800.0, 0.01, np.zeros(2), np.zeros(3), N0=N0, N1=N1)
    built = replace(model, modes=model.modes + (mode,))
    assert problem.added_term_cost(model, den_asked, N0, N1) == pytest.approx(
        problem.cost(built), rel=1e-9
    )


def test_not_offered_where_a_start_is_fitted_or_the_outputs_are_coupled():
    model, problem = _case()
    moving = TimeProblem(problem.data, transient=True)
    coupled = replace(model, T_out=np.eye(3) + 0.02)
    assert MissingMode().lines(moving, model) is None
    # the lines of a record (its DFT): the start's terms span the added term's poles
    assert MissingMode().lines(make_problem(problem.data, domain="frequency"), model) is None
    assert UpperResidual().lines(problem, coupled) is None
    assert not problem.added_terms_exact(coupled)
    assert problem.added_terms_exact(model)


@pytest.mark.parametrize("structure", [MissingMode(), UpperResidual(), UpperResidual(late=True)])
def test_screen_and_fit_end_where_the_built_models_do(structure, monkeypatch):
    model, problem = _case()
    fast_screen = screen(structure, problem, model)
    fast = fit(structure, problem, model, starts=fast_screen.starts)
    monkeypatch.setattr(type(structure), "lines", lambda self, problem, base: None)
    slow_screen = screen(structure, problem, model)
    slow = fit(structure, problem, model, starts=slow_screen.starts)
    assert fast_screen.cost == pytest.approx(slow_screen.cost, rel=1e-9)
    # the grid's order: the same points best
    assert all(np.array_equal(a, b) for a, b in zip(fast_screen.starts[:5], slow_screen.starts))
    assert fast.cost == pytest.approx(slow.cost, rel=1e-9, abs=1e-6 * slow.sigma2)
    assert np.all(np.abs(fast.theta - slow.theta) <= 1e-3 * np.maximum(slow.theta_std, 1e-9))
    if isinstance(structure, MissingMode):
        # the record's extra mode, found within 3 std
        assert abs(fast.theta[0] - np.log(410.0)) <= 3 * fast.theta_std[0]


def test_an_aliased_mode_uses_its_parents_residual():
    model, problem = _case()
    assert isinstance(AliasedMode().lines(problem, model), _Lines)
