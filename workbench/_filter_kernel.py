"""Compiled recursive filter of several input streams through one denominator.

The time-domain simulation of a modal model (:mod:`workbench.modal.simulate`) filters a
mode's inputs through ``1/den`` and ``s/den`` (exact ZOH, ``b_k(z) / a(z)``) and mixes them
by the mode's numerators. Both filters share ``a``: the mode's output is one recursion,
``y = sum_k b_k(z) / a(z) x_k``, over the inputs already mixed by each numerator
(``x_0 = u N0^T``, ``x_1 = u N1^T``), where ``scipy.signal.lfilter`` takes one call per
numerator and input column. :func:`iir_streams` is that recursion, the transposed direct
form II of ``lfilter`` with the streams' numerator terms summed into its states (the same
arithmetic as summing ``lfilter(b_k, a, x_k)``, up to the order of the additions).

numba is a dependency of the project (see :mod:`workbench._port_kernel`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["iir_streams"]


@numba.njit(cache=True, boundscheck=False)
def _order2(b, a, x, out):  # pragma: no cover - compiled
    """:func:`iir_streams` for ``a`` of length 3 and ``b`` of length <= 4 (a mode's filter):
    the states in scalars (the generic loop keeps them in memory, ~2.5x slower)."""
    S, L = b.shape
    C, N = x.shape[1], x.shape[2]
    a1, a2 = a[1], a[2]
    bb = np.zeros((S, 4))
    bb[:, :L] = b
    for c in range(C):
        z1 = 0.0
        z2 = 0.0
        z3 = 0.0
        for i in range(N):
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            f3 = 0.0
            for s in range(S):
                xs = x[s, c, i]
                f0 += bb[s, 0] * xs
                f1 += bb[s, 1] * xs
                f2 += bb[s, 2] * xs
                f3 += bb[s, 3] * xs
            y = f0 + z1
            z1 = f1 - a1 * y + z2
            z2 = f2 - a2 * y + z3
            z3 = f3
            out[c, i] = y


@numba.njit(cache=True, boundscheck=False)
def _order4(b, a, x, out):  # pragma: no cover - compiled
    """:func:`iir_streams` for ``a`` of length 4-5 and ``b`` of length <= 6 (a mode behind
    one or two lags), padded with zeros to those lengths: the states in scalars."""
    S, L = b.shape
    C, N = x.shape[1], x.shape[2]
    aa = np.zeros(5)
    aa[: a.size] = a
    a1, a2, a3, a4 = aa[1], aa[2], aa[3], aa[4]
    bb = np.zeros((S, 6))
    bb[:, :L] = b
    for c in range(C):
        z1 = 0.0
        z2 = 0.0
        z3 = 0.0
        z4 = 0.0
        z5 = 0.0
        for i in range(N):
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            f3 = 0.0
            f4 = 0.0
            f5 = 0.0
            for s in range(S):
                xs = x[s, c, i]
                f0 += bb[s, 0] * xs
                f1 += bb[s, 1] * xs
                f2 += bb[s, 2] * xs
                f3 += bb[s, 3] * xs
                f4 += bb[s, 4] * xs
                f5 += bb[s, 5] * xs
            y = f0 + z1
            z1 = f1 - a1 * y + z2
            z2 = f2 - a2 * y + z3
            z3 = f3 - a3 * y + z4
            z4 = f4 - a4 * y + z5
            z5 = f5
            out[c, i] = y


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


def iir_streams(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``sum_k lfilter(b[k], a, x[k], axis=-1)``, from rest, in one pass.

    Parameters
    ----------
    b : (S, L) float
        Each stream's numerator, coefficients of ``z^0, z^-1, ..`` (lfilter's order).
    a : (n + 1,) float
        The shared denominator, ``a[0] = 1``.
    x : (S, C, N) float
        S streams of C signals of N samples (each signal contiguous).

    Returns
    -------
    (C, N) float: the filtered streams summed, per signal.
    """
    # C-contiguous and writable: numba compiles one version per layout and per read-only
    # flag (the cached coefficients and mixed inputs are read-only), each ~1-2 s on first use
    b = np.require(b, float, ["C", "W"])
    a = np.require(a, float, ["C", "W"])
    if a[0] != 1.0:
        b, a = b / a[0], a / a[0]
    x = np.require(x, float, ["C", "W"])
    out = np.empty(x.shape[1:])
    if a.size == 3 and b.shape[1] <= 4:
        _order2(b, a, x, out)
    elif a.size <= 5 and b.shape[1] <= 6:
        _order4(b, a, x, out)
    else:
        _generic(b, a, x, out)
    return out
