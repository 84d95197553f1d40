"""The rigid body's double pole at the origin, sampled in closed form and run as two sums.

Against the analytic step response (a held step is sampled exactly by the ZOH), with a
fractional input delay and behind lags; and smooth in the lag: a change of 1e-12 in tau
moves the response by rounding only (the matrix exponential's coefficients and a
direct-form recursion through a double pole at z = 1 moved it by ~1e-8 of itself).
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench.modal import simulate as S

DT = 1e-4
N = 20000


def _step(num, den, delay):
    return S.zoh_filter(num, den, np.ones(N), DT, delay)


@pytest.mark.parametrize("delay", [0.0, 0.37 * DT, 2.6 * DT])
def test_a_double_integrator_is_exact_at_the_samples(delay):
    t = np.arange(N) * DT - delay
    exact = np.where(t > 0, 0.5 * t**2, 0.0)
    y = _step([1.0], [1.0, 0.0, 0.0], delay)
    assert np.max(np.abs(y - exact)) <= 1e-12 * np.max(exact)


@pytest.mark.parametrize("tau", [2e-5, 3e-4, 1e-2])
@pytest.mark.parametrize("delay", [0.0, 0.4 * DT])
def test_a_rigid_body_behind_a_lag_is_exact_at_the_samples(tau, delay):
    # 1 / (s^2 (1 + s tau)): t^2/2 - tau t + tau^2 (1 - exp(-t / tau)) for t > 0
    t = np.arange(N) * DT - delay
    tp = np.maximum(t, 0.0)
    exact = np.where(t > 0, 0.5 * tp**2 - tau * tp - tau**2 * np.expm1(-tp / tau), 0.0)
    y = _step([1.0], np.convolve([1.0, 0.0, 0.0], [tau, 1.0]), delay)
    assert np.max(np.abs(y - exact)) <= 1e-11 * np.max(exact)


def test_a_rigid_body_behind_two_lags_matches_the_state_space_discretization():
    from workbench.sim import c2d_zoh

    den = np.convolve(np.convolve([1.0, 0.0, 0.0], [3e-4, 1.0]), [1e-3, 1.0])
    den = den / den[0]
    n = den.size - 1
    A = np.zeros((n, n))
    A[0] = -den[1:]
    A[1:, :-1] = np.eye(n - 1)
    B = np.zeros((n, 1))
    B[0, 0] = 1.0
    C = np.zeros((1, n))
    C[0, -1] = 1.0  # 1 / den
    Ad, B0, B1, _ = c2d_zoh(A, B, DT, delay_s=0.3 * DT)
    rng = np.random.default_rng(2)
    u = rng.standard_normal(3000)
    x, prev, ref = np.zeros((n, 1)), 0.0, np.empty(u.size)
    for k in range(u.size):
        ref[k] = (C @ x)[0, 0]
        x = Ad @ x + B0 * u[k] + B1 * prev
        prev = u[k]
    y = S.zoh_filter([1.0], den, u, DT, 0.3 * DT)
    assert np.max(np.abs(y - ref)) <= 1e-8 * np.max(np.abs(ref))


def test_the_sampled_rigid_body_is_smooth_in_its_lag():
    rng = np.random.default_rng(1)
    u = rng.standard_normal(16384)

    def response(tau):
        return S.zoh_filter([1.0], np.convolve([1.0, 0.0, 0.0], [tau, 1.0]), u, DT, 0.2 * DT)

    y0 = response(3e-4)
    scale = np.max(np.abs(y0))
    for rel in (1e-12, 1e-10):
        moved = response(3e-4 * (1 + rel))
        # the true change is ~rel tau / T of the response, ~1e-4 rel here: rounding only
        assert np.max(np.abs(moved - y0)) <= 1e-12 * scale
