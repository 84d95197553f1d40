"""Analytic variable-projection Jacobian of the modal fit (workbench.modal.fit.ModalStructure).

Oracles: a central finite-difference Jacobian of the engine's own residual
(``problem.residual(structure.build(theta).model)``), and the finite-difference fit of
the engine (a structure without ``jacobian``) on the FRFs of tests/test_modalfit.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_modalfit import frf_data, known_model

import workbench.diagnosis.fit as fit_engine
from workbench.diagnosis.fit import fit
from workbench.diagnosis.problem import FrfProblem
from workbench.io.formats import FrfData
from workbench.modal.fit import ModalStructure, fit_modal
from workbench.modal.model import ModalModel, Mode


def random_problem(rng: np.random.Generator) -> FrfProblem:
    """3 inputs x 2 outputs, three modes in 5..200 Hz, D, 5 % complex noise (G_var given)."""
    n_u, n_y = 3, 2
    freq = np.linspace(5.0, 200.0, 300)
    modes = tuple(
        Mode(
            "flexible",
            f,
            z,
            rng.standard_normal(n_u),
            rng.standard_normal(n_y) * (2 * np.pi * f) ** 2,
        )
        for f, z in ((30.0, 0.02), (80.0, 0.01), (150.0, 0.03))
    )
    G = ModalModel(modes=modes, D=rng.standard_normal((n_y, n_u))).frf(freq)
    sig = 0.05 * np.abs(G)
    G = G + sig / np.sqrt(2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    return FrfProblem(FrfData(freq, G, sig**2, 1000.0, ("a", "b", "c"), ("y1", "y2")))


@pytest.mark.parametrize(
    "rigid, upper_hz",
    [(False, None), (False, 300.0), (True, None), (True, 300.0)],
    ids=["modes", "upper", "rigid", "rigid-upper"],
)
def test_jacobian_matches_central_differences(rigid, upper_hz):
    """Golub-Pereyra form (exact): every column within 1e-5 of a central difference.

    The theta is off the optimum (residual not small), so the second Golub-Pereyra term
    (dropped by Kaufman's approximation) matters: it is checked too.
    """
    rng = np.random.default_rng(7)
    problem = random_problem(rng)
    n_u, n_y = 3, 2
    tail = [[upper_hz, np.log(0.03)]] if upper_hz else []
    theta = np.concatenate(
        [[30.3, 79.0, 151.0], np.log([0.025, 0.012, 0.028]), rng.standard_normal(3 * (n_u - 1))]
        + tail
    )
    structure = ModalStructure(
        theta0=theta, pivot=np.array([0, 2, 1]), n_u=n_u, n_y=n_y, rigid=rigid, upper_hz=upper_hz
    )
    base = ModalModel(modes=(), D=np.zeros((n_y, n_u)))

    def residual(th):
        return problem.residual(structure.build(th, problem, base).model)

    J = structure.jacobian(theta, problem, base)
    assert J.shape == (problem.n_obs, theta.size)
    J_fd = np.empty_like(J)
    for t in range(theta.size):
        # step ~ eps^(1/3) |theta|: truncation and round-off of the central difference ~1e-10
        h = 1e-6 * max(1.0, abs(theta[t]))
        step = np.zeros(theta.size)
        step[t] = h
        J_fd[:, t] = (residual(theta + step) - residual(theta - step)) / (2 * h)
    err = np.linalg.norm(J - J_fd, axis=0) / np.linalg.norm(J_fd, axis=0)
    assert np.max(err) < 1e-5, err

    # the normal equations the engine's Levenberg-Marquardt uses, formed without J
    r = residual(theta)
    H, g = structure.normal_equations(theta, problem, base, r)
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-9, atol=1e-11 * np.max(np.abs(H)))
    np.testing.assert_allclose(g, J.T @ r, rtol=1e-9, atol=1e-11 * np.max(np.abs(g)))


class _FiniteDifferences:
    """The structure without its derivatives: the engine falls back to finite differences
    in ``scipy.optimize.least_squares``."""

    def __init__(self, inner):
        self._inner = inner

    def __getattr__(self, name):
        if name in ("jacobian", "normal_equations"):
            raise AttributeError(name)
        return getattr(self._inner, name)


@pytest.mark.parametrize(
    "rigid, above, noise",
    [(False, False, 0.01), (True, False, 0.01), (False, True, 0.01), (False, False, 0.0)],
    ids=["noisy", "noisy-rigid", "noisy-above", "noise-free"],
)
def test_fit_with_analytic_jacobian_equals_the_finite_difference_fit(
    rigid, above, noise, monkeypatch
):
    """Same optimum from the same start (tests/test_modalfit.py FRFs): theta within 2 % of its
    std (noise-free: the modes' parameters within 1e-8 relative), the std within 2 %, the cost
    within 1e-8 relative (noise-free: both relative FRF errors below 1e-10). The reference is
    scipy's trust-region search with finite differences (``FRF_SOLVER = "trf"``)."""
    monkeypatch.setattr(fit_engine, "FRF_SOLVER", "trf")
    data = frf_data(known_model(rigid=rigid, above=above), noise=noise, seed=3)
    res = fit_modal(data, rigid=rigid)
    st = res.result.structure
    problem = FrfProblem(data)
    base = ModalModel(modes=(), D=np.zeros((data.n_y, data.n_u)))
    ref = fit(_FiniteDifferences(st), problem, base, starts=[st.theta0], n_starts=1, max_nfev=100)
    assert res.status == ref.status == "ok"
    if noise:
        assert res.result.cost == pytest.approx(ref.cost, rel=1e-8)
    else:  # both at rounding level (relative FRF errors ~1e-13 and ~1e-11, the latter where
        # the finite-difference steps stop): their costs are not comparable, their errors tiny
        assert max(res.result.error, ref.error) < 1e-10
    if noise:
        np.testing.assert_array_less(np.abs(res.result.theta - ref.theta), 0.02 * ref.theta_std)
        np.testing.assert_allclose(res.result.theta_std, ref.theta_std, rtol=0.02)
    else:
        # the modes' parameters (without a mode above the band the upper pseudo-mode has
        # E = 0: its frequency and damping are undetermined and wander)
        n = 2 * st.n_modes + st.n_modes * (st.n_u - 1)
        np.testing.assert_allclose(res.result.theta[:n], ref.theta[:n], rtol=1e-8)


def test_levenberg_marquardt_matches_scipy_on_a_damped_sine():
    """The engine's normal-equation LM against ``scipy.optimize.least_squares`` (an independent
    implementation) on a 4-parameter damped sine with noise, from the same start: the same
    minimum (cost within 1e-9 relative, parameters within 1e-6), a bound respected."""
    import scipy.optimize

    from workbench.diagnosis.fit import levenberg_marquardt

    rng = np.random.default_rng(11)
    t = np.linspace(0.0, 2.0, 400)
    truth = np.array([1.5, 0.8, 7.0, 0.3])  # amplitude, decay 1/s, rad/s, phase

    def model(p):
        return p[0] * np.exp(-p[1] * t) * np.sin(p[2] * t + p[3])

    y = model(truth) + 0.05 * rng.standard_normal(t.size)

    def residual(p):
        return model(p) - y

    def jac(p):
        e, s, c = np.exp(-p[1] * t), np.sin(p[2] * t + p[3]), np.cos(p[2] * t + p[3])
        return np.column_stack([e * s, -t * p[0] * e * s, t * p[0] * e * c, p[0] * e * c])

    x0 = np.array([1.0, 0.5, 6.5, 0.0])
    lo, hi = np.array([0.0, 0.0, 5.0, -1.0]), np.array([10.0, 5.0, 9.0, 1.0])
    ours = levenberg_marquardt(residual, lambda p, r: (jac(p).T @ jac(p), jac(p).T @ r), x0, lo, hi)
    ref = scipy.optimize.least_squares(
        residual, x0, jac=jac, bounds=(lo, hi), xtol=1e-12, ftol=1e-12, gtol=1e-12
    )
    assert ours.success
    assert ours.cost == pytest.approx(ref.cost, rel=1e-9)
    np.testing.assert_allclose(ours.x, ref.x, rtol=1e-6)
    # the same problem with the phase's optimum (about 0.3) outside a bound: held on it
    hi_tight = hi.copy()
    hi_tight[3] = 0.1
    held = levenberg_marquardt(
        residual, lambda p, r: (jac(p).T @ jac(p), jac(p).T @ r), x0, lo, hi_tight
    )
    assert held.x[3] == pytest.approx(0.1) and held.cost > ours.cost
