"""Gram matrices of block-Hankel data matrices, from correlation sums.

A subspace method needs the row space of a block-Hankel matrix ``H`` with
``n_rows = n_blocks * n_ch`` rows and ``j = N - n_blocks + 1`` columns. Its
Gram ``H H^T`` has the structure of the data: block ``(a, a + d)`` is a lagged
correlation sum over a window of ``j`` samples. We compute the ``n_blocks``
full-record correlation sums once (``O(N * n_ch * n_rows)`` work, in chunks of
time so memory stays ``O(chunk * n_rows + n_rows^2)`` whatever ``N``) and obtain
every block by subtracting a few edge terms, never forming ``H``.

:func:`hankel` builds ``H`` itself, for the QR reference path and for tests.
"""

from __future__ import annotations

import numpy as np

__all__ = ["hankel_gram", "hankel", "stacked_signals"]


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


def hankel_gram(signals, scales, *, n_blocks: int, n_samples: int, chunk: int = 1024) -> np.ndarray:
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
        Samples per chunk of the correlation sums (bounds memory).

    Returns
    -------
    (n_blocks * n_ch, n_blocks * n_ch) array
        Row ``a * n_ch + p`` belongs to block row ``a``, channel ``p``:
        ``G[(a, p), (b, q)] = sum_{t=0}^{j-1} z_{t+a, p} z_{t+b, q}``.

    Notes
    -----
    With ``F_d = sum_{t=0}^{N-1-d} z_t z_{t+d}^T`` the full-record lag-``d``
    correlation sum, block ``(a, a + d)`` of the Gram is
    ``F_d - sum_{t<a} z_t z_{t+d}^T - sum_{t=a+j}^{N-1-d} z_t z_{t+d}^T``; both
    corrections have fewer than ``n_blocks`` terms. The ``F_d`` cost
    ``N n_ch^2 n_blocks`` multiply-adds, one GEMM per chunk.
    """
    N = int(n_samples)
    k = int(n_blocks)
    m = sum(np.shape(c)[0] for c in scales)
    # F[:, d*m:(d+1)*m] = F_d, accumulated over chunks of "left" samples t;
    # one GEMM per lag on views of the chunk (no lagged copy of the data).
    F = np.zeros((m, k * m))
    for t0 in range(0, N, chunk):
        t1 = min(N, t0 + chunk)
        L = t1 - t0
        z = np.zeros((L + k - 1, m))  # zero padding beyond N adds nothing
        got = stacked_signals(signals, scales, t0, min(N, t1 + k - 1))
        z[: got.shape[0]] = got
        left = z[:L].T
        for d in range(k):
            F[:, d * m : (d + 1) * m] += left @ z[d : d + L]
    F = F.reshape(m, k, m).transpose(1, 0, 2)  # F[d] (m, m)

    # Edge corrections, vectorized: products z_t z_{t+d}^T near both ends.
    zh = np.zeros((2 * k, m))
    got = stacked_signals(signals, scales, 0, min(N, 2 * k))
    zh[: got.shape[0]] = got

    def lag_products(w):  # [d, t] = w_t w_{t+d}^T, flattened to m * m, t = 0..k-1
        lagged = np.stack([w[d : d + k] for d in range(k)])  # [d, t, q] = w_{t+d}
        return (w[None, :k, :, None] * lagged[:, :, None, :]).reshape(k, k, m * m)

    # head[d, a] = sum_{t<a} z_t z_{t+d}^T, a = 0..k-1: a strictly lower triangular
    # matrix of ones sums the running products, one small GEMM per lag
    head = (np.tril(np.ones((k, k)), -1) @ lag_products(zh)).reshape(k, k, m, m)
    # tail[d, a] = sum_{t=a+j}^{N-1-d} z_t z_{t+d}^T (zero padding past N-1)
    zt = np.zeros((2 * k, m))
    got = stacked_signals(signals, scales, N - (k - 1), N)  # samples j .. N-1
    zt[: got.shape[0]] = got
    tail = (np.triu(np.ones((k, k))) @ lag_products(zt)).reshape(k, k, m, m)

    G = np.empty((k * m, k * m))
    G4 = G.reshape(k, m, k, m)  # a view: G4[a, p, b, q]
    for d in range(k):
        blocks = F[d][None] - head[d, : k - d] - tail[d, : k - d]  # (k - d, m, m)
        a = np.arange(k - d)
        G4[a, :, a + d, :] = blocks
        G4[a + d, :, a, :] = blocks.transpose(0, 2, 1)
    return G


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
