"""workbench.scan: 4th-order setpoints (limits checked analytically) and MA / MSD figures."""

from __future__ import annotations

import numpy as np
import pytest

from workbench.core.errors import InputError
from workbench.scan import (
    ScanLimits,
    moving_average_std,
    point_to_point,
    scan,
    tracking_figures,
)

FS = 5000.0  # the wafer stage's rate, Hz
# limits of a short-stroke stage move (SI): every duration T1..T4 then binds one limit
LIMITS = ScanLimits(velocity=0.25, acceleration=10.0, jerk=2e3, snap=1e6)

CASES = {
    # long move: every limit binding (T1 = D/v > T2 + T3 + T4)
    "long": (0.02, LIMITS),
    # short move: the velocity limit is not reached
    "short": (1e-4, LIMITS),
    # snap-dominated: T4 = j/s larger than a/j
    "snap_bound": (0.01, ScanLimits(0.2, 5.0, 1e4, 1e6)),
}


def _rtol_peak(x, limit):
    # the sampled peak may miss the analytic one; never exceed it beyond rounding
    return np.max(np.abs(x)) <= limit * (1 + 1e-9)


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_limits_hold_and_final_position_is_exact(case):
    distance, lim = CASES[case]
    p = point_to_point(distance, lim, FS, settle_s=0.01)
    assert _rtol_peak(p.velocity, lim.velocity)
    assert _rtol_peak(p.acceleration, lim.acceleration)
    assert _rtol_peak(p.jerk, lim.jerk)
    assert _rtol_peak(p.snap, lim.snap)
    assert p.position[-1] == distance
    assert p.velocity[-1] == 0.0 and p.acceleration[-1] == 0.0
    assert p.position[0] == 0.0 and p.velocity[0] == 0.0
    T1, T2, T3, T4 = p.durations_s
    # the non-overlap conditions that make the peaks D/T1, D/(T1 T2), ... exact
    assert T3 >= T4 and T2 >= T3 + T4 - 1e-15 and T1 >= T2 + T3 + T4 - 1e-15


def test_binding_limits_are_reached_on_a_long_move():
    """A long move reaches the peaks D/T1 = v, D/(T1 T2) = a ... (analytic, module notes)."""
    distance, lim = CASES["long"]
    p = point_to_point(distance, lim, 1e6)  # 1 MHz: the samples land within 1e-6 s of each peak
    T1, T2, T3, T4 = p.durations_s
    assert T1 == pytest.approx(distance / lim.velocity)
    assert np.max(np.abs(p.velocity)) == pytest.approx(lim.velocity, rel=1e-9)
    assert np.max(np.abs(p.acceleration)) == pytest.approx(distance / (T1 * T2), rel=1e-6)
    assert np.max(np.abs(p.snap)) == pytest.approx(lim.snap, rel=1e-9)


def test_derivatives_are_consistent():
    """Each signal is the integral of the next (trapezoid on a fine grid, independent check)."""
    p = point_to_point(0.02, LIMITS, 2e5)
    dt = 1 / p.fs
    pairs = [
        (p.position, p.velocity),
        (p.velocity, p.acceleration),
        (p.acceleration, p.jerk),
        (p.jerk, p.snap),
    ]
    for x, dx in pairs:
        integral = x[0] + np.concatenate([[0.0], np.cumsum((dx[1:] + dx[:-1]) / 2 * dt)])
        # trapezoid error: at most max|dx| dt per jump of dx (the snap has 16), else far less
        tol = 16 * np.max(np.abs(dx)) * dt
        assert np.max(np.abs(integral - x)) <= tol


def test_scan_holds_velocity_over_the_scan_length():
    v, length = 0.2, 0.01
    p = scan(v, length, LIMITS, FS, lead_s=0.002, settle_s=0.02)
    t0, t1 = p.constant_velocity_s
    assert t1 - t0 == pytest.approx(length / v)
    inside = (p.t >= t0 + 1e-9) & (p.t <= t1 - 1e-9)
    assert np.allclose(p.velocity[inside], v, rtol=1e-9)
    assert np.allclose(p.acceleration[inside], 0.0, atol=1e-9 * LIMITS.acceleration)
    assert p.position[-1] == pytest.approx(p.distance, rel=0, abs=0)
    assert np.all(p.position[p.t < 0.002] == 0.0)


def test_bad_input_is_refused():
    with pytest.raises(InputError, match="ScanLimits.jerk: expected a finite value > 0"):
        ScanLimits(1.0, 1.0, -1.0, 1.0)
    with pytest.raises(InputError, match="velocity: expected at most limits.velocity"):
        scan(1.0, 0.01, LIMITS, FS)
    with pytest.raises(InputError, match="distance"):
        point_to_point(0.0, LIMITS, FS)


def _direct(e, n):
    """MA / MSD by an explicit loop over the windows (independent implementation)."""
    rows = e.shape[0] - n + 1
    ma = np.empty((rows, e.shape[1]))
    msd = np.empty_like(ma)
    for k in range(rows):
        for c in range(e.shape[1]):
            w = e[k : k + n, c]
            ma[k, c] = sum(w) / n
            msd[k, c] = (sum((x - ma[k, c]) ** 2 for x in w) / n) ** 0.5
    return ma, msd


def test_moving_average_and_std_match_a_direct_loop():
    rng = np.random.default_rng(5)
    # a nm-level error riding on an offset (the cancellation the centring guards against)
    e = 1e-9 * rng.standard_normal((300, 3)) + np.array([1e-6, 0.0, -3e-9])
    for n in (1, 7, 50, 300):
        ma, msd = moving_average_std(e, n)
        ma_ref, msd_ref = _direct(e, n)
        np.testing.assert_allclose(ma, ma_ref, rtol=1e-9, atol=1e-21)
        # atol: 1e-6 of the 1e-9 error level (rounding of the running sums, amplified by sqrt)
        np.testing.assert_allclose(msd, msd_ref, rtol=1e-6, atol=1e-15)


def test_tracking_figures_over_the_constant_velocity_part():
    fs = 1000.0
    t = np.arange(1000) / fs
    # error: a sine of amplitude 1 (period 10 ms) plus a ramp; the windows (10 ms = one period)
    # see a mean equal to the ramp's centre value and std of the sine 1/sqrt(2)
    e = (np.sin(2 * np.pi * 100 * t) + 0.01 * t)[:, None]
    during = (0.2, 0.5)
    fig = tracking_figures(e, fs, window_s=0.01, during=during)
    k0, k1 = 200, 501
    ma_ref, msd_ref = _direct(e[k0:k1], 10)
    assert fig.n_windows == k1 - k0 - 10 + 1
    assert fig.ma_max[0] == pytest.approx(np.max(np.abs(ma_ref)), rel=1e-9)
    assert fig.msd_max[0] == pytest.approx(np.max(msd_ref), rel=1e-9)
    assert fig.msd_max[0] == pytest.approx(1 / np.sqrt(2), rel=1e-3)
    assert fig.rms[0] == pytest.approx(np.sqrt(np.mean(e[k0:k1, 0] ** 2)))
    with pytest.raises(InputError, match="window_s: expected an exposure window within"):
        tracking_figures(e, fs, window_s=0.5, during=during)
