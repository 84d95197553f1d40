"""Compiled recursive filter of several input streams through one denominator.

The time-domain simulation of a modal model (:mod:`workbench.modal.simulate`) filters a
mode's inputs through ``1/den`` and ``s/den`` (exact ZOH, ``b_k(z) / a(z)``) and mixes them
by the mode's numerators. Both filters share ``a``: the mode's output is one recursion,
``y = sum_k b_k(z) / a(z) x_k``, over the inputs already mixed by each numerator
(``x_0 = u N0^T``, ``x_1 = u N1^T``), where ``scipy.signal.lfilter`` takes one call per
numerator and input column. :func:`iir_streams` is that recursion, the transposed direct
form II of ``lfilter`` with the streams' numerator terms summed into its states (the same
arithmetic as summing ``lfilter(b_k, a, x_k)``, up to the order of the additions).
:func:`transposed` lays the summed signals out as a record.

numba is a dependency of the project (see :mod:`workbench._port_kernel`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["iir_streams", "transposed"]


@numba.njit(cache=True, boundscheck=False)
def _order2(b, a, x0, x1, out):  # pragma: no cover - compiled
    """:func:`iir_streams` for ``a`` of length 3 and ``b`` of length <= 4 (a mode's filter),
    one or two streams (``x1`` read where ``b`` has two rows).

    The states in scalars (the generic loop keeps them in memory, ~2.5x slower), two
    signals per pass: a recursion's samples wait on each other (``y`` on ``z1`` on the
    last ``y``), and a second independent chain fills that wait (~1.6x faster).
    """
    S, L = b.shape
    C, N = x0.shape
    a1, a2 = a[1], a[2]
    bb = np.zeros((2, 4))
    bb[:S, :L] = b
    c = 0
    while c + 1 < C:
        p1 = p2 = p3 = 0.0
        q1 = q2 = q3 = 0.0
        for i in range(N):
            u = x0[c, i]
            v = x0[c + 1, i]
            f0, f1, f2, f3 = bb[0, 0] * u, bb[0, 1] * u, bb[0, 2] * u, bb[0, 3] * u
            g0, g1, g2, g3 = bb[0, 0] * v, bb[0, 1] * v, bb[0, 2] * v, bb[0, 3] * v
            if S == 2:
                u = x1[c, i]
                v = x1[c + 1, i]
                f0 += bb[1, 0] * u
                f1 += bb[1, 1] * u
                f2 += bb[1, 2] * u
                f3 += bb[1, 3] * u
                g0 += bb[1, 0] * v
                g1 += bb[1, 1] * v
                g2 += bb[1, 2] * v
                g3 += bb[1, 3] * v
            y = f0 + p1
            w = g0 + q1
            p1 = f1 - a1 * y + p2
            q1 = g1 - a1 * w + q2
            p2 = f2 - a2 * y + p3
            q2 = g2 - a2 * w + q3
            p3 = f3
            q3 = g3
            out[c, i] = y
            out[c + 1, i] = w
        c += 2
    if c < C:
        z1 = z2 = z3 = 0.0
        for i in range(N):
            u = x0[c, i]
            f0, f1, f2, f3 = bb[0, 0] * u, bb[0, 1] * u, bb[0, 2] * u, bb[0, 3] * u
            if S == 2:
                u = x1[c, i]
                f0 += bb[1, 0] * u
                f1 += bb[1, 1] * u
                f2 += bb[1, 2] * u
                f3 += bb[1, 3] * u
            y = f0 + z1
            z1 = f1 - a1 * y + z2
            z2 = f2 - a2 * y + z3
            z3 = f3
            out[c, i] = y


@numba.njit(cache=True, boundscheck=False)
def _order4(b, a, x0, x1, out):  # pragma: no cover - compiled
    """:func:`iir_streams` for ``a`` of length 4-5 and ``b`` of length <= 6 (a mode behind
    one or two lags), padded with zeros to those lengths, one or two streams: the states
    in scalars, two signals per pass as :func:`_order2`."""
    S, L = b.shape
    C, N = x0.shape
    aa = np.zeros(5)
    aa[: a.size] = a
    a1, a2, a3, a4 = aa[1], aa[2], aa[3], aa[4]
    bb = np.zeros((2, 6))
    bb[:S, :L] = b
    c = 0
    while c + 1 < C:
        p1 = p2 = p3 = p4 = p5 = 0.0
        q1 = q2 = q3 = q4 = q5 = 0.0
        for i in range(N):
            u = x0[c, i]
            v = x0[c + 1, i]
            f0, f1, f2 = bb[0, 0] * u, bb[0, 1] * u, bb[0, 2] * u
            f3, f4, f5 = bb[0, 3] * u, bb[0, 4] * u, bb[0, 5] * u
            g0, g1, g2 = bb[0, 0] * v, bb[0, 1] * v, bb[0, 2] * v
            g3, g4, g5 = bb[0, 3] * v, bb[0, 4] * v, bb[0, 5] * v
            if S == 2:
                u = x1[c, i]
                v = x1[c + 1, i]
                f0 += bb[1, 0] * u
                f1 += bb[1, 1] * u
                f2 += bb[1, 2] * u
                f3 += bb[1, 3] * u
                f4 += bb[1, 4] * u
                f5 += bb[1, 5] * u
                g0 += bb[1, 0] * v
                g1 += bb[1, 1] * v
                g2 += bb[1, 2] * v
                g3 += bb[1, 3] * v
                g4 += bb[1, 4] * v
                g5 += bb[1, 5] * v
            y = f0 + p1
            w = g0 + q1
            p1 = f1 - a1 * y + p2
            q1 = g1 - a1 * w + q2
            p2 = f2 - a2 * y + p3
            q2 = g2 - a2 * w + q3
            p3 = f3 - a3 * y + p4
            q3 = g3 - a3 * w + q4
            p4 = f4 - a4 * y + p5
            q4 = g4 - a4 * w + q5
            p5 = f5
            q5 = g5
            out[c, i] = y
            out[c + 1, i] = w
        c += 2
    if c < C:
        z1 = z2 = z3 = z4 = z5 = 0.0
        for i in range(N):
            u = x0[c, i]
            f0, f1, f2 = bb[0, 0] * u, bb[0, 1] * u, bb[0, 2] * u
            f3, f4, f5 = bb[0, 3] * u, bb[0, 4] * u, bb[0, 5] * u
            if S == 2:
                u = x1[c, i]
                f0 += bb[1, 0] * u
                f1 += bb[1, 1] * u
                f2 += bb[1, 2] * u
                f3 += bb[1, 3] * u
                f4 += bb[1, 4] * u
                f5 += bb[1, 5] * u
            y = f0 + z1
            z1 = f1 - a1 * y + z2
            z2 = f2 - a2 * y + z3
            z3 = f3 - a3 * y + z4
            z4 = f4 - a4 * y + z5
            z5 = f5
            out[c, i] = y


@numba.njit(cache=True, boundscheck=False)
def _transpose(x, out):  # pragma: no cover - compiled
    C, N = x.shape
    for i in range(N):
        for c in range(C):
            out[i, c] = x[c, i]


def transposed(x: np.ndarray) -> np.ndarray:
    """``np.ascontiguousarray(x.T)`` of signals ``x`` (C, N) as a record (N, C): compiled,
    ~1.5x faster for a handful of long signals (numpy's strided copy)."""
    if min(x.shape) == 1:  # one signal, or one sample: a reshape
        return np.ascontiguousarray(x).reshape(x.shape[::-1])
    out = np.empty(x.shape[::-1])
    _transpose(_read_only(x), out)
    return out


@numba.njit(cache=True, boundscheck=False)
def _generic(b, a, x, out):  # pragma: no cover - compiled
    """:func:`iir_streams` for any orders (the states in an array: ~2.5x slower)."""
    S, L = b.shape
    C, N = x.shape[1], x.shape[2]
    m = max(L, a.size)
    bb = np.zeros((S, m))
    aa = np.zeros(m)
    bb[:, :L] = b
    aa[: a.size] = a
    z = np.zeros(m)
    for c in range(C):
        z[:] = 0.0
        for i in range(N):
            f = 0.0
            for s in range(S):
                f += bb[s, 0] * x[s, c, i]
            y = f + z[0]
            for j in range(1, m):
                f = 0.0
                for s in range(S):
                    f += bb[s, j] * x[s, c, i]
                z[j - 1] = f - aa[j] * y + (z[j] if j < m - 1 else 0.0)
            out[c, i] = y


def iir_streams(b: np.ndarray, a: np.ndarray, x) -> np.ndarray:
    """``sum_k lfilter(b[k], a, x[k], axis=-1)``, from rest, in one pass.

    Parameters
    ----------
    b : (S, L) float
        Each stream's numerator, coefficients of ``z^0, z^-1, ..`` (lfilter's order).
    a : (n + 1,) float
        The shared denominator, ``a[0] = 1``.
    x : (S, C, N) float, or a sequence of S (C, N) arrays
        S streams of C signals of N samples (each signal contiguous). A sequence spares
        the caller stacking streams it keeps apart (a mode's inputs mixed by each of its
        numerators, cached one by one).

    Returns
    -------
    (C, N) float: the filtered streams summed, per signal.
    """
    b = np.require(b, float, ["C", "W"])
    a = np.require(a, float, ["C", "W"])
    if a[0] != 1.0:
        b, a = b / a[0], a / a[0]
    xs = [_read_only(xk) for xk in x]
    out = np.empty(xs[0].shape)
    if b.shape[0] <= 2 and a.size == 3 and b.shape[1] <= 4:
        _order2(b, a, xs[0], xs[-1], out)
    elif b.shape[0] <= 2 and a.size <= 5 and b.shape[1] <= 6:
        _order4(b, a, xs[0], xs[-1], out)
    else:
        _generic(b, a, np.require(np.stack(xs), float, ["C", "W"]), out)
    return out


def _read_only(x) -> np.ndarray:
    """``x`` as a C-contiguous float array the kernels see read-only: numba compiles one
    version per read-only flag (~1-2 s each on first use), and the cached mixed inputs are
    read-only; a view is flagged, not copied."""
    x = np.require(x, float, ["C"])
    if x.flags.writeable:
        x = x.view()
        x.flags.writeable = False
    return x
