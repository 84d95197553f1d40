"""Exact zero-order-hold simulation of a :class:`~workbench.modal.model.ModalModel`, mode by mode.

Each mode ``(N1 s + N0) / den(s)`` is simulated by filtering the inputs
through ``1/den`` and ``s/den`` (and the lags and delay of their channel;
exact ZOH coefficients, by partial fractions where the poles are distinct)
with ``lfilter``'s recursion (compiled: :mod:`workbench._filter_kernel`) and
mixing the filtered inputs with ``N0``, ``N1``: a 10,000-sample 6x6 record
takes milliseconds, and a fit that changes one mode refilters that mode only
(the diagnosis's time-domain problem caches :func:`filtered_inputs` per mode,
the regressors of its linear fits, and computes a mode's output by
:func:`mixed_inputs`: the inputs mixed by the numerators first, both filters
in one recursion).

Data flow::

    u (N, n_u) --T_in--> per (sensor-lag, actuator-lag) group:
        zoh_filter(num, den * lags, delay) --> X (groups, N, n_u, 2)
        --N0, N1 rows--> y (N, n_y) --T_out--> y
    (mixed_inputs: u --N0, N1 rows--> per group one recursion --> y)
"""

from __future__ import annotations

import cmath
import functools
import math
from typing import NamedTuple

import numpy as np
import scipy.linalg

from workbench._filter_kernel import iir_streams, transposed
from workbench.sim import c2d_zoh, split_delay

__all__ = [
    "filtered_inputs",
    "filtered_lines",
    "line_responses",
    "mixed_inputs",
    "mixed_lines",
    "mode_line_responses",
    "simulate",
    "zoh_filter",
    "zoh_response",
    "zoh_responses",
]


def _channel_filters(model, den, numerator_s: bool):
    """The filters of :func:`filtered_inputs`: per output group and input-lag set.

    Returns
    -------
    filters : list of :class:`_Filter`
        Output group ``g``, input columns ``cols``, the numerators (``[1]``, and ``[1, 0]``
        for ``s/den`` when asked and ``den`` is second order; slot k of X is ``nums[k]``),
        the common denominator ``d`` (``den`` times the channel's lags), the channels it
        filters as flat indices ``i n_u + j`` of an (n_y, n_u) array, and ``d``'s roots
        when a lag multiplies ``den`` (the mode's and the lags' -1/tau, known in closed
        form: no eigenvalue computation per filter), else None.
    groups : tuple of int arrays
        Output indices sharing one sensor lag.

    Cached by the denominator and the lags (read-only arrays): a fit evaluates the same
    mode behind the same lags many times.
    """
    return _filters_of(
        None if den is None else np.asarray(den, float).tobytes(),
        np.round(model.lags("out"), 15).tobytes(),
        np.round(model.lags("in"), 15).tobytes(),
        bool(numerator_s),
    )


@functools.lru_cache(maxsize=1024)
def _filters_of(den_bytes, out_bytes: bytes, in_bytes: bytes, numerator_s: bool):
    """:func:`_channel_filters` from the denominator's and the lags' bytes."""
    den = None if den_bytes is None else np.frombuffer(den_bytes)
    groups, lag_sets = _channel_layout(out_bytes, in_bytes)
    two = den is not None and len(den) == 2 and numerator_s
    base = np.array([1.0]) if den is None else np.concatenate([[1.0], den])
    base.flags.writeable = False
    nums = _NUMS_TWO if two else _NUMS_ONE
    filters = []
    den_roots = None
    for g, cols, lag, flat, lag_roots in lag_sets:
        if lag.size == 1:
            filters.append(_Filter(g, cols, nums, base, flat, None))
            continue
        if den_roots is None:
            den_roots = _den_roots(den)
        # np.convolve is np.polymul without its poly1d wrapping (both leading terms are
        # nonzero: nothing to trim)
        d = np.convolve(base, lag)
        roots = np.array(den_roots + lag_roots, complex)
        d.flags.writeable = roots.flags.writeable = False
        filters.append(_Filter(g, cols, nums, d, flat, roots))
    return tuple(filters), groups


class _Filter(NamedTuple):
    """One filter of :func:`_channel_filters`."""

    g: int
    cols: np.ndarray
    nums: tuple
    d: np.ndarray
    flat: np.ndarray
    roots: np.ndarray | None

    @property
    def roots_bytes(self) -> bytes:
        """``roots`` as :func:`_zoh_parts` takes them (empty: found there)."""
        return b"" if self.roots is None else self.roots.tobytes()


def _den_roots(den) -> list:
    """The roots of ``s^2 + a1 s + a0`` (``den`` = (a1, a0); rigid (0, 0): the double root 0)
    or of ``s + a0`` (``den`` = (a0,)); none for ``den`` None."""
    if den is None:
        return []
    if len(den) == 1:
        return [complex(-den[0])]
    h = 0.5 * float(den[0])
    q = cmath.sqrt(h * h - float(den[1]))
    return [-h + q, -h - q]


_NUMS_ONE = (np.array([1.0]),)
_NUMS_TWO = (np.array([1.0]), np.array([1.0, 0.0]))


@functools.lru_cache(maxsize=256)  # a lag fit's Jacobian: one layout per perturbed channel
def _channel_layout(out_bytes: bytes, in_bytes: bytes):
    """Output groups of equal sensor lag and, per group and input-lag set, the lags' polynomial.

    From the lags' bytes (cached: a model's lags change far less often than its modes).
    Returns (groups, [(g, cols, lag_polynomial, flat, lag_roots), ...]), ``flat`` the
    channels (group g's outputs i, the set's inputs j) as flat indices ``i n_u + j``,
    ``lag_roots`` the lag polynomial's roots ``-1/tau`` (a list).
    """
    taus, tin = np.frombuffer(out_bytes), np.frombuffer(in_bytes)
    uniq = np.unique(taus)
    groups = tuple(np.flatnonzero(taus == t) for t in uniq)
    sets = []
    for g, ty in enumerate(uniq):
        for ti in np.unique(tin):
            lag = np.array([1.0])
            for tau in (ty, ti):
                if tau > 0:
                    lag = np.convolve(lag, [tau, 1.0])  # np.polymul, without poly1d
            cols = np.flatnonzero(tin == ti)
            flat = (groups[g][:, None] * tin.size + cols[None, :]).ravel()
            roots = [complex(-1.0 / tau) for tau in (ty, ti) if tau > 0]
            sets.append((g, cols, lag, flat, roots))
    for x in list(groups) + [a for _, c, p, f, _ in sets for a in (c, p, f)]:
        x.flags.writeable = False
    return groups, sets


def filtered_inputs(model, den, u: np.ndarray, fs: float, *, numerator_s: bool = True):
    """Inputs filtered through the model's lags and delay and ``1/den``, ``s/den``.

    Parameters
    ----------
    model : ModalModel
        Gives the lags (``tau_in``, ``tau_out``, s) and the delay (s).
    den : array or None
        ``(a1, a0)`` or ``(a0,)`` of a mode's denominator (:meth:`Mode.denominator`);
        None for the feedthrough (den = 1).
    u : (N, n_u) array
        Inputs after the static input coupling.
    fs : float
        Sample rate, Hz.
    numerator_s : bool
        Also filter through ``s/den`` (second-order ``den`` only).

    Returns
    -------
    X : (n_groups, N, n_u, 2) array
        ``X[g, :, j, 0]`` is ``u_j`` through ``Hy Hu_j exp(-s delay) / den``
        for the outputs of group g, ``[..., 1]`` the same times ``s``.
    groups : list of int arrays
        Output indices sharing one sensor lag.
    """
    filters, groups = _channel_filters(model, den, numerator_s)
    X = np.zeros((len(groups), u.shape[0], model.n_u, 2))
    for f in filters:
        for k, num in enumerate(f.nums):
            X[f.g, :, f.cols, k] = zoh_filter(num, f.d, u[:, f.cols], 1.0 / fs, model.delay_s).T
    return X, groups


def mixed_inputs(
    model, den, N0, N1, u: np.ndarray, fs: float, *, products=None, outputs=None
) -> np.ndarray:
    """One mode's output on the record, (N, n_y): :func:`filtered_inputs` mixed by the
    numerator ``N1 s + N0``, without forming the filtered inputs.

    Per filter (output group, input-lag set) the inputs are mixed by each numerator first,
    ``x_k = u[:, cols] N_k[rows, cols]^T``, and the filters ``1/d`` and ``s/d`` (one
    denominator) run as one recursion over the group's outputs
    (:func:`workbench._filter_kernel.iir_streams`): n_rows signals where
    :func:`filtered_inputs` filters 2 n_u and the mixing then reads them back (a fit
    evaluates thousands of moved modes; their regressors are needed only by the linear
    fits). ``den`` (a mode's, :meth:`Mode.denominator`; not None), ``N0``, ``N1`` (n_y,
    n_u; ``N1`` None or zero: ``1/d`` only), ``u`` (N, n_u) after the input coupling, ``fs``
    Hz. ``products``: a cache of the mixed inputs for this ``u`` (the caller keeps one per
    ``u``), keyed by the numerator's block of the filter's rows and columns: a moved mode
    keeps its numerator. ``outputs``: a cache of each filter's recursion output for this ``u``
    (the caller keeps one per ``u``, as ``products``), keyed by its denominator, delay and
    the inputs it filters: a lag moved on one channel (a lag fit's difference quotient)
    leaves the other channels' filters as they were, and they are found here (with four
    input lags, one recursion in four). The same output as mixing :func:`filtered_inputs`
    (the additions in another order: rounding).

    The filters' outputs are summed along the samples of each output, (n_y, N), and
    transposed once: adding each into columns of an (N, n_y) array strode across it (with
    a sensor lag per output, once per output) and cost more than the recursions.
    """
    filters, groups = _channel_filters(model, den, True)
    dt = 1.0 / fs
    m_int, frac = split_delay(model.delay_s, dt)
    N = u.shape[0]
    yT = np.zeros((N0.shape[0], N))
    numerators = (N0, N1) if N1 is not None and np.any(N1) else (N0,)
    for f in filters:
        rows = groups[f.g]
        n = min(len(f.nums), len(numerators))
        coefficients = _filter_parts(f.d.tobytes(), n, dt, frac, f.roots_bytes)
        blocks = tuple(_block(N_k, rows, f.cols) for N_k in numerators[:n])
        key = out = None
        if outputs is not None:
            key = (f.d.tobytes(), n, dt, frac, tuple(b.tobytes() for b in blocks), f.flat.tobytes())
            out = outputs.get(key)
        if out is None:
            out = _filter_record(coefficients, blocks, u, f.cols, products)
            if key is not None:
                _keep(outputs, key, out, RECORD_OUTPUTS_BYTES)
        if m_int < N:
            for j, r in enumerate(rows):
                yT[r, m_int:] += out[j, : N - m_int]
    return transposed(yT)


#: bytes of mixed inputs a ``products`` cache of :func:`mixed_inputs` keeps (each n_rows N
#: floats: a model's modes times its output groups, twice (N0, N1); with a sensor lag per
#: output, 8 modes of a 5-output beam are 80 entries, which a count of 64 cycled through
#: on every evaluation)
RECORD_PRODUCTS_BYTES = 64 * 2**20

#: bytes of filter outputs an ``outputs`` cache of :func:`mixed_inputs` keeps: a model's
#: modes times its lag sets, twice over (a difference quotient's point beside its base point)
RECORD_OUTPUTS_BYTES = 64 * 2**20


def _keep(store: dict, key, value: np.ndarray, budget: int) -> None:
    """``store[key] = value`` (read-only), the oldest entries dropped while the store holds
    more than ``budget`` bytes (its entries of one size: a count from the first's)."""
    value.flags.writeable = False
    while store and (len(store) + 1) * value.nbytes > budget:
        store.pop(next(iter(store)))
    store[key] = value


def _block(N: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``N[np.ix_(rows, cols)]``, without ``np.ix_`` where the block is all of N or one row
    (a fit's hot path: the index arrays cost more than the copy)."""
    if cols.size == N.shape[1]:
        return N if rows.size == N.shape[0] else N[rows]
    if rows.size == 1:
        return N[rows[0], cols][None]
    return N[np.ix_(rows, cols)]


@functools.lru_cache(maxsize=1024)
def _filter_parts(d_bytes: bytes, n: int, dt: float, frac: float, roots_bytes: bytes) -> tuple:
    """(b, a, k) of :func:`_zoh_parts` for the first ``n`` of ``1/d``, ``s/d`` (``d`` a
    filter's denominator, not monic behind a lag), cached by the filter: one lookup per
    filter where the numerators made monic and looked up each cost as much again."""
    d = np.frombuffer(d_bytes)
    parts = []
    for num in _NUMS_TWO[:n]:
        (num,), dm = _monic([num], d)
        if num[0] or dm.size == 1:
            raise ValueError("mixed_inputs: a mode's strictly proper filters only")
        parts.append(_zoh_parts(num.tobytes(), dm.tobytes(), dt, frac, roots_bytes))
    return tuple(parts)


def _filter_record(coefficients, blocks, u, cols, products) -> np.ndarray:
    """One filter's output (n_rows, N) of :func:`mixed_inputs`: its inputs mixed by each
    numerator (``blocks``: ``N_k[rows, cols]``) and run through ``b_j / (a (1 - z^-1)^k)``
    (``coefficients``: :func:`_zoh_parts`, one ``a`` and ``k``) in one recursion and ``k``
    running sums."""
    a, k = coefficients[0][1], coefficients[0][2]
    if 2 * cols.size < blocks[0].shape[0] and len(coefficients) == 2:
        # a lag on one input of many outputs: its column through 1/d and s/d (two
        # recursions) and mixed after, fewer than one recursion per output
        x = np.ascontiguousarray(u[:, cols].T)[None]
        out = 0.0
        for (b, _, _), block in zip(coefficients, blocks):
            X = _recursion(b[None], a, k, x)  # (n_cols, N)
            out = out + block @ X
        return out
    bs = np.stack([b for b, _, _ in coefficients])
    xs = [_mixed_record(u, block, cols, products) for block in blocks]
    return _recursion(bs, a, k, xs)  # (n_rows, N)


def _recursion(bs: np.ndarray, a: np.ndarray, k: int, xs) -> np.ndarray:
    """:func:`~workbench._filter_kernel.iir_streams` through ``a``, then ``k`` running sums
    (the integrators ``1 / (1 - z^-1)`` of :func:`_zoh_parts`) along the samples."""
    out = iir_streams(bs, a, xs)
    for _ in range(k):
        out = np.cumsum(out, axis=-1)
    return out


def _mixed_record(u: np.ndarray, block: np.ndarray, cols, products: dict | None):
    """``block u[:, cols]^T`` (n_rows, N_samples), C-contiguous (``block``: a numerator's
    rows and columns of one filter), from / into the ``products`` cache when given."""
    key = None
    if products is not None:
        key = (block.shape, block.tobytes(), cols.tobytes())
        out = products.get(key)
        if out is not None:
            return out
    # block u^T straight into the (n_rows, N) layout: BLAS reads u^T as a flag on u, where
    # (u block^T)^T and its contiguous copy took ~10x longer (16 384 x 3: 485 vs 49 us)
    x = np.ascontiguousarray(block @ (u.T if cols.size == u.shape[1] else u[:, cols].T))
    if products is not None:
        _keep(products, key, x, RECORD_PRODUCTS_BYTES)
    return x


def line_responses(model, den, z: np.ndarray, fs: float, *, numerator_s=True, responses=None):
    """The filters of :func:`filtered_inputs` with their exact ZOH responses at the points ``z``.

    Parameters as :func:`filtered_lines`. Returns ``([(g, cols, hs, flat), ...], groups)``:
    per filter its output group ``g``, input columns ``cols``, the responses ``hs`` (one
    (n_l,) complex array per numerator: ``1/d``, and ``s/d`` when asked and ``den`` is
    second order) of :func:`zoh_responses`, looked up in / added to ``responses``, and its
    channels as flat indices (:func:`_channel_filters`).
    """
    filters, groups = _channel_filters(model, den, numerator_s)
    out = []
    for g, cols, nums, d, flat, roots in filters:
        hs = None
        if responses is not None:
            key = (d.tobytes(), len(nums), float(fs), float(model.delay_s))
            hs = responses.get(key)
        if hs is None:
            hs = zoh_responses(nums, d, z, 1.0 / fs, model.delay_s, roots=roots)
            if responses is not None:
                if len(responses) > RESPONSES_KEPT:
                    responses.clear()
                responses[key] = hs
        out.append((g, cols, hs, flat))
    return out, groups


def filtered_lines(
    model, den, U: np.ndarray, z: np.ndarray, fs: float, *, numerator_s=True, responses=None
):
    """:func:`filtered_inputs` in the frequency domain: the same filters at DFT lines.

    For a periodic input in steady state, the DFT of ``filtered_inputs`` over one
    period is ``H(z_l) U_l`` at its bins (``z_l = exp(2j pi l / period)``), with
    ``H`` the exact ZOH-sampled filter of :func:`zoh_response`.

    Parameters
    ----------
    model, den, fs, numerator_s
        As :func:`filtered_inputs`.
    U : (n_l, n_u) complex array
        DFT of the inputs (after the static input coupling) at the lines.
    z : (n_l,) complex array
        The lines' points on the unit circle, ``exp(2j pi f / fs)``.
    responses : dict, optional
        A cache of :func:`zoh_responses` at these ``z`` (the caller keeps one per ``z``),
        keyed by the filter's denominator (``den`` times the channel's lags), numerators
        and delay: a fit that moves one channel's lag recomputes that channel's filters
        only (the others are found here, the same arrays bit for bit).

    Returns
    -------
    X : (n_groups, n_l, n_u, 2) complex array
    groups : list of int arrays
    """
    lines, groups = line_responses(model, den, z, fs, numerator_s=numerator_s, responses=responses)
    X = np.zeros((len(groups), U.shape[0], model.n_u, 2), complex)
    for g, cols, hs, _ in lines:
        for k, h in enumerate(hs):
            X[g, :, cols, k] = (h[:, None] * U[:, cols]).T
    return X, groups


def mixed_lines(
    model, den, N0, N1, U: np.ndarray, z: np.ndarray, fs: float, *, responses=None, products=None
):
    """One mode's (or the feedthrough's) output at the lines, (n_l, n_y) complex.

    :func:`filtered_lines` mixed by the numerator ``N1 s + N0`` (``N0``, ``N1`` (n_y, n_u);
    ``N1`` None for the feedthrough, ``den`` None), as the simulation mixes
    :func:`filtered_inputs`: per filter ``h_0(z) (U N0^T) + h_1(z) (U N1^T)`` over its
    output rows and input columns, without forming the filtered inputs (a fit evaluates
    thousands of moved modes; their regressors are needed only by the linear fits).
    ``U``, ``z``, ``fs``, ``responses`` as :func:`filtered_lines`; ``products``: a cache of
    the inputs mixed by a numerator (:class:`_Mixed`, keyed by the numerator's bytes) for
    this ``U`` (the caller keeps one per ``U``): a moved mode keeps its numerator, and the
    product would otherwise cost more than the rest of the evaluation.
    """
    lines, groups = line_responses(model, den, z, fs, responses=responses)
    n_y, n_u = N0.shape
    Y = np.zeros((U.shape[0], n_y), complex)
    for k, N in enumerate((N0, N1) if N1 is not None and np.any(N1) else (N0,)):
        mixed = _mixed_inputs(U, N, products)
        for g, cols, hs, _ in lines:
            if k >= len(hs):
                continue  # no s/den filter (a first-order or no denominator)
            rows = groups[g]
            if cols.size == n_u:
                Q = mixed.all_inputs
            elif cols.size == 1:  # a lag on one input
                Q = mixed.per_input[:, :, cols[0]]
            else:
                Q = mixed.per_input[:, :, cols].sum(axis=-1)
            if rows.size == n_y:
                Y += hs[k][:, None] * Q
            else:  # a lag on some outputs
                Y[:, rows] += hs[k][:, None] * Q[:, rows]
    return Y


class _Mixed:
    """The inputs at the lines ``U`` (n_l, n_u) mixed by a numerator ``N`` (n_y, n_u):
    ``all_inputs`` = ``U N^T`` (n_l, n_y) and, when a filter takes some inputs only (a lag
    on an input), ``per_input`` (n_l, n_y, n_u) = ``N_ij U_lj`` (computed on first use)."""

    def __init__(self, U: np.ndarray, N: np.ndarray):
        self.U, self.N = U, N
        self.all_inputs = U @ N.T
        self._per_input = None

    @property
    def per_input(self) -> np.ndarray:
        if self._per_input is None:
            self._per_input = self.U[:, None, :] * self.N[None, :, :]
        return self._per_input


#: numerators whose mixed inputs a ``products`` cache of :func:`mixed_lines` keeps
PRODUCTS_KEPT = 256


def _mixed_inputs(U: np.ndarray, N: np.ndarray, products: dict | None) -> _Mixed:
    """:class:`_Mixed` of ``U`` and ``N``, from / into the ``products`` cache when given."""
    if products is None:
        return _Mixed(U, N)
    key = N.tobytes()
    out = products.get(key)
    if out is None:
        if len(products) > PRODUCTS_KEPT:
            products.clear()
        out = products[key] = _Mixed(U, N)
    return out


#: filters whose line responses a ``responses`` cache of :func:`filtered_lines` keeps (~15 MB
#: at 230 lines: a modal pattern screen moves every mode, and its variants share them)
RESPONSES_KEPT = 2048


def simulate(model, u: np.ndarray, fs: float) -> np.ndarray:
    """ZOH response of ``model`` from rest to ``u`` (N, n_u) sampled at ``fs`` (Hz): (N, n_y)."""
    u = np.asarray(u, float)
    if model.T_in is not None:
        u = u @ model.T_in.T
    y = np.zeros((u.shape[0], model.n_y))
    parts = [(None, model.D, None)] if np.any(model.D) else []
    parts += [(m.denominator(), *m.numerator()) for m in model.modes]
    for den, N0, N1 in parts:
        X, groups = filtered_inputs(model, den, u, fs)
        for g, rows in enumerate(groups):
            y[:, rows] += X[g, :, :, 0] @ N0[rows].T
            if N1 is not None and np.any(N1):
                y[:, rows] += X[g, :, :, 1] @ N1[rows].T
    if model.T_out is not None:
        y = y @ model.T_out.T
    return y


def _charpoly(M: np.ndarray) -> np.ndarray:
    """Characteristic polynomial det(zI - M), highest power first (Faddeev-LeVerrier, small n)."""
    n = M.shape[0]
    c = np.zeros(n + 1)
    c[0] = 1.0
    Mk = np.zeros_like(M)
    eye = np.eye(n)
    for k in range(1, n + 1):
        Mk = M @ Mk + c[k - 1] * eye
        c[k] = -np.trace(M @ Mk) / k
    return c


@functools.lru_cache(maxsize=512)
def _zoh_discretization(den_bytes: bytes, dt: float, frac: float):
    """(Ad, B0, B1, t, a) of the balanced controllable form of 1/den, ZOH with a delay ``frac``.

    ``t`` is the balancing's diagonal (the output row of a numerator is scaled by it) and
    ``a`` = det(zI - Ad). One discretization serves every numerator over the same ``den``
    (a mode's ``1/den`` and ``s/den``).
    """
    den = np.frombuffer(den_bytes)
    n = den.size - 1
    # controllable canonical form
    A = np.zeros((n, n))
    A[0, :] = -den[1:]
    if n > 1:
        A[1:, :-1] = np.eye(n - 1)
    B = np.zeros((n, 1))
    B[0, 0] = 1.0
    # balance the companion matrix: a0 ~ w^2 makes expm costly and inaccurate
    A, Tb = scipy.linalg.matrix_balance(A, permute=False)
    t = np.diag(Tb).copy()
    B = B / t[:, None]
    Ad, B0, B1, _ = c2d_zoh(A, B, dt, delay_s=frac)
    a = _charpoly(Ad)
    for x in (Ad, B0, B1, t, a):
        x.flags.writeable = False
    return Ad, B0, B1, t, a


@functools.lru_cache(maxsize=512)
def _zoh_parts(
    num_bytes: bytes, den_bytes: bytes, dt: float, frac: float, roots_bytes: bytes = b""
):
    """(b, a, k): the ZOH-sampled strictly proper part of num/den (monic den, num padded)
    as ``b / (a (1 - z^-1)^k)``.

    ``k = 2`` for a ``den`` with the rigid body's double pole at the origin (behind lags:
    :func:`_rigid_coefficients`), run as a recursion through ``a`` (the other poles) and
    two running sums (:func:`_recursion`); else ``k = 0``: partial fractions
    (:func:`_pole_coefficients`) or, for poles too close for them, the matrix exponential.
    A double pole at ``z = 1`` inside ``a`` is not one in floating point (``a``'s rounding
    splits it to ``1 +- sqrt(eps)``, and a direct-form recursion through it amplifies its
    rounding), and the matrix exponential's ``b`` (a difference of characteristic
    polynomials that are ~1/dt^2 larger than it) is ~1e-8 off. Over a 16 384-sample
    record the simulated rigid body then moved with a lag by ~1e-6 of the cost for a 1e-12
    change in ``tau``, 0.1-0.2 of the noise variance (an indep3 planar record), which a lag
    fit's difference quotients read as slope; here the cost is smooth to 1e-8 of it.

    Cached: a diagnosis fit evaluates the same mode with the same lag and delay
    many times (every other parameter's Jacobian column), and the discretization
    (balance, expm, three characteristic polynomials) costs more than the filter.
    ``roots_bytes``: den's roots (complex) where the caller knows them in closed form (a
    mode behind lags: :func:`_channel_filters`), else empty (then found numerically).
    """
    num, den = np.frombuffer(num_bytes), np.frombuffer(den_bytes)
    strict = num[1:] - num[0] * den[1:]
    if den.size >= 3 and den[-1] == 0 and den[-2] == 0:
        rigid = _rigid_coefficients(strict, den, roots_bytes, dt, frac)
        if rigid is not None:
            return rigid + (2,)
    roots = np.frombuffer(roots_bytes, complex) if roots_bytes else None
    closed = _pole_coefficients(strict, den, dt, frac, roots)
    if closed is not None:
        for x in closed:
            x.flags.writeable = False
        return closed + (0,)
    Ad, B0, B1, t, a = _zoh_discretization(den_bytes, dt, frac)
    C = (strict * t)[None, :]
    # SISO transfer functions of (Ad, B0, C) and (Ad, B1, C): numerator
    # det(zI - Ad + B C) - det(zI - Ad) (what scipy's ss2tf computes, without its overhead)
    b0 = _charpoly(Ad - B0 @ C) - a
    b1 = _charpoly(Ad - B1 @ C) - a
    b = np.concatenate([b0, [0.0]]) + np.concatenate([[0.0], b1])
    b.flags.writeable = False
    return b, a, 0


@functools.lru_cache(maxsize=512)
def _zoh_coefficients(
    num_bytes: bytes, den_bytes: bytes, dt: float, frac: float, roots_bytes: bytes = b""
):
    """(b, a) of :func:`_zoh_parts` over the whole denominator, ``a (1 - z^-1)^k`` (the
    frequency responses' form: on the unit circle away from ``z = 1`` the product is
    harmless)."""
    b, a, k = _zoh_parts(num_bytes, den_bytes, dt, frac, roots_bytes)
    if k:
        a = np.convolve(np.poly(np.ones(k)), a)  # (1 - z^-1)^k: [1, -2, 1]
        a.flags.writeable = False
    return b, a


def _pole_coefficients(
    strict: np.ndarray, den: np.ndarray, dt: float, frac: float, roots: np.ndarray | None = None
):
    """(b, a) of :func:`_zoh_coefficients` by partial fractions, or None.

    ``roots``: the roots of ``den`` when known (a mode's behind lags, in closed form:
    np.roots' eigenvalue solve cost more than the rest of the coefficients on a fit's
    hot path), else None (np.roots).

    Over the simple poles ``lam_k`` of the monic ``den`` (residues ``r_k`` of
    ``strict(s) / den(s)``), each pole samples to ``r_k (b0_k z^-1 + b1_k z^-2) / (1 - p_k
    z^-1)``, ``p_k = exp(lam_k dt)`` (:func:`_pole_responses`); over the common denominator
    ``a = prod_k (1 - p_k z^-1)`` the numerator is ``b = sum_k r_k (b0_k z^-1 + b1_k z^-2)
    prod_{j != k} (1 - p_j z^-1)``. The same filter as the discretization by the matrix
    exponential (to ~1e-13 relative), without its balancing, exponential and three
    characteristic polynomials: a fit moving a mode asks for new coefficients at every
    evaluation. None where two poles lie within :data:`_POLE_SEPARATION` (the rigid body's
    double pole among them) or the result is not finite: the exponential then.
    """
    n = den.size - 1
    if n == 0:
        return None
    if n == 2:  # a mode, the most frequent filter: in scalar arithmetic
        return _pair_coefficients(strict, float(den[1]), float(den[2]), dt, frac)
    if roots is not None and roots.size == n:
        lam = np.asarray(roots, complex)
    else:
        lam = np.array([-den[1]], complex) if n == 1 else np.roots(den).astype(complex)
    if _too_close(lam):
        return None
    # scalar arithmetic from here (n <= 4 behind lags: numpy's per-call cost dominated)
    lam = [complex(x) for x in lam]
    terms = _pole_terms(strict, den, lam, dt, frac)
    if terms is None:
        return None
    r, p, b0, b1 = terms
    b = [0j] * (n + 2)
    for k in range(n):
        rest = _poly_z(p[:k] + p[k + 1 :])  # prod_{j != k} (1 - p_j z^-1), length n
        for i, c in enumerate(rest):
            b[1 + i] += r[k] * b0[k] * c
            b[2 + i] += r[k] * b1[k] * c
    a = _poly_z(p)
    b, a = np.array([x.real for x in b]), np.array([x.real for x in a])
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(a))):
        return None
    return b, a


#: smallest ``|lam| dt`` of a pole beside the rigid body's double pole that
#: :func:`_rigid_coefficients` takes: its partial fractions cancel to about
#: ``eps / (|lam| dt)`` relative (a lag 1000x slower than the sample rate: ~1e-13)
_RIGID_SEPARATION = 1e-6


def _rigid_coefficients(strict: np.ndarray, den: np.ndarray, roots_bytes: bytes, dt, frac):
    """(b, a) with ``strict(s) / den(s)`` sampled = ``b / (a (1 - z^-1)^2)``, for ``den = s^2
    q(s)`` (monic: the rigid body's double pole at the origin times lags, ``q``'s roots
    simple: given in ``roots_bytes`` with the two zeros, or found here), or None.

    Partial fractions ``c2 / s^2 + c1 / s + sum_k r_k / (s - lam_k)`` (``c2 = strict(0) /
    q(0)``, ``c1 = (strict'(0) q(0) - strict(0) q'(0)) / q(0)^2``, ``r_k = strict(lam_k) /
    den'(lam_k)``), each sampled exactly with the input delayed by ``frac`` within a
    sample: ``1/s^2`` through the double integrator's state ``[[1, dt], [0, 1]]`` (the input
    held over ``[frac, dt]``, the previous one over ``[0, frac]``), ``1/s`` and each
    ``lam_k`` as :func:`_pole_coefficients` samples a pole; ``a = prod_k (1 - exp(lam_k dt)
    z^-1)``. Checked against the analytic step response of ``1 / (s^2 (1 + s tau))``
    (tests/test_rigid_zoh.py).
    """
    n = den.size - 1
    if roots_bytes:
        rest = [complex(x) for x in np.frombuffer(roots_bytes, complex) if x != 0]
    else:
        rest = [complex(x) for x in np.roots(den[:-2])] if n > 2 else []
    if len(rest) != n - 2 or _too_close(np.array(rest, complex)):
        return None
    if any(abs(x) * dt < _RIGID_SEPARATION for x in rest):
        return None
    q = [float(c) for c in den[:-2]]
    q0, q1 = q[-1], (q[-2] if len(q) > 1 else 0.0)  # q(0), q'(0)
    s0, s1 = float(strict[-1]), (float(strict[-2]) if strict.size > 1 else 0.0)
    c2, c1 = s0 / q0, (s1 * q0 - s0 * q1) / (q0 * q0)
    terms = _pole_terms(strict, den, rest, dt, frac)
    if terms is None:
        return None
    r, p, b0, b1 = terms
    h = dt - frac
    al0, al1 = 0.5 * h * h, dt * frac - 0.5 * frac * frac  # position from u[k], u[k-1]
    two = [0.0, al0, al1 - al0 + dt * h, dt * frac - al1]  # 1/s^2 over (1 - z^-1)^2
    one = [0.0, h, frac, 0.0]  # 1/s over (1 - z^-1), times (1 - z^-1) below
    one = [one[i] - (one[i - 1] if i else 0.0) for i in range(4)]
    a = _poly_z(p)  # prod_k (1 - p_k z^-1), length n - 1
    b = [0j] * (n + 2)
    for i, c in enumerate(a):
        for j in range(4):
            b[i + j] += (c2 * two[j] + c1 * one[j]) * c
    for k in range(len(rest)):
        others = _poly_z([1.0, 1.0] + p[:k] + p[k + 1 :])  # (1 - z^-1)^2 prod_{j != k}
        for i, c in enumerate(others):
            b[1 + i] += r[k] * b0[k] * c
            b[2 + i] += r[k] * b1[k] * c
    b, a = np.array([x.real for x in b]), np.array([complex(x).real for x in a])
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(a))):
        return None
    b.flags.writeable = False
    a.flags.writeable = False
    return b, a


def _pole_terms(strict: np.ndarray, den: np.ndarray, lam: list, dt: float, frac: float):
    """Per simple pole ``lam_k`` of the monic ``den``: its residue ``r_k = strict(lam_k) /
    den'(lam_k)``, ``p_k = exp(lam_k dt)`` and the sampled pole's numerator ``b0_k z^-1 +
    b1_k z^-2`` with the input delayed by ``frac`` within a sample (lists, scalar
    arithmetic), or None where they overflow."""
    n = den.size - 1
    dden = [(n - i) * float(den[i]) for i in range(n)]  # den', highest power first
    try:
        r = [_horner(strict, x) / _horner(dden, x) for x in lam]
        p = [cmath.exp(x * dt) for x in lam]
        b0 = [_integral(x, dt - frac, dt) for x in lam]
        b1 = [cmath.exp(x * (dt - frac)) * _integral(x, frac, dt) for x in lam]
    except (OverflowError, ZeroDivisionError):
        return None
    return r, p, b0, b1


def _horner(c, x: complex) -> complex:
    """The polynomial with coefficients ``c`` (highest power first) at ``x``."""
    v = 0j
    for ci in c:
        v = v * x + float(ci)
    return v


def _poly_z(p: list) -> list:
    """Coefficients of ``prod_k (1 - p_k z^-1)`` in powers of ``z^-1`` (0 first)."""
    c = [1 + 0j]
    for pk in p:
        c = [x - pk * y for x, y in zip(c + [0j], [0j] + c)]
    return c


def _integral(lam: complex, t: float, dt: float) -> complex:
    """``int_0^t exp(lam s) ds``, its limit ``t`` at ``lam = 0`` (as :func:`_pole_responses`)."""
    x = lam * t
    if abs(lam) * dt < 1e-8:
        return t * (1 + 0.5 * x)
    return _expm1(x) / lam


def _pair_coefficients(strict: np.ndarray, a1: float, a0: float, dt: float, frac: float):
    """:func:`_pole_coefficients` of ``s^2 + a1 s + a0`` (a mode), its two poles in closed
    form and every step in scalar arithmetic (the array path's calls cost ~10x more)."""
    h = 0.5 * a1
    q = cmath.sqrt(h * h - a0)
    l1, l2 = q - h, -h - q
    d = 2.0 * q  # den'(l1) = -den'(l2) = l1 - l2
    if abs(d) <= _POLE_SEPARATION * max(abs(l1), abs(l2), 1e-300):
        return None
    c1, c0 = float(strict[0]), float(strict[1])
    r1, r2 = (c1 * l1 + c0) / d, -(c1 * l2 + c0) / d

    try:
        p1, p2 = cmath.exp(l1 * dt), cmath.exp(l2 * dt)
        b01, b02 = _integral(l1, dt - frac, dt), _integral(l2, dt - frac, dt)
        if frac > 0:
            b11 = cmath.exp(l1 * (dt - frac)) * _integral(l1, frac, dt)
            b12 = cmath.exp(l2 * (dt - frac)) * _integral(l2, frac, dt)
        else:
            b11 = b12 = 0.0
    except OverflowError:
        return None
    b = np.array(
        [
            0.0,
            (r1 * b01 + r2 * b02).real,
            (r1 * (b11 - b01 * p2) + r2 * (b12 - b02 * p1)).real,
            -(r1 * b11 * p2 + r2 * b12 * p1).real,
        ]
    )
    a = np.array([1.0, -(p1 + p2).real, (p1 * p2).real])
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(a))):
        return None
    return b, a


def _expm1(x: complex) -> complex:
    """``exp(x) - 1`` without the cancellation near x = 0 (cmath has no expm1):
    ``e^a cos b - 1 = expm1(a) cos b - 2 sin(b/2)^2`` for ``x = a + ib``."""
    a, b = x.real, x.imag
    return complex(
        math.expm1(a) * math.cos(b) - 2.0 * math.sin(0.5 * b) ** 2, math.exp(a) * math.sin(b)
    )


def _monic(nums, den):
    """Numerators over a monic ``den``, each padded to ``den``'s length (highest power first)."""
    den = np.atleast_1d(np.asarray(den, float))
    den0, den = den[0], den / den[0]
    padded = []
    for num in nums:
        num = np.atleast_1d(np.asarray(num, float)) / den0
        padded.append(np.concatenate([np.zeros(den.size - num.size), num]))
    return padded, den


def zoh_filter(num, den, u: np.ndarray, dt: float, delay_s: float = 0.0) -> np.ndarray:
    """Exact ZOH response of ``num(s)/den(s)`` (proper) to ``u`` (N, ...), input delay, from rest.

    ``dt`` and ``delay_s`` in s; the delay may be any fraction of a sample.
    """
    (num,), den = _monic([num], den)
    n = den.size - 1
    d = num[0]
    m_int, frac = split_delay(delay_s, dt)
    u = np.asarray(u, float)
    N = u.shape[0]
    y = np.zeros(u.shape)
    if n > 0:
        b, a, k = _zoh_parts(num.tobytes(), den.tobytes(), float(dt), float(frac))
        # lfilter's recursion, compiled, on the signals laid out one after the other
        flat = np.ascontiguousarray(u.reshape(N, -1).T)
        y = _recursion(b[None], a, k, flat[None]).T.reshape(u.shape)
        if m_int:
            y = np.concatenate([np.zeros((min(m_int, N),) + u.shape[1:]), y[: max(N - m_int, 0)]])
    if d:
        # the held input delayed by m_int + frac samples, sampled at k dt
        shift = m_int + (1 if frac > 0 else 0)
        ud = np.zeros(u.shape)
        if shift < N:
            ud[shift:] = u[: N - shift]
        y = y + d * ud
    return y


def zoh_response(num, den, z: np.ndarray, dt: float, delay_s: float = 0.0) -> np.ndarray:
    """Frequency response of :func:`zoh_filter`'s discrete filter at the points ``z``.

    The exact ZOH-sampled ``num(s)/den(s)`` with its input delay, as a transfer
    function of the shift operator: ``zoh_filter``'s output in periodic steady
    state has the DFT ``zoh_response(...) * DFT(u)`` at every bin. ``z`` (n,)
    complex, usually on the unit circle; ``dt``, ``delay_s`` in s. Returns (n,) complex.
    """
    return zoh_responses([num], den, z, dt, delay_s)[0]


def mode_line_responses(a1, a0, z: np.ndarray, fs: float, delay_s: float = 0.0):
    """The line responses of many modes without lags: ``1/den`` and ``s/den`` per mode.

    :func:`line_responses`' filter for ``den = s^2 + a1_p s + a0_p`` (no lag), evaluated for
    P denominators at once (a screen of a moved mode's grid). ``a1``, ``a0`` (P,) (1/s, 1/s^2);
    ``z`` (n_l,), ``fs`` Hz, ``delay_s`` s as :func:`zoh_responses`. Returns ``H``
    (P, 2, n_l) complex (``H[p, 0]`` the response of ``1/den_p``, ``H[p, 1]`` of
    ``s/den_p``, as :func:`zoh_responses` gives them) and ``ok`` (P,): False where the
    partial fractions do not apply (coinciding poles: :func:`zoh_responses` then).
    """
    dt = 1.0 / fs
    m_int, frac = split_delay(delay_s, dt)
    zi = 1.0 / np.asarray(z, complex)
    # the numerators 1 and s over the monic den: strict parts (0, 1) and (1, 0)
    H, ok = _pair_responses(_STRICT_TWO, np.asarray(a1, float), np.asarray(a0, float), zi, dt, frac)
    if m_int:
        H *= zi**m_int
    return H, ok


_STRICT_TWO = np.array([[0.0, 1.0], [1.0, 0.0]])


def zoh_responses(nums, den, z: np.ndarray, dt: float, delay_s: float = 0.0, *, roots=None):
    """:func:`zoh_response` of several numerators over one ``den`` (one pole computation).

    ``roots``: ``den``'s roots (complex array) when the caller knows them in closed form (a
    mode's times its channel's lags), else None (computed here). Returns a list of (n,)
    complex arrays, one per numerator."""
    padded, den = _monic(nums, den)
    n = den.size - 1
    m_int, frac = split_delay(delay_s, dt)
    zi = 1.0 / np.asarray(z, complex)
    out = [np.zeros(zi.shape, complex) for _ in padded]
    if n > 0:
        strict = np.array([num[1:] - num[0] * den[1:] for num in padded])
        hs = _distinct_pole_response(strict, den, zi, dt, frac, roots)
        if hs is None:
            hs = []
            for num in padded:
                b, a = _zoh_coefficients(num.tobytes(), den.tobytes(), float(dt), float(frac))
                # b, a are lfilter's coefficients of z^-1, lowest power first
                hs.append(np.polyval(b[::-1], zi) / np.polyval(a[::-1], zi))
        shift = zi**m_int if m_int else 1.0
        out = [h * shift for h in hs]
    for i, num in enumerate(padded):
        if num[0]:
            out[i] = out[i] + num[0] * zi ** (m_int + (1 if frac > 0 else 0))
    return out


#: poles closer than this (relative) are treated as repeated: partial fractions would lose
#: about its inverse squared in accuracy, and the discretization by expm takes over
_POLE_SEPARATION = 1e-3


def _distinct_pole_response(strict, den, zi, dt: float, frac: float, roots=None):
    """ZOH responses of ``strict_i(s) / den(s)`` (monic ``den``) by partial fractions.

    Each simple pole ``lam`` with residue ``r`` samples exactly to
    ``r (b0 z^-1 + b1 z^-2) / (1 - exp(lam dt) z^-1)`` with ``b0 = (exp(lam (dt - frac)) - 1)
    / lam`` and ``b1 = exp(lam (dt - frac)) (exp(lam frac) - 1) / lam`` (the scalar case of
    :func:`workbench.sim.c2d_zoh`). ``strict`` (n_num, n) numerator coefficients; returns a
    (n_num, n_l) complex array, or None when two poles are within :data:`_POLE_SEPARATION`
    of each other (or a pole is at 0 with another one): then the caller's discretization
    by the matrix exponential applies. The rigid body's double pole at 0 (behind lags) has
    its own closed form, :func:`_rigid_body_response`: more accurate than that
    discretization's characteristic polynomials, and not recomputed per delay. ``roots``:
    ``den``'s roots when known (:func:`zoh_responses`).
    """
    if _rigid_body(den):
        return _rigid_body_response(strict, den, zi, dt, frac, roots)
    if den.size == 3:  # a mode (no lag): the most frequent filter, in scalar arithmetic
        return _pair_response(strict, float(den[1]), float(den[2]), zi, dt, frac)
    lam = np.roots(den) if roots is None else roots
    if _too_close(lam):
        return None
    hs = _pole_sum(_residues(strict, den, lam), lam, zi, dt, frac)
    return hs if np.all(np.isfinite(hs)) else None


def _too_close(lam: np.ndarray) -> bool:
    """Whether two of the poles ``lam`` lie within :data:`_POLE_SEPARATION` (relative)."""
    if lam.size < 2:
        return False
    diff = np.abs(lam[:, None] - lam[None, :]) + np.diag(np.full(lam.size, np.inf))
    size = np.maximum(np.abs(lam[:, None]), np.abs(lam[None, :]))
    return bool(np.any(diff <= _POLE_SEPARATION * np.maximum(size, 1e-300)))


def _residues(strict: np.ndarray, den: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Residues (n_num, n_poles) of ``strict_i(s) / den(s)`` at the simple roots ``lam`` of the
    monic ``den``: ``strict_i(lam) / den'(lam)``, both polynomials evaluated by one
    Vandermonde product (``np.polyval`` per row costs ~20 us of call overhead each)."""
    n = den.size - 1
    V = lam[None, :] ** np.arange(n - 1, -1, -1)[:, None]  # (n, n_poles): lam^(n-1) .. 1
    dden = (np.arange(n, 0, -1) * den[:-1]) @ V  # den' = sum_k (n - k) den_k s^(n-1-k)
    return (strict @ V) / dden


def _pair_response(strict, a1: float, a0: float, zi, dt: float, frac: float):
    """:func:`_distinct_pole_response` of ``s^2 + a1 s + a0`` (a mode): one mode of
    :func:`_pair_responses`; None when its poles coincide (a critically damped mode)."""
    hs, ok = _pair_responses(strict, np.array([a1]), np.array([a0]), zi, dt, frac)
    return hs[0] if ok[0] else None


def _pair_responses(strict, a1: np.ndarray, a0: np.ndarray, zi, dt: float, frac: float):
    """:func:`_distinct_pole_response` of the modes ``s^2 + a1_p s + a0_p``, at once.

    The two poles of each in closed form, ``lam = -a1 / 2 +- q``, ``den'(lam) = +-2 q =
    +-(lam_1 - lam_2)``: the partial fractions of :func:`_distinct_pole_response` without
    its root finding and polynomial evaluations (a screen or a fit evaluates thousands
    of moved modes; a screen of a moved mode evaluates its whole grid in one call).

    ``strict`` (n_num, 2) numerator coefficients; ``a1``, ``a0`` (P,). Returns ``hs``
    (P, n_num, n_l) complex and ``ok`` (P,): False where the poles coincide within
    :data:`_POLE_SEPARATION` or the response is not finite (the caller's discretization
    by the matrix exponential applies there).
    """
    h = 0.5 * np.asarray(a1, float)
    q = np.sqrt((h * h - a0).astype(complex))
    l1, l2 = q - h, -h - q
    d = 2.0 * q
    ok = np.abs(d) > _POLE_SEPARATION * np.maximum(np.maximum(np.abs(l1), np.abs(l2)), 1e-300)
    if not ok.all():
        d = np.where(ok, d, 1.0)
    G = _pole_responses(np.concatenate([l1, l2]), zi, dt, frac)
    G1, G2 = G[: l1.size], G[l1.size :]
    hs = np.empty((l1.size, strict.shape[0], zi.size), complex)
    for i, (c1, c0) in enumerate(strict.tolist()):
        hs[:, i] = ((c1 * l1 + c0) / d)[:, None] * G1 - ((c1 * l2 + c0) / d)[:, None] * G2
    ok &= np.isfinite(hs).all(axis=(1, 2))
    return hs, ok


def _pole_responses(lam: np.ndarray, zi, dt: float, frac: float) -> np.ndarray:
    """(m, n_l) ZOH responses of ``1 / (s - lam_k)`` at ``zi`` = 1/z with the delay ``frac``:
    ``(b0 z^-1 + b1 z^-2) / (1 - exp(lam dt) z^-1)`` of :func:`_distinct_pole_response`
    (``lam = 0``, the integrator, included), ``lam`` (m,) complex."""

    def integral(h):  # int_0^h exp(lam s) ds, its limit h at lam = 0
        x = lam * h
        small = np.abs(x) < 1e-8
        if not small.any():
            return np.expm1(x) / lam
        return np.where(small, h * (1 + 0.5 * x), np.expm1(x) / np.where(small, 1.0, lam))

    lam = np.asarray(lam, complex)
    b0 = integral(dt - frac)[:, None]
    p = np.exp(lam * dt)[:, None]
    if frac > 0:
        b1 = (np.exp(lam * (dt - frac)) * integral(frac))[:, None]
        return (b0 + b1 * zi) * zi / (1.0 - p * zi)
    return b0 * zi / (1.0 - p * zi)


def _pole_sum(r: np.ndarray, lam: np.ndarray, zi, dt: float, frac: float) -> np.ndarray:
    """``sum_k r[i, k] g_k`` (n_num, n_l): the simple poles' ZOH responses
    (:func:`_pole_responses`) weighted by the residues ``r`` (n_num, n_poles)."""
    return r @ _pole_responses(lam, zi, dt, frac)


#: the rigid body's closed form (:func:`_rigid_body_response`) takes the other poles down to
#: ``|lam| dt`` = this: closer to 0 its partial fractions cancel (a loss of about
#: ``(pi / (|lam| dt))^2`` in relative accuracy at the Nyquist frequency, ~1e-11 here)
_RIGID_POLE_MIN = 1e-2


def _rigid_body(den) -> bool:
    """Whether monic ``den`` is ``s^2 q(s)`` with ``q(0) != 0``: a rigid body (behind lags)."""
    return den.size >= 3 and den[-1] == 0.0 and den[-2] == 0.0 and den[-3] != 0.0


def _rigid_body_response(strict, den, zi, dt: float, frac: float, roots=None):
    """ZOH responses of ``strict_i(s) / (s^2 q(s))`` in closed form (:func:`_rigid_body` ``den``).

    Partial fractions ``c2 / s^2 + c1 / s + sum r_k / (s - lam_k)`` over the simple roots
    ``lam_k`` of ``q``: ``c2 = strict(0) / q(0)``, ``c1 = (strict / q)'(0)``, and ``r_k`` as in
    :func:`_distinct_pole_response`. The double integrator's input held on
    ``[k dt + frac, (k+1) dt + frac)`` and sampled at ``n dt`` has the pulse response
    ``S(m dt - frac) - S((m-1) dt - frac)``, ``S(t) = t^2 / 2`` for ``t >= 0``: ``frac^2 / 2`` more
    than ``dt^2 (m - 1/2) - dt frac`` at ``m = 1``, that at every ``m >= 2``, whose sum is
    ``frac^2 / 2 w + dt^2 w / (1 - w)^2 - (dt^2 / 2 + dt frac) w / (1 - w)`` with ``w = z^-1``.
    Returns (n_num, n_l) complex, or None (the caller's matrix exponential then) when two of
    ``q``'s roots are within :data:`_POLE_SEPARATION` or one is within :data:`_RIGID_POLE_MIN`
    of 0 (in ``|lam| dt``). ``roots``: ``den``'s roots when known (the double 0 among them).
    """
    q = den[:-2]
    if roots is not None:
        lam = roots[roots != 0]
    elif q.size == 1:
        lam = np.zeros(0, complex)
    elif q.size == 2:  # one lag: its root directly (np.roots costs 20x more)
        lam = np.array([-q[1] / q[0]], complex)
    else:
        lam = np.roots(q).astype(complex)
    if _too_close(lam):
        return None
    if np.any(np.abs(lam) * dt < _RIGID_POLE_MIN):
        return None
    q0, q1 = q[-1], (q[-2] if q.size > 1 else 0.0)  # q(0), q'(0)
    c2 = strict[:, -1] / q0
    c1 = (strict[:, -2] * q0 - strict[:, -1] * q1) / q0**2
    poles = np.concatenate([[0.0], lam])  # the integrator, then q's roots
    r = _residues(strict, den, lam)
    r = np.concatenate([c1[:, None], r], axis=1)  # (n_num, 1 + n_lam)
    w = zi
    double = (
        0.5 * frac**2 * w + dt**2 * w / (1.0 - w) ** 2 - (0.5 * dt**2 + dt * frac) * w / (1.0 - w)
    )
    hs = _pole_sum(r, poles, zi, dt, frac) + c2[:, None] * double[None, :]
    return hs if np.all(np.isfinite(hs)) else None
