"""The noise floor of a periodic record estimated from the spread of its periods.

Oracle: a record built here with a known white output noise, its floor ``||noise|| / ||y||``
computed from the drawn noise itself. The periods' spread holds the noise plus whatever is
not periodic; a stick-slip-like part (bursts of a damped resonance at random instants, as
friction leaves on a beam) inflates it, and the white estimate (the median over frequency
of the spread's spectrum) must stay near the noise.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from workbench.diagnosis import detect
from workbench.io.formats import TimeData

FS, P, N_PER = 1000.0, 500, 8


def _record(bursts: bool, seed: int = 0):
    rng = np.random.default_rng(seed)
    N = P * N_PER
    t = np.arange(N) / FS
    # periodic: a few harmonics of the period, two channels
    k = np.array([3, 7, 19, 40])
    y = np.stack([np.cos(2 * np.pi * np.outer(t, k * FS / P) + c).sum(1) for c in (0.3, 1.1)], 1)
    u = y[:, :1].copy()  # a periodic excitation (the periodic part): the record's time base
    noise = 0.01 * rng.standard_normal(y.shape)
    if bursts:
        # impulses of random size at random instants through a lightly damped 60 Hz
        # resonance: not periodic, in a band, 20x the noise's power
        kicks = np.zeros(N)
        idx = rng.choice(N, 40, replace=False)
        kicks[idx] = rng.normal(0, 1, idx.size)
        b, a = scipy.signal.iirpeak(60.0, 6.0, fs=FS)
        burst = scipy.signal.lfilter(b, a, kicks)
        burst *= np.sqrt(20) * 0.01 / burst.std()
        y = y + np.stack([burst, -0.5 * burst], 1)
    y = y + noise
    floor = float(np.linalg.norm(noise) / np.linalg.norm(y))
    return TimeData(fs=FS, u=u, y=y, period=P), floor


def test_white_record_both_estimates_at_the_noise():
    data, floor = _record(bursts=False)
    assert detect.noise_floor(data) == pytest.approx(floor, rel=0.1)
    assert detect.noise_floor(data, white=True) == pytest.approx(floor, rel=0.1)


def test_a_non_periodic_part_inflates_the_spread_not_the_white_estimate():
    data, floor = _record(bursts=True)
    # the bursts are in the spread (3.8x the noise floor); the resonance's skirts reach every
    # bin, so they lift the median a little (1.3x)
    assert detect.noise_floor(data) > 3 * floor
    assert 0.95 * floor < detect.noise_floor(data, white=True) < 1.5 * floor


def test_white_residual_passes_white_noise_and_fails_a_resonance_below_it():
    """Ljung-Box on a record without periods: white noise passes at the 1e-3 level (2 of
    20 seeds failing would already be a 2e-4 event); a lightly
    damped resonance's response at a tenth of the noise's power (what a port element's
    distortion looks like through the plant) fails, as does a first-order coloured noise."""
    N = 16384
    passes = [
        detect.white_residual(np.random.default_rng(s).standard_normal((N, 3))) for s in range(20)
    ]
    assert sum(passes) >= 18
    rng = np.random.default_rng(7)
    white = rng.standard_normal((N, 2))
    b, a = scipy.signal.iirpeak(60.0, 20.0, fs=FS)
    ring = scipy.signal.lfilter(b, a, rng.standard_normal(N))
    ring *= np.sqrt(0.1) / ring.std()
    assert not detect.white_residual(white + np.c_[ring, np.zeros(N)])
    ar1 = scipy.signal.lfilter([1.0], [1.0, -0.2], rng.standard_normal(N))
    assert not detect.white_residual(np.c_[ar1, white[:, 0]])
