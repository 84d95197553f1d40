"""The saturation levels' exact profile (``_level_profile``) and the peak scan built on it.

Between two consecutive amplitudes of an input the clipped samples are the same, so the
output is linear and the error squared quadratic in that input's level; the profile walks
down the amplitudes adding shifted pulse responses. Checked here against the definition,
written independently: every level scored by a whole simulation of the clipped input with
scipy's ``cont2discrete`` / ``dlsim``. The model has a free rigid body (a from-rest
simulation integrates a level error twice, what makes the error steep and rough in the
level) and a whole-sample input delay.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from workbench.core.model import LTIModel
from workbench.diagnosis.nonlinear import _level_profile, _scan_peaks

FS = 1000.0
DELAY_SAMPLES = 2


def _plant():
    """2 inputs x 2 outputs: a free rigid body (mass 2 kg) and modes at 40 and 130 Hz."""
    blocks_A, blocks_B, blocks_C = [], [], []
    for f, zeta, b, c in (
        (0.0, 0.0, [0.5, 0.5], [1.0, 1.0]),
        (40.0, 0.02, [0.8, -0.3], [0.6, -0.9]),
        (130.0, 0.01, [0.2, 0.7], [-0.4, 0.5]),
    ):
        w = 2 * np.pi * f
        blocks_A.append(np.array([[0.0, 1.0], [-(w**2), -2 * zeta * w]]))
        blocks_B.append(np.array([[0.0, 0.0], b]))
        blocks_C.append(np.array([c, [0.0, 0.0]]).T)
    A = np.zeros((6, 6))
    for k, a in enumerate(blocks_A):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = a
    return A, np.vstack(blocks_B), np.hstack(blocks_C), np.zeros((2, 2))


def _reference_error(A, B, C, D, u, y, level):
    """||y - y_sat|| / ||y||, y_sat simulated whole by scipy (ZOH, delay as shifted input)."""
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, B, C, D), 1.0 / FS, method="zoh")
    v = np.clip(u, -level, level)
    v = np.vstack([np.zeros((DELAY_SAMPLES, u.shape[1])), v[: u.shape[0] - DELAY_SAMPLES]])
    _, y_sat, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, 1.0 / FS), v)
    return float(np.linalg.norm(y - y_sat) / np.linalg.norm(y))


@pytest.fixture(scope="module")
def record():
    rng = np.random.default_rng(5)
    A, B, C, D = _plant()
    n = 3000
    sos = scipy.signal.butter(2, 60.0, fs=FS, output="sos")
    u = scipy.signal.sosfilt(sos, rng.standard_normal((n, 2)), axis=0)
    u -= u.mean(0)
    u /= u.std(0)
    # input 0 slightly clipped (between its 4th and 5th largest |u|), input 1 on 4 % of its
    # samples
    top = np.sort(np.abs(u), axis=0)[::-1]
    true = np.array([0.5 * (top[3, 0] + top[4, 0]), 0.5 * (top[119, 1] + top[120, 1])])
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, B, C, D), 1.0 / FS, method="zoh")
    v = np.clip(u, -true, true)
    v = np.vstack([np.zeros((DELAY_SAMPLES, 2)), v[: n - DELAY_SAMPLES]])
    _, y0, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, 1.0 / FS), v)
    y = y0 + 1e-4 * np.std(y0) * rng.standard_normal(y0.shape)
    model = LTIModel(A, B, C, D, delay_s=DELAY_SAMPLES / FS)
    return model, (A, B, C, D), u, y, true


def test_scan_scores_levels_as_the_whole_simulation(record):
    model, abcd, u, y, _ = record
    start = np.full(2, np.inf)
    err0 = _reference_error(*abcd, u, y, start)
    level, err = _scan_peaks(model, np.arange(2), u, y, FS, start, err0, sweeps=2)
    # the error it reports is the error of the levels it reports, simulated whole
    assert err == pytest.approx(_reference_error(*abcd, u, y, level), rel=1e-9)
    assert err < 0.6 * err0  # (input 1 clips more samples than the peaks it scans)


@pytest.mark.parametrize("j", [0, 1])
def test_profile_is_the_best_level_of_the_whole_simulation(record, j):
    """Over the levels clipping up to 40 samples of input j: the profile's level fits at
    least as well as any level of a dense grid (every amplitude it passes and 7 levels
    between each two), each scored by a whole simulation, and its error is its level's."""
    model, abcd, u, y, true = record
    held = true.copy()
    k_max = 40
    level, err = _level_profile(model, np.arange(2), u, y, FS, held, j, k_max)
    trial = held.copy()
    trial[j] = level
    assert err == pytest.approx(_reference_error(*abcd, u, y, trial), rel=1e-9)
    amps = np.sort(np.abs(u[:, j]))[::-1][: k_max + 1]
    grid = np.concatenate(
        [np.linspace(a, b, 8, endpoint=False) for a, b in zip(amps[:-1], amps[1:])] + [amps[-1:]]
    )
    best = np.inf
    for x in grid:
        trial[j] = x
        best = min(best, _reference_error(*abcd, u, y, trial))
    assert err <= best * (1 + 1e-9)


def test_profile_finds_a_clipped_input_left_unclipped(record):
    """Input 1 clips 4 % of its samples; started unclipped (its level at its largest |u|,
    where the least squares' box ends), the profile over 10 % of the samples finds its level
    and the error falls to the noise the record carries."""
    model, abcd, u, y, true = record
    start = true.copy()
    start[1] = np.abs(u[:, 1]).max()
    err_true = _reference_error(*abcd, u, y, true)
    level, err = _level_profile(model, np.arange(2), u, y, FS, start, 1, u.shape[0] // 10)
    assert level == pytest.approx(true[1], rel=2e-3)
    assert err <= 1.01 * err_true
    assert _reference_error(*abcd, u, y, start) > 10 * err_true


def test_scan_holds_a_level_it_cannot_better(record):
    """Started at the levels the simulation fits best, the scan keeps them (a trial must
    lower the error)."""
    model, abcd, u, y, true = record
    err_true = _reference_error(*abcd, u, y, true)
    level, err = _scan_peaks(model, np.arange(2), u, y, FS, true, err_true, sweeps=1)
    assert err <= err_true
    np.testing.assert_allclose(level, true, rtol=0.02)
