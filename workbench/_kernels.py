"""Compiled inner loop of :func:`workbench.sim.closed_loop`: a linear controller on a stepped plant.

Data flow of one sample k (the same as ``plant.step`` / ``controller.step`` in
``workbench.sim._step_loop``)::

    u[k] = d[k] + u_c[k - delay]           (u_c = C_c x_c before e[k] when delay = 0, D_c = 0)
    raw  = C_r x + D_r sat(u[k-m]) + noise[k]  -> quantized          (raw sensors, n_raw)
    y[k] = T raw;  e = r[k] - y[k]
    u_c[k] = C_c x_c + D_c e;   x_c <- A_c x_c + B_c e
    x <- A x + B0 sat(u[k-m]) + B1 sat(u[k-m-1])

The state matrices A and A_c are passed in banded storage
(``workbench.compiled.banded``): their tridiagonal part, which holds all of a
block-diagonal matrix with 1x1 / 2x2 blocks (the real modal form), plus the
few rows with entries further out, each one contiguous dot product.

numba is a dependency of the project; importing this module without it is an
ImportError on purpose (``engine="python"`` is the explicit way around it).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["closed_loop_kernel"]

# reassociation lets the short dot products use SIMD; the result moves by rounding only
_FAST = {"reassoc", "contract"}


# No array slices in the helpers: each slice is a reference-counted view (two atomic
# operations), which cost more than the short dot products themselves.
@numba.njit(cache=True, fastmath=_FAST, inline="always")
def _banded_matvec(tri, rows, Er, x, out):
    """out = A x, A = tridiagonal part ``tri`` + the rows ``rows`` of the remainder ``Er``.

    ``tri`` (3, n): A[i, i-1], A[i, i], A[i, i+1]; ``Er`` (r, n): row ``rows[r]`` of A
    outside the tridiagonal band (a full-length dot product, vectorized).
    """
    n = x.shape[0]
    if n == 1:
        out[0] = tri[1, 0] * x[0]
    elif n > 1:
        out[0] = tri[1, 0] * x[0] + tri[2, 0] * x[1]
        for i in range(1, n - 1):
            out[i] = tri[0, i] * x[i - 1] + tri[1, i] * x[i] + tri[2, i] * x[i + 1]
        out[n - 1] = tri[0, n - 1] * x[n - 2] + tri[1, n - 1] * x[n - 1]
    for r in range(rows.shape[0]):
        s = 0.0
        for j in range(n):
            s += Er[r, j] * x[j]
        out[rows[r]] += s


@numba.njit(cache=True, fastmath=_FAST, inline="always")
def _matvec_add(M, x, out):
    """out += M x, M (n_out, n_in) row-major: for long rows (dot products)."""
    for i in range(M.shape[0]):
        s = 0.0
        for j in range(M.shape[1]):
            s += M[i, j] * x[j]
        out[i] += s


@numba.njit(cache=True, fastmath=_FAST, inline="always")
def _matvec_add_t(Mt, x, out):
    """out += Mt.T x, Mt (n_in, n_out) row-major: for short inputs (one AXPY per input)."""
    for j in range(Mt.shape[0]):
        xj = x[j]
        for i in range(Mt.shape[1]):
            out[i] += Mt[j, i] * xj


@numba.njit(cache=True, fastmath=_FAST)
def closed_loop_kernel(
    a_tri, a_rows, a_Er, B0t, B1t, Cr, Drt, m, sat, T, w, noise_std, q,
    c_tri, c_rows, c_Er, Bct, Cc, Dct, delay,
    r, d, u, y,
):  # fmt: skip
    """Run the loop of the module docstring over N samples, writing ``u`` and ``y``.

    Parameters
    ----------
    a_tri, a_rows, a_Er
        Plant state matrix (discrete, one sample) in banded storage
        (``workbench.compiled.banded``): tridiagonal part (3, n) + listed rows of the rest.
    B0t, B1t : (n_u, n) arrays
        Transposed inputs of u[k-m] and u[k-m-1] (saturated); B1t may be (0, n) (none).
    Cr : (n_raw, n) array, Drt : (n_u, n_raw) or (0, n_raw) array
        State and transposed feedthrough (of u[k-m]) to the raw sensors, m.
    m : int
        Whole samples of the plant's input delay.
    sat : (n_u,) array
        Symmetric input saturation, N (inf = none).
    T : (n_y, n_raw) array
        Raw sensors to measured outputs.
    w : (N, n_raw) or (N, 0) array
        Standard normal draws of the sensor noise (N, 0: no noise).
    noise_std : (n_raw,) array
        Noise standard deviation of each raw sensor, m.
    q : float
        Raw sensor resolution, m (0 = none).
    c_tri, c_rows, c_Er
        Controller state matrix in banded storage.
    Bct : (n_y, n_c), Cc : (n_u, n_c), Dct : (n_y, n_u) or (0, n_u) arrays
        Controller input (transposed), output and feedthrough (transposed).
    delay : int
        Loop delay, samples (0 needs no feedthrough: Dct (0, n_u)).
    r : (N, n_y) array, d : (N, n_u) array
        Reference and input excitation.
    u : (N, n_u) array, y : (N, n_y) array
        Outputs, overwritten.
    """
    N = r.shape[0]
    n = a_tri.shape[1]
    n_c = c_tri.shape[1]
    n_u = Cc.shape[0]
    n_raw = Cr.shape[0]
    n_y = T.shape[0]
    x = np.zeros(n)
    xn = np.zeros(n)
    xc = np.zeros(n_c)
    xcn = np.zeros(n_c)
    L = delay + 1
    uc = np.zeros((L, n_u))  # ring of controller outputs, applied ``delay`` samples later
    um = np.zeros(n_u)
    um1 = np.zeros(n_u)
    raw = np.zeros(n_raw)
    e = np.zeros(n_y)
    ucur = np.zeros(n_u)
    for k in range(N):
        # the input applied at k
        if delay == 0:
            for i in range(n_u):
                ucur[i] = 0.0
            _matvec_add(Cc, xc, ucur)
            for i in range(n_u):
                u[k, i] = d[k, i] + ucur[i]
        elif k >= delay:
            for i in range(n_u):
                u[k, i] = d[k, i] + uc[(k - delay) % L, i]
        else:
            for i in range(n_u):
                u[k, i] = d[k, i]
        # the plant's delayed, saturated inputs
        for i in range(n_u):
            a = u[k - m, i] if k >= m else 0.0
            b = u[k - m - 1, i] if k >= m + 1 else 0.0
            um[i] = min(max(a, -sat[i]), sat[i])
            um1[i] = min(max(b, -sat[i]), sat[i])
        # measurement
        if w.shape[1]:
            for i in range(n_raw):
                raw[i] = w[k, i] * noise_std[i]
        else:
            for i in range(n_raw):
                raw[i] = 0.0
        _matvec_add(Cr, x, raw)
        _matvec_add_t(Drt, um, raw)
        if q > 0.0:
            for i in range(n_raw):
                raw[i] = q * np.rint(raw[i] / q)
        for i in range(n_y):
            s = 0.0
            for j in range(n_raw):
                s += T[i, j] * raw[j]
            y[k, i] = s
            e[i] = r[k, i] - s
        # controller
        for i in range(n_u):
            ucur[i] = 0.0
        _matvec_add_t(Dct, e, ucur)
        _matvec_add(Cc, xc, ucur)
        slot = k % L
        for i in range(n_u):
            uc[slot, i] = ucur[i]
        _banded_matvec(c_tri, c_rows, c_Er, xc, xcn)
        _matvec_add_t(Bct, e, xcn)
        for i in range(n_c):  # copy, not swap: swapping array variables costs refcounts
            xc[i] = xcn[i]
        # plant
        _banded_matvec(a_tri, a_rows, a_Er, x, xn)
        _matvec_add_t(B0t, um, xn)
        _matvec_add_t(B1t, um1, xn)
        for i in range(n):
            x[i] = xn[i]
