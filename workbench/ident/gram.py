"""Gram matrices of block-Hankel data matrices, from correlation sums.

A subspace method needs the row space of a block-Hankel matrix ``H`` with
``n_rows = n_blocks * n_ch`` rows and ``j = N - n_blocks + 1`` columns. Its
Gram ``H H^T`` has the structure of the data: block ``(a, a + d)`` is a lagged
correlation sum over a window of ``j`` samples, i.e. the block-Toeplitz matrix
of the ``n_blocks`` full-record lagged sums minus a low-rank edge term. The
lagged sums come from FFTs of short overlapping segments accumulated in the
frequency domain (:func:`lag_sums`, ``O(N n_ch^2)`` work, in chunks of time so
memory stays ``O(chunk * n_ch + n_rows^2)`` whatever ``N``); the edge term is
one product of the first and last ``n_blocks - 1`` samples. ``H`` is never formed.

:func:`hankel` builds ``H`` itself, for the QR reference path and for tests.
"""

from __future__ import annotations

import numpy as np
import scipy.fft
import scipy.linalg.blas
from numpy.lib.stride_tricks import as_strided

__all__ = ["hankel_gram", "hankel", "lag_sums", "stacked_signals"]


def stacked_signals(signals, scales, start: int, stop: int) -> np.ndarray:
    """Samples ``start:stop`` of the signals, scaled and side by side.

    Parameters
    ----------
    signals : sequence of (N_s, n_s) arrays
        The channels, each already aligned so that row ``k`` is time ``k``.
    scales : sequence of (n_s,) arrays
        Each signal is divided by its scale (channel normalization).
    start, stop : int
        Sample range.

    Returns
    -------
    (stop - start, sum n_s) array
    """
    return np.hstack([s[start:stop] / c for s, c in zip(signals, scales)])


def hankel_gram(
    signals, scales, *, n_blocks: int, n_samples: int, chunk: int = 4096, rows=None
) -> np.ndarray:
    """Gram ``H H^T`` of the block-Hankel matrix of stacked signals.

    Parameters
    ----------
    signals : sequence of (N, n_s) arrays
        Channels that are stacked per sample into ``z_t`` (n_ch,) in this order.
    scales : sequence of (n_s,) arrays
        Channel scales (the Gram is that of the scaled data).
    n_blocks : int
        Number of block rows ``2 i`` (past and future).
    n_samples : int
        Samples used, ``N``; ``j = N - n_blocks + 1`` columns.
    chunk : int
        Samples per chunk of the correlation sums (bounds memory; rounded to
        whole FFT segments, at least one).
    rows : (n_sel,) int array, optional
        Only these rows of the Gram (all its columns): a closed-loop method
        needs the rows of the excitation alone, a third of the Gram or less.

    Returns
    -------
    (n_blocks * n_ch, n_blocks * n_ch) array, or (n_sel, n_blocks * n_ch) with ``rows``
        Row ``a * n_ch + p`` belongs to block row ``a``, channel ``p``:
        ``G[(a, p), (b, q)] = sum_{t=0}^{j-1} z_{t+a, p} z_{t+b, q}``.

    Notes
    -----
    With ``F_d = sum_{t=0}^{N-1-d} z_t z_{t+d}^T`` the full-record lag-``d``
    correlation sum, block ``(a, a + d)`` of the Gram is
    ``F_d - sum_{t<a} z_t z_{t+d}^T - sum_{t=a+j}^{N-1-d} z_t z_{t+d}^T``; both
    corrections have fewer than ``n_blocks`` terms, and block ``(a + d, a)`` is
    the transpose. The ``F_d`` come from :func:`lag_sums` (FFT segments).
    """
    N = int(n_samples)
    k = int(n_blocks)
    m = sum(np.shape(c)[0] for c in scales)
    F = lag_sums(signals, scales, n_lags=k, n_samples=N, chunk=chunk)  # (k, m, m)

    # Edge corrections: G = T - E E^T, T block-Toeplitz of the F_d. With
    # tau = 1 .. k - 1, head block a of E holds z_{a - tau} (zero for a < tau): its
    # products give sum_{t<a} z_t z_{t+d}^T. With sigma = 0 .. k - 2, tail block a holds
    # z_{a + j + sigma} (zero past N - 1): sum_{t >= a + j} z_t z_{t+d}^T.
    # k - 1 zeros, samples 0 .. k - 2, samples j .. N - 1, k - 1 zeros (tail rows read to 4k - 5)
    ends = np.zeros((4 * k - 4, m))
    got = stacked_signals(signals, scales, 0, min(N, k - 1))
    ends[k - 1 : k - 1 + got.shape[0]] = got
    ends[2 * k - 2 : 3 * k - 3] = stacked_signals(signals, scales, N - k + 1, N)
    s0, s1 = ends.strides
    # E[a, p, c]: c < k - 1 is tau = c + 1 (sample a - tau), c >= k - 1 is sigma = c - k + 1
    head = as_strided(ends[k - 2 :], (k, m, k - 1), (s0, s1, -s0), writeable=False)
    tail = as_strided(ends[2 * k - 2 :], (k, m, k - 1), (s0, s1, s0), writeable=False)
    E = np.concatenate([head, tail], axis=2).reshape(k * m, 2 * k - 2)

    # T: block (a, b) = F_{b - a} (b >= a) or F_{a - b}^T, gathered from all 2k - 1 lags
    # Fx[p, k - 1 + d, q] = F_d[p, q], Fx[p, k - 1 - d, q] = F_d[q, p]: block (a, b) of T
    # is Fx[:, k - 1 + b - a, :], a strided view of Fx (a steps back, b forward)
    Fx = np.concatenate([F[:0:-1].transpose(0, 2, 1), F]).transpose(1, 0, 2).copy()
    f0, f1, f2 = Fx.strides
    T = as_strided(Fx[:, k - 1 :], (k, m, k, m), (-f1, f0, f1, f2), writeable=False)
    if rows is not None:
        rows = np.asarray(rows, int)
        G = T[rows // m, rows % m].reshape(rows.size, k * m)  # the selected rows, gathered
        # G -= E[rows] E^T, in place (BLAS on the transposes: G.T is Fortran-ordered)
        return scipy.linalg.blas.dgemm(
            -1.0, E.T, E[rows].T, beta=1.0, c=G.T, trans_a=1, overwrite_c=1
        ).T
    G = T.reshape(k * m, k * m)  # a copy (the view is not contiguous)
    # G -= E E^T in place: a fresh (k m)^2 temporary costs more in page faults than the
    # product itself; G is symmetric, so its transpose is the Fortran array BLAS updates
    # (the returned array is G.T itself unless BLAS had to copy; either way it is the result)
    return scipy.linalg.blas.dgemm(-1.0, E.T, E.T, beta=1.0, c=G.T, trans_a=1, overwrite_c=1).T


def lag_sums(signals, scales, *, n_lags: int, n_samples: int, chunk: int = 4096) -> np.ndarray:
    """Lagged correlation sums ``F_d = sum_{t=0}^{N-1-d} z_t z_{t+d}^T``, d < n_lags.

    Parameters
    ----------
    signals, scales
        As for :func:`hankel_gram` (the sums are of the scaled, stacked ``z_t``).
    n_lags : int
        Number of lags ``K`` (0 .. K - 1).
    n_samples : int
        Samples used, ``N``.
    chunk : int
        Samples per chunk (memory ``O(chunk * n_ch + K n_ch^2)``, whatever ``N``).

    Returns
    -------
    (K, n_ch, n_ch) array, ``F[d, p, q] = sum_t z_{t, p} z_{t+d, q}``.

    Notes
    -----
    The record is cut into segments of ``B`` samples. For the segment starting
    at ``s``, ``x`` holds its ``B`` samples zero-padded to the FFT length
    ``P >= B + K - 1`` and ``y`` the ``P`` samples from ``s`` on; their circular
    cross-correlation at lags below ``K`` never wraps, so it is the segment's
    share of ``F_d``. The shares add up in the frequency domain: per frequency,
    ``sum_s conj(X_s) Y_s^T`` is one small complex matrix product over all
    segments, and a single inverse FFT per channel pair ends. That is about
    ``4 n_ch^2 P / B`` real multiply-adds per sample instead of the
    ``K n_ch^2`` of direct lagged sums; the rounding is that of the FFT
    (relative ``~1e-16 log P`` of the zero-lag sums).
    """
    N, K = int(n_samples), int(n_lags)
    widths = [np.shape(c)[0] for c in scales]
    m = sum(widths)
    # FFT length: the power of two nearest 6 K (at least 4.2 K), segments of P - K + 1 samples
    # (fewer, longer segments cost more FFT work per sample; shorter ones more of the
    # products). A power of two: pocketfft's fastest, 256 for K = 40 took 3.1 ms against
    # 3.5 ms for the 240 of next_fast_len (benchmarks/bench_subspace.py's 6x6 record)
    P = max(2 ** int(np.round(np.log2(6 * K))), 32)
    B = P - K + 1
    n_seg = -(-N // B)
    per_chunk = max(1, int(chunk) // B)
    S = np.zeros((P // 2 + 1, m, m), complex)
    for s0 in range(0, n_seg, per_chunk):
        t0, ns = s0 * B, min(per_chunk, n_seg - s0)
        z = np.zeros((ns * B + P - B, m))  # the chunk's samples, zero past N
        stop = min(N, t0 + ns * B + K - 1)  # later samples are never reached (lags < K)
        col = 0
        for sig, c, w in zip(signals, scales, widths):
            np.divide(sig[t0:stop], c, out=z[: stop - t0, col : col + w])
            col += w
        # segment s: rows s B .. s B + P - 1 of z (a view; segments overlap by P - B)
        seg = as_strided(
            z, (ns, P, m), (B * z.strides[0], z.strides[0], z.strides[1]), writeable=False
        )
        Y = scipy.fft.rfft(seg, axis=1)  # (ns, P // 2 + 1, m)
        X = scipy.fft.rfft(seg[:, :B], n=P, axis=1)  # the first B samples, zero-padded
        np.conj(X, out=X)
        # per frequency, (m, ns) @ (ns, m): BLAS-compatible strided views, no copies
        S += X.transpose(1, 2, 0) @ Y.transpose(1, 0, 2)
    return scipy.fft.irfft(S, n=P, axis=0)[:K]


def hankel(signals, scales, *, n_blocks: int, n_samples: int) -> np.ndarray:
    """The block-Hankel matrix itself, ``(n_blocks * n_ch, j)``; memory grows with N.

    Same row layout as :func:`hankel_gram`: ``hankel(...) @ hankel(...).T``
    equals ``hankel_gram(...)``.
    """
    N = int(n_samples)
    k = int(n_blocks)
    j = N - k + 1
    z = stacked_signals(signals, scales, 0, N)
    m = z.shape[1]
    H = np.empty((k * m, j))
    for a in range(k):
        H[a * m : (a + 1) * m] = z[a : a + j].T
    return H
