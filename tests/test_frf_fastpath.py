"""The FRF's hot path (one pass over the period spread of all blocks) against a plain,
independently written per-period implementation on random data.

The reference below takes numpy's DFT of every kept period of every block, averages the
spectra, and forms G, the residual of every period and G_var line by line in Python loops:
the textbook definitions (Pintelon & Schoukens, *System Identification*, 2nd ed., 2012,
sections 2.5 and 2.7), nothing shared with the estimator. Data are random (no plant): the
identities hold for any record. Blocks have different lengths, the input repeats bit for bit
in some blocks and not in others, channels differ by orders of magnitude in scale.
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench.io.formats import TimeData
from workbench.signals.frf import frf_multisine
from workbench.signals.periodic import periodic_record

FS = 1000.0  # Hz, any rate
P = 64  # samples per period: small, any even length
N_PERIODS = (5, 4, 6)  # periods per block: unequal on purpose
N_TRANSIENT = 1


def random_record(rng, *, u_varies=(True, False, True), n_u=2, n_y=3) -> TimeData:
    """Three blocks of a random periodic excitation r; u = r plus noise in the blocks flagged
    in ``u_varies`` (else u repeats bit for bit), y a random mix of u plus noise."""
    r, u = [], []
    for n, varies in zip(N_PERIODS, u_varies):
        period = rng.standard_normal((P, n_u)) * np.array([1.0, 1e3])[:n_u]  # N, two scales
        block = np.tile(period, (n, 1))
        r.append(block)
        u.append(block + (1e-2 * rng.standard_normal(block.shape) * block.std(0) if varies else 0))
    r, u = np.vstack(r), np.vstack(u)
    mix = rng.standard_normal((n_u, n_y)) * np.array([1e-6, 1.0, 1e3])[:n_y]  # m/N, 3 scales
    y = u @ mix + 1e-3 * rng.standard_normal((u.shape[0], n_y)) * (u @ mix).std(0)
    return TimeData(fs=FS, u=u, y=y, r=r, period=P)


def direct_multisine(data: TimeData, lines: np.ndarray):
    """G, G_var (noise) and the per-bin output noise of the mean, by per-period DFTs."""
    scale = 2.0 / P
    starts = np.cumsum((0,) + N_PERIODS[:-1])
    spec = {"y": [], "u": [], "r": []}
    for a, n in zip(starts, N_PERIODS):
        for name in spec:
            x = getattr(data, name)[(a + N_TRANSIENT) * P : (a + n) * P]
            spec[name].append(np.fft.rfft(x.reshape(n - N_TRANSIENT, P, -1), axis=1) * scale)
    n_b = len(N_PERIODS)
    n_y, n_u = data.n_y, data.n_u
    G = np.empty((lines.size, n_y, n_u), complex)
    var = np.empty((lines.size, n_y, n_u))
    for i, k in enumerate(lines):
        Y = np.array([s[:, k].mean(axis=0) for s in spec["y"]]).T  # (n_y, n_b)
        U = np.array([s[:, k].mean(axis=0) for s in spec["u"]]).T
        R = np.array([s[:, k].mean(axis=0) for s in spec["r"]]).T
        W = R.conj().T @ np.linalg.inv(U @ R.conj().T)  # (n_b, n_u)
        G[i] = Y @ W
        var_e = np.zeros((n_b, n_y))
        for b in range(n_b):
            Yp, Up = spec["y"][b][:, k], spec["u"][b][:, k]  # (n_p, ch)
            n = Yp.shape[0]
            for p in range(n):
                e = (Yp[p] - Yp.mean(axis=0)) - G[i] @ (Up[p] - Up.mean(axis=0))
                var_e[b] += np.abs(e) ** 2 / (n * (n - 1))
        for j in range(n_y):
            for m in range(n_u):
                var[i, j, m] = sum(var_e[b, j] * abs(W[b, m]) ** 2 for b in range(n_b))
    noise = np.zeros((P // 2 + 1, n_y))
    for s in spec["y"]:
        n = s.shape[0]
        noise += np.sum(np.abs(s - s.mean(axis=0)) ** 2, axis=0) / (n * (n - 1)) / n_b
    return G, var, noise


@pytest.mark.parametrize(
    "u_varies, lines",
    [
        ((True, False, True), np.arange(1, P // 2)),  # closed loop, mixed; one band of lines
        ((False, False, False), np.arange(1, P // 2)),  # open loop: u repeats everywhere
        ((True, True, True), np.array([2, 3, 7, 11, 12, 20, 31])),  # lines not a band
        ((False, False, False), np.array([1, 5, 6, 30])),
    ],
    ids=["mixed-band", "repeats-band", "varies-sparse", "repeats-sparse"],
)
def test_fast_path_equals_per_period_reference(u_varies, lines):
    rng = np.random.default_rng(11)  # any seed: the identities hold for every record
    data = random_record(rng, u_varies=u_varies)
    est = frf_multisine(data, lines=lines, zoh="none", n_transient=N_TRANSIENT)
    G, var, noise = direct_multisine(data, lines)
    # rounding only: both are float64 with DFTs of the same periods (rtol 1e-9 as in
    # tests/test_frf_estimation.py's direct implementation)
    np.testing.assert_allclose(est.frf.G, G, rtol=1e-9, atol=1e-12 * np.abs(G).max())
    np.testing.assert_allclose(est.G_var_noise, var, rtol=1e-9)
    band = np.arange(lines[0], lines[-1] + 1)
    np.testing.assert_allclose(est.lines.noise_var, noise[band], rtol=1e-9)


def test_spread_powers_equal_per_block_dfts_with_repeating_and_single_period_blocks():
    rng = np.random.default_rng(5)  # any seed
    data = random_record(rng, u_varies=(True, False, True))
    rec = periodic_record(data, n_transient=N_TRANSIENT)
    x = rng.standard_normal((data.n_samples, 3)) * np.array([1.0, 1e6, 1e-6])  # three scales
    for sig in ("y", "u", x):
        got = rec.spread_powers(sig)
        for b, p in enumerate(rec.periods(sig)):
            D = np.fft.rfft(p - p.mean(axis=0), axis=1)
            want = np.sum(np.abs(D) ** 2, axis=0)
            if isinstance(sig, str) and rec.repeats[sig][b]:
                want = np.zeros_like(want)  # identical periods: exactly no spread
            np.testing.assert_allclose(got[b], want, rtol=1e-12, atol=0)
            np.testing.assert_allclose(rec.spread_power(sig, b), got[b], rtol=1e-12, atol=0)
    # no transient dropped, one period kept per block: no spread, no variance
    one = TimeData(fs=FS, u=data.u[: 2 * P], y=data.y[: 2 * P], period=P)
    rec1 = periodic_record(one, n_transient=1)
    assert rec1.n_kept.tolist() == [1]
    np.testing.assert_array_equal(rec1.spread_powers("y"), 0.0)
    assert np.all(np.isnan(rec1.noise_var("y")))
