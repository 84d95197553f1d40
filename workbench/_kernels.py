"""Compiled inner loop of :func:`workbench.sim.closed_loop`: a linear controller on a stepped plant.

Data flow of one sample k (the same as ``plant.step`` / ``controller.step`` in
``workbench.sim._step_loop``)::

    u[k] = d[k] + u_c[k - delay]           (u_c = C_c x_c before e[k] when delay = 0, D_c = 0)
    raw  = C_r x + D_r sat(u[k-m]) + std * w[k]  -> quantized          (raw sensors, n_raw)
    y[k] = T raw;  e = r[k] - y[k]
    u_c[k] = C_c x_c + D_c e;   x_c <- A_c x_c + B_c e
    x <- A x + B0 sat(u[k-m]) + B1 sat(u[k-m-1])

w[k] are the caller's generator's standard normals, drawn in the loop in the order
``plant.step`` draws them (n_raw per sample): :func:`_normal` is NumPy's
ziggurat (``Generator.standard_normal``) on the generator's own bit stream, the same
numbers bit for bit, about twice as fast as NumPy's loop (the sign is applied
without a branch; the rare wedge and tail cases go to a separate function).

The state matrices A and A_c are passed in banded storage
(``workbench.compiled.banded``): their tridiagonal part, which holds all of a
block-diagonal matrix with 1x1 / 2x2 blocks (the real modal form), plus the
few rows with entries further out, each one contiguous dot product. C_r is
passed without its zero columns (a position sensor reads no velocity state).

Every loop is written out in the kernel: a helper inlined by numba
(``inline="always"``) brings reference counting of its array arguments into the
loop (atomic increments, ~15 % of the time), a view or a swap of arrays too.

numba is a dependency of the project; importing this module without it is an
ImportError on purpose (``engine="python"`` is the explicit way around it).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["closed_loop_kernel", "standard_normal_fill"]

# reassociation lets the short dot products use SIMD; the result moves by rounding only
_FAST = {"reassoc", "contract"}

try:  # numba's access to a Generator's bit stream and NumPy's ziggurat tables
    from numba.np.random._constants import (
        fi_double,
        ki_double,
        wi_double,
        ziggurat_nor_inv_r,
        ziggurat_nor_r,
    )
    from numba.np.random.generator_core import next_double, next_uint64

    _ZIGGURAT = True
except ImportError:  # a numba that moved them: its own (public, slower) standard_normal
    _ZIGGURAT = False

_SIGN = np.array([1.0, -1.0])

# The draws take the Generator's bit generator (a plain struct) rather than the Generator,
# whose passing to a function is reference counted (atomic operations on every draw).
if _ZIGGURAT:

    @numba.njit(cache=True)
    def _noise_source(rng):
        """What :func:`_normal` draws from: the generator's bit generator."""
        return rng.bit_generator

    @numba.njit(cache=True)
    def _ziggurat_rest(bg, idx, rabs, x):
        """NumPy's ``random_standard_normal`` after a draw that fell outside the boxes."""
        while True:
            if idx == 0:  # the tail beyond r
                while True:
                    xx = -ziggurat_nor_inv_r * np.log1p(-next_double(bg))
                    yy = -np.log1p(-next_double(bg))
                    if yy + yy > xx * xx:
                        if (rabs >> 8) & 0x1:
                            return -(ziggurat_nor_r + xx)
                        return ziggurat_nor_r + xx
            else:  # the wedge
                f0, f1 = fi_double[idx - 1], fi_double[idx]
                if (f0 - f1) * next_double(bg) + f1 < np.exp(-0.5 * x * x):
                    return x
            r = next_uint64(bg)
            idx = r & 0xFF
            r >>= 8
            rabs = (r >> 1) & 0x000FFFFFFFFFFFFF
            x = np.int64(rabs) * wi_double[idx] * _SIGN[r & 0x1]
            if rabs < ki_double[idx]:
                return x

    @numba.njit(cache=True)
    def _normal(bg):
        """One ``standard_normal()`` of the generator: the same number, the same state after.

        No fastmath: the products and sums round as NumPy's C code does.
        """
        r = next_uint64(bg)
        idx = r & 0xFF
        r >>= 8
        rabs = (r >> 1) & 0x000FFFFFFFFFFFFF  # < 2**52: exact as a double
        x = np.int64(rabs) * wi_double[idx] * _SIGN[r & 0x1]  # * -1 is exact
        if rabs < ki_double[idx]:  # 99.3 % of the draws
            return x
        return _ziggurat_rest(bg, idx, rabs, x)

else:

    @numba.njit(cache=True)
    def _noise_source(rng):
        return rng

    @numba.njit(cache=True)
    def _normal(rng):
        """One ``rng.standard_normal()`` (numba's Generator support)."""
        return rng.standard_normal()


@numba.njit(cache=True)
def _scaled_normal(src, std):
    """std * standard_normal(), rounded as NumPy rounds ``w * std`` (no contraction)."""
    return _normal(src) * std


@numba.njit(cache=True)
def standard_normal_fill(rng, out):
    """Fill ``out`` (N, n) as ``rng.standard_normal((N, n))`` would: the kernel's noise draws."""
    src = _noise_source(rng)
    for k in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[k, i] = _normal(src)


@numba.njit(cache=True, fastmath=_FAST)
def closed_loop_kernel(
    a_tri, a_rows, a_Er, B0t, B1t, Crc, cr_cols, Drt, m, sat, T, rng, noise_std, q,
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
    Crc : (n_raw, n_g) array, cr_cols : (n_g,) int64 array
        The columns ``cr_cols`` of the state-to-raw-sensor matrix C_r (its other
        columns are zero).
    Drt : (n_u, n_raw) or (0, n_raw) array
        Transposed feedthrough of u[k-m] to the raw sensors.
    m : int
        Whole samples of the plant's input delay.
    sat : (n_u,) array
        Symmetric input saturation, N (inf = none).
    T : (n_y, n_raw) array
        Raw sensors to measured outputs.
    rng : numpy.random.Generator
        Source of the sensor noise: n_raw standard normals per sample (none drawn
        when ``noise_std`` is empty).
    noise_std : (n_raw,) or (0,) array
        Noise standard deviation of each raw sensor, m ((0,): no noise).
    q : float
        Raw sensor resolution, m (0 = none).
    c_tri, c_rows, c_Er
        Controller state matrix in banded storage.
    Bct : (n_y, n_c), Cc : (n_u, n_c), Dct : (n_y, n_u) or (0, n_u) arrays
        Controller input (transposed), output and feedthrough (transposed).
    delay : int
        Loop delay, samples (0 needs no feedthrough: Dct (0, n_u)).
    r : (N, n_y) or (N, 0) array, d : (N, n_u) array
        Reference ((N, 0): zero) and input excitation.
    u : (N, n_u) array, y : (N, n_y) array
        Outputs, overwritten.
    """
    N = d.shape[0]
    n = a_tri.shape[1]
    n_c = c_tri.shape[1]
    n_u = Cc.shape[0]
    n_raw = Crc.shape[0]
    n_g = cr_cols.shape[0]
    n_y = T.shape[0]
    noisy = noise_std.shape[0] > 0
    has_r = r.shape[1] > 0
    src = _noise_source(rng)
    x = np.zeros(n)
    xn = np.zeros(n)
    xg = np.zeros(n_g)
    xc = np.zeros(n_c)
    xcn = np.zeros(n_c)
    L = delay + 1
    uc = np.zeros((L, n_u))  # ring of controller outputs, applied ``delay`` samples later
    um = np.zeros(n_u)
    um1 = np.zeros(n_u)
    raw = np.zeros(n_raw)
    e = np.zeros(n_y)
    for k in range(N):
        # the input applied at k
        if delay == 0:
            for i in range(n_u):
                s = 0.0
                for j in range(n_c):
                    s += Cc[i, j] * xc[j]
                u[k, i] = d[k, i] + s
        elif k >= delay:
            slot = (k - delay) % L
            for i in range(n_u):
                u[k, i] = d[k, i] + uc[slot, i]
        else:
            for i in range(n_u):
                u[k, i] = d[k, i]
        # the plant's delayed, saturated inputs
        for i in range(n_u):
            a = u[k - m, i] if k >= m else 0.0
            b = u[k - m - 1, i] if k >= m + 1 else 0.0
            um[i] = min(max(a, -sat[i]), sat[i])
            um1[i] = min(max(b, -sat[i]), sat[i])
        # measurement: the states the sensors read, then one dot product per raw sensor
        for j in range(n_g):
            xg[j] = x[cr_cols[j]]
        for i in range(n_raw):
            s = 0.0
            for j in range(n_g):
                s += Crc[i, j] * xg[j]
            raw[i] = s
        for j in range(Drt.shape[0]):
            uj = um[j]
            for i in range(n_raw):
                raw[i] += Drt[j, i] * uj
        if noisy:  # in plant.step's order: n_raw draws per sample
            for i in range(n_raw):
                raw[i] += _scaled_normal(src, noise_std[i])
        if q > 0.0:
            for i in range(n_raw):
                raw[i] = q * np.rint(raw[i] / q)
        for i in range(n_y):
            s = 0.0
            for j in range(n_raw):
                s += T[i, j] * raw[j]
            y[k, i] = s
            e[i] = r[k, i] - s if has_r else -s
        # controller: output (applied ``delay`` samples later), then its state
        if delay > 0:
            slot = k % L
            for i in range(n_u):
                s = 0.0
                for j in range(n_c):
                    s += Cc[i, j] * xc[j]
                uc[slot, i] = s
            for j in range(Dct.shape[0]):
                ej = e[j]
                for i in range(n_u):
                    uc[slot, i] += Dct[j, i] * ej
        if n_c == 1:
            xcn[0] = c_tri[1, 0] * xc[0]
        elif n_c > 1:
            xcn[0] = c_tri[1, 0] * xc[0] + c_tri[2, 0] * xc[1]
            for i in range(1, n_c - 1):
                xcn[i] = c_tri[0, i] * xc[i - 1] + c_tri[1, i] * xc[i] + c_tri[2, i] * xc[i + 1]
            xcn[n_c - 1] = c_tri[0, n_c - 1] * xc[n_c - 2] + c_tri[1, n_c - 1] * xc[n_c - 1]
        for rr in range(c_rows.shape[0]):
            s = 0.0
            for j in range(n_c):
                s += c_Er[rr, j] * xc[j]
            xcn[c_rows[rr]] += s
        for j in range(n_y):
            ej = e[j]
            for i in range(n_c):
                xcn[i] += Bct[j, i] * ej
        for i in range(n_c):  # copy, not swap: swapping array variables costs refcounts
            xc[i] = xcn[i]
        # plant
        if n == 1:
            xn[0] = a_tri[1, 0] * x[0]
        elif n > 1:
            xn[0] = a_tri[1, 0] * x[0] + a_tri[2, 0] * x[1]
            for i in range(1, n - 1):
                xn[i] = a_tri[0, i] * x[i - 1] + a_tri[1, i] * x[i] + a_tri[2, i] * x[i + 1]
            xn[n - 1] = a_tri[0, n - 1] * x[n - 2] + a_tri[1, n - 1] * x[n - 1]
        for rr in range(a_rows.shape[0]):
            s = 0.0
            for j in range(n):
                s += a_Er[rr, j] * x[j]
            xn[a_rows[rr]] += s
        for j in range(B0t.shape[0]):
            uj = um[j]
            for i in range(n):
                xn[i] += B0t[j, i] * uj
        for j in range(B1t.shape[0]):
            uj = um1[j]
            for i in range(n):
                xn[i] += B1t[j, i] * uj
        for i in range(n):
            x[i] = xn[i]
