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


def _line_noise(rng, n_f, shape=(3, 2)):
    """Complex noise independent from line to line, its level 1 to 3x across a resonance."""
    f = np.linspace(1.0, 2000.0, n_f)
    level = 1 + 2 * np.exp(-(((f - 500) / 20) ** 2))
    z = rng.standard_normal((n_f,) + shape) + 1j * rng.standard_normal((n_f,) + shape)
    return f, level[:, None, None] * z / np.sqrt(2)


def test_frf_structure_share_bounds_what_is_not_line_noise():
    """An FRF residual across its lines: for noise independent from line to line, whatever
    its level does (within a few times: a few lines holding most of the power weaken the
    bound, towards searching on), the bound is small (about 0.9 / sqrt(n_f) + 2.6 /
    sqrt(n_f n_ch): 0.06 on 2000 lines of 6 channels); an error smooth across the
    lines, its phase turning, or a few lines far above their neighbours (a mode narrower
    than the spacing), holding a share q of the power, is bounded from above by at least q;
    noise correlated between neighbouring lines (leakage) is not line noise; too few lines
    give no bound (1)."""
    shares = [
        detect.frf_structure_share(_line_noise(np.random.default_rng(s), 2000)[1])
        for s in range(20)
    ]
    assert max(shares) < 0.08
    rng = np.random.default_rng(3)
    f, E = _line_noise(rng, 2000)
    E = E / (1 + 2 * np.exp(-(((f - 500) / 20) ** 2)))[:, None, None]
    power = np.sum(np.abs(E) ** 2)
    for q in (0.1, 0.3):
        smooth = E.copy()  # on one channel of six, amplitude smooth, phase turning
        smooth[:, 0, 0] += np.sqrt(q / (1 - q) * power / f.size) * np.exp(2j * np.pi * f / 7)
        assert q <= detect.frf_structure_share(smooth) <= q + 0.05
        spike = E.copy()  # three lines of one channel
        spike[700:703, 1, 1] += np.sqrt(q / (1 - q) * power / 3)
        # (counted both as correlated and as lines above their neighbours: an upper bound)
        assert q <= detect.frf_structure_share(spike) <= 3 * q + 0.08
    leaky = E[1:] + E[:-1]  # a Hann window's neighbouring bins share half their input
    assert detect.frf_structure_share(leaky) > 0.3
    assert detect.frf_structure_share(E[:40]) == 1.0
