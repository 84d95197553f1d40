"""The bounded Levenberg-Marquardt of the diagnosis: a parameter held on its bound, and the
judgement of a search stopped by its budget.

Checked against scipy's bounded linear least squares (``lsq_linear``, an independent solver)
on problems whose optimum lies on a bound, with parameters coupled to the held one.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from workbench.diagnosis.fit import SETTLED_GAIN, _settled, levenberg_marquardt


def _linear(seed: int, n: int = 200, p: int = 4, coupling: float = 0.9):
    """A residual ``A x - b`` with correlated columns; the optimum of parameter 0 below 0."""
    rng = np.random.default_rng(seed)
    base = rng.standard_normal((n, 1))
    A = coupling * base + np.sqrt(1 - coupling**2) * rng.standard_normal((n, p))
    x_true = np.array([-0.5, 1.0, 2.0, -1.0])[:p]
    b = A @ x_true + 0.01 * rng.standard_normal(n)
    return A, b


def _normal(A):
    return lambda x, r: (A.T @ A, A.T @ r)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_parameter_on_its_bound_is_held_and_the_others_converge(seed):
    A, b = _linear(seed)
    lo = np.array([0.0, -10, -10, -10])  # parameter 0 wants -0.5: held at 0
    hi = np.full(4, 10.0)
    res = levenberg_marquardt(
        lambda x: A @ x - b, _normal(A), np.array([0.5, 0, 0, 0]), lo, hi, max_nfev=60
    )
    ref = scipy.optimize.lsq_linear(A, b, bounds=(lo, hi), tol=1e-12)
    assert res.success, res.message
    # a linear problem: a handful of evaluations (the projected full step crept: 60)
    assert res.nfev <= 15
    assert res.x[0] == 0.0
    assert np.allclose(res.x, ref.x, atol=1e-6)
    assert 2 * res.cost == pytest.approx(float(np.sum((A @ ref.x - b) ** 2)), rel=1e-9)


def test_a_parameter_leaves_its_bound_when_the_gradient_pulls_it_inwards():
    A, b = _linear(3)
    lo = np.array([-10.0, -10, -10, 1.5])  # parameter 3 starts on its bound, wants -1 ... held
    hi = np.array([10.0, 10, 10, 10])
    start = np.array([0.0, 0.0, 0.0, 1.5])
    res = levenberg_marquardt(lambda x: A @ x - b, _normal(A), start, lo, hi, max_nfev=60)
    ref = scipy.optimize.lsq_linear(A, b, bounds=(lo, hi), tol=1e-12)
    assert res.x[3] == 1.5
    assert np.allclose(res.x, ref.x, atol=1e-4)
    assert 2 * res.cost == pytest.approx(float(np.sum((A @ ref.x - b) ** 2)), rel=1e-9)
    # ... and one started on a bound it should leave (its optimum inside) leaves it
    lo2 = np.array([-10.0, -10, -10, -2.0])
    res2 = levenberg_marquardt(
        lambda x: A @ x - b, _normal(A), np.array([0.0, 0, 0, -2.0]), lo2, hi, max_nfev=60
    )
    assert res2.success
    assert res2.x[3] == pytest.approx(-1.0, abs=0.01)


def test_a_search_stopped_by_its_budget_is_settled_only_near_its_optimum():
    A, b = _linear(4)
    lo, hi = np.full(4, -10.0), np.full(4, 10.0)
    x_opt = np.linalg.lstsq(A, b, rcond=None)[0]
    r_opt = A @ x_opt - b
    sigma2 = float(r_opt @ r_opt) / (A.shape[0] - 4)
    cov = np.linalg.inv(A.T @ A) * sigma2

    def result(x):
        r = A @ x - b
        return scipy.optimize.OptimizeResult(x=x, gram=A.T @ A, grad=A.T @ r, fun=r, jac=A)

    # a tenth of a std off the optimum along the first axis of the covariance: settled
    w, V = np.linalg.eigh(cov)
    near = x_opt + 0.1 * np.sqrt(w[-1]) * V[:, -1]
    far = x_opt + 3.0 * np.sqrt(w[-1]) * V[:, -1]
    assert _settled(result(near), lo, hi, sigma2)
    assert not _settled(result(far), lo, hi, sigma2)
    # the same judgement from a Jacobian (scipy's trust region returns no normal equations)
    for x, expected in ((near, True), (far, False)):
        r = A @ x - b
        res = scipy.optimize.OptimizeResult(x=x, jac=A, fun=r)
        assert _settled(res, lo, hi, sigma2) is expected
    # the threshold: the Gauss-Newton gain in noise variances
    d = far - x_opt
    gain = float(d @ A.T @ A @ d)
    assert gain > SETTLED_GAIN * sigma2


def test_a_parameter_pushed_against_its_bound_does_not_count_as_unsettled():
    A, b = _linear(5)
    lo = np.array([0.0, -10, -10, -10])
    hi = np.full(4, 10.0)
    ref = scipy.optimize.lsq_linear(A, b, bounds=(lo, hi), tol=1e-12)
    r = A @ ref.x - b
    sigma2 = float(r @ r) / (A.shape[0] - 4)
    res = scipy.optimize.OptimizeResult(x=ref.x, gram=A.T @ A, grad=A.T @ r, fun=r)
    # the unbounded Gauss-Newton step would move parameter 0 far below its bound
    assert _settled(res, lo, hi, sigma2)
