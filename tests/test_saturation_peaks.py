"""The saturation levels' peak scan (``_scan_peaks``): trial levels by shifted pulse responses.

A trial level among an input's largest peaks clips only a few samples, so the scan scores it
as the simulation with that input unclipped less a shifted pulse response per clipped sample.
Checked here against the definition, written independently: every trial scored by a whole
simulation of the clipped input with scipy's ``cont2discrete`` / ``dlsim``, in the same search.
The model has a free rigid body (a from-rest simulation integrates a level error twice, what
makes the error steep in the level) and a whole-sample input delay.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from workbench.core.model import LTIModel
from workbench.diagnosis.nonlinear import SATURATION_PEAKS, _scan_peaks

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


def _reference_scan(A, B, C, D, u, y, level, err, sweeps):
    """The scan as defined: each input's level at its largest peaks, then a bounded search
    between the best one's neighbours, every trial a whole simulation."""
    level = np.array(level, float)
    amp = np.abs(u)
    for _ in range(sweeps):
        for j in range(u.shape[1]):
            peaks = np.unique(amp[:, j])[::-1][: SATURATION_PEAKS + 1]

            def cost(x, j=j):
                trial = level.copy()
                trial[j] = x
                return _reference_error(A, B, C, D, u, y, trial)

            errs = [cost(p) for p in peaks]
            k = int(np.argmin(errs))
            lo, hi = peaks[min(k + 1, peaks.size - 1)], peaks[max(k - 1, 0)]
            x, e = peaks[k], errs[k]
            sol = scipy.optimize.minimize_scalar(
                cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-7 * hi}
            )
            if sol.fun < e:
                x, e = float(sol.x), float(sol.fun)
            if e < err:
                level[j], err = x, e
    return level, err


@pytest.fixture(scope="module")
def record():
    rng = np.random.default_rng(5)
    A, B, C, D = _plant()
    n = 3000
    sos = scipy.signal.butter(2, 60.0, fs=FS, output="sos")
    u = scipy.signal.sosfilt(sos, rng.standard_normal((n, 2)), axis=0)
    u -= u.mean(0)
    u /= u.std(0)
    # the true levels sit between the 4th and 5th largest |u| of input 0, the 2nd and 3rd of
    # input 1 (a slight clipping: a few peaks)
    top = np.sort(np.abs(u), axis=0)[::-1]
    true = np.array([0.5 * (top[3, 0] + top[4, 0]), 0.3 * top[1, 1] + 0.7 * top[2, 1]])
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
    assert err < 0.2 * err0


def test_scan_ends_where_the_whole_simulation_scan_ends(record):
    model, abcd, u, y, _ = record
    start = np.full(2, np.inf)
    err0 = _reference_error(*abcd, u, y, start)
    level, err = _scan_peaks(model, np.arange(2), u, y, FS, start, err0, sweeps=2)
    ref_level, ref_err = _reference_scan(*abcd, u, y, start, err0, sweeps=2)
    np.testing.assert_allclose(level, ref_level, rtol=1e-6)
    assert err == pytest.approx(ref_err, rel=1e-6)


def test_scan_holds_a_level_it_cannot_better(record):
    """Started at the levels the simulation fits best, the scan keeps them (a trial must
    lower the error)."""
    model, abcd, u, y, true = record
    err_true = _reference_error(*abcd, u, y, true)
    level, err = _scan_peaks(model, np.arange(2), u, y, FS, true, err_true, sweeps=1)
    assert err <= err_true
    np.testing.assert_allclose(level, true, rtol=0.02)
