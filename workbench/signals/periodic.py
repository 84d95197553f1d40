"""One periodic record: experiment blocks, steady-state periods, excited lines, spectra, noise.

Every consumer of periodic (multisine) data goes through :class:`PeriodicRecord`:
FRF estimation, subspace identification, modal refinement, the model-validation
F-test of ``compare``, the nonlinearity detector and the data-quality checks.

Data flow::

    TimeData (period set) ---------------.
                                         +--> periodic_record(...) --> PeriodicRecord:
    MultisineExperiment (blocks known) --'    blocks, dropped transient periods,
                                              mean-period DFTs U, Y, R per block,
                                              excited lines, noise from the period spread

**Blocks.** A record may hold several experiments one after the other (spec 1a
concatenates them): a *block* is a run of identical periods of one excitation.
Blocks are found from the excitation (``r``, else ``u``): a period starts a new
block when it differs from the previous one by more than
:data:`BLOCK_REL_CHANGE` (relative norm); periods without excitation are left
out. Periods of different blocks are never averaged together.

**Transient.** In every block of ``n`` periods the first
``min(n_transient, max(n - min_periods, 0))`` periods are dropped: the
transient from rest or from the switch to a new excitation, but never so many
that fewer than ``min_periods`` stay; a block shorter than ``min_periods`` is
refused (a consumer that needs all of ``n_transient`` dropped checks
:attr:`PeriodicRecord.n_dropped`).

**Spectra.** The DFT is numpy's unnormalized ``rfft`` of one period (multiply
by ``2 / period`` for sine amplitudes). The DFT is linear, so the mean over the
kept periods of the per-period DFTs is the DFT of the mean period, which is
what is computed (one FFT per channel and block).

**Excited lines.** Per block, the bins where the reference's mean-period power
(summed over channels) exceeds :data:`EXCITED_REL_POWER` times that block's
strongest bin and, when the reference varies from period to period (a
measured ``u``), :data:`EXCITED_SNR` times the variance of its mean; DC and the
Nyquist bin are never excited lines (their DFT is real, the noise there is not
circular).

**Noise.** Per block of ``n >= 2`` kept periods, the DFT ``D_p`` of each
period's deviation from the block mean gives the variance of the block-mean
DFT, ``sum_p |D_p|^2 / (n (n - 1))`` (Pintelon & Schoukens, *System
Identification*, 2nd ed., 2012, section 2.5: the sample variance of the mean
over periods). These DFTs stay in float64. In float32 they take half the time
(benchmarks/bench_frf.py: 6 blocks x 11 periods x 6 channels, about 5 -> 2.6
ms), but their rounding is relative to the spread's total power, not to each
bin's, so a bin far below the mean power carries a larger relative error.
On the benchmark's record (bins down to 1/700 of the mean) the median error
is 1e-7 and the worst 3e-5; on 1/f to 1/f^3 spreads (bins 1e5 below the
mean) 1e-4. Far inside the estimate's own scatter (about
30 % with 11 periods), but not the 1e-5 agreement with float64 that a result
of record is held to.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft

from workbench.core.errors import InputError
from workbench.io.formats import TimeData

__all__ = [
    "EXCITED_REL_POWER",
    "EXCITED_SNR",
    "BLOCK_REL_CHANGE",
    "PeriodicRecord",
    "periodic_record",
    "split_blocks",
]

EXCITED_REL_POWER = 1e-8
"""A bin is excited when its reference power exceeds this share of the block's strongest bin.

-80 dB in power (1e-4 in amplitude). Why this value: the bins a generated
multisine leaves out hold rounding only (below 1e-20 of the peak in float64,
about 1e-13 after a float32 file), so anything above 1e-8 is designed
excitation; and designed amplitude spectra (shaped multisines, 1/f or mass
compensated) span far less than 40 dB in amplitude, so no designed line falls
below it. It replaces the five private thresholds of before (1e-4, 1e-6,
1e-8, 1e-10) with the one that is both far above rounding and far below any
designed line. A measured (noisy) ``u`` as reference carries noise at every
bin: :data:`EXCITED_SNR` keeps that noise out.
"""

EXCITED_SNR = 100.0
"""A reference that varies over periods: a line must also exceed this times its noise variance.

20 dB. At a bin without excitation the reference's mean-period power over
the estimated variance of that mean is F-distributed with mean about 1; for
one channel and d = 2 (n_kept - 1) degrees of freedom it exceeds 100 with
probability (1 + 200 / d)^(-d / 2): 1 % with 2 kept periods, 4e-4 with 3,
4e-11 with 11 (less with more channels). A designed line measured 20 dB above
its noise is kept.
Without it a measured (noisy) ``u`` as reference would make every bin an
excited line. A reference that repeats bit for bit (a generator's ``r`` or
open-loop ``u``) has no noise and only :data:`EXCITED_REL_POWER` applies.
"""

BLOCK_REL_CHANGE = 0.1
"""A period starts a new block when it differs from the previous one by this relative norm."""

_SILENT_BLOCK = 1e-12  # a block whose excitation norm is below this share of the peak is no block


def split_blocks(x: np.ndarray, period: int) -> list[tuple[int, int]]:
    """Blocks of identical periods in an excitation record.

    Parameters
    ----------
    x : (N, n_ch) array
        The excitation (``r``, or ``u`` in open loop), N a multiple of ``period``.
    period : int
        Samples per period.

    Returns
    -------
    list of (first_period, n_periods)
        Periods whose excitation is zero are skipped.
    """
    per = x.reshape(-1, 1, period * x.shape[1])
    # row dot products as stacked (1, n) @ (n, 1) products: BLAS dots, twice einsum's speed
    sq = (per @ np.swapaxes(per, 1, 2))[:, 0, 0]
    norm = np.sqrt(sq)
    # ||a - b||^2 = ||a||^2 + ||b||^2 - 2 a.b without a copy of the differences; its rounding
    # (about 1e-8 of the norm) is far below the 10 % that starts a block
    dot = (per[1:] @ np.swapaxes(per[:-1], 1, 2))[:, 0, 0]
    diff = np.sqrt(np.maximum(sq[1:] + sq[:-1] - 2 * dot, 0.0))
    scale = np.maximum(norm[1:], norm[:-1])
    new = np.concatenate([[True], diff > BLOCK_REL_CHANGE * np.where(scale > 0, scale, 1.0)])
    starts = list(np.flatnonzero(new)) + [per.shape[0]]
    peak = norm.max() if norm.size else 0.0
    blocks = []
    for a, b in zip(starts[:-1], starts[1:]):
        if norm[a] > _SILENT_BLOCK * peak:
            blocks.append((int(a), int(b - a)))
    return blocks


def _mean_period(p: np.ndarray) -> tuple[np.ndarray, bool]:
    """Mean of periods (n, P, ch), and whether all are identical (then exactly the first).

    A generator's signal repeats bit for bit, but the float mean of n equal
    numbers is not always that number: taking the first period keeps the
    deviations exactly zero, so that no spread (and no FFT of it) is computed.
    """
    if p.shape[0] == 1 or (
        np.array_equal(p[1], p[0]) and np.array_equal(p, np.broadcast_to(p[0], p.shape))
    ):
        return p[0].copy(), True
    return p.mean(axis=0), False


def _rfft_periods(d: np.ndarray, out: np.ndarray, workers: int | None) -> np.ndarray:
    """rfft of periods (n, P, ch) along axis 1, into ``out`` (n, P // 2 + 1, ch) when it can.

    numpy's rfft (pocketfft, like scipy's) writes into a given buffer; scipy's
    has the ``workers`` but always allocates its output.
    """
    if (scipy.fft.get_workers() if workers is None else workers) == 1:
        return np.fft.rfft(d, axis=1, out=out)
    return scipy.fft.rfft(d, axis=1, workers=workers)


def _view(x: np.ndarray) -> np.ndarray:
    v = np.asarray(x).view()
    v.setflags(write=False)
    return v


@dataclass(frozen=True)
class PeriodicRecord:
    """A periodic record split into experiment blocks, with its period-averaged spectra.

    Build it with :func:`periodic_record`. ``n_b`` blocks, ``n_bins = period // 2 + 1``.

    Attributes
    ----------
    fs : float
        Sampling frequency, Hz.
    period : int
        Samples per period.
    first : (n_b,) int array
        Index (in periods from the record's start) of the first kept period of each block.
    n_kept : (n_b,) int array
        Steady-state periods kept per block (>= 1).
    n_dropped : (n_b,) int array
        Transient periods dropped at the start of each block.
    U, Y : (n_b, n_bins, n_u), (n_b, n_bins, n_y) complex arrays
        DFT of the mean kept period of the input (N) and output (m), unnormalized.
    R : (n_b, n_bins, n_u) complex array or None
        The same for the excitation ``r``; None when the record has none.
    ref_power : (n_b, n_bins) array
        Power of the reference's (``R``, else ``U``) mean DFT summed over channels,
        DC and Nyquist set to 0, N^2.
    excited : (n_b, n_bins) bool array
        ``ref_power > EXCITED_REL_POWER * max`` per block, and, for a reference
        that varies over periods, ``ref_power > EXCITED_SNR * (its noise variance)``.
    u_mean, y_mean, r_mean : (n_b, period, n_u), (n_b, period, n_y), (n_b, period, n_u) arrays
        Mean kept period of each block, N and m (``r_mean`` None without ``r``).
    repeats : dict of str to (n_b,) bool array
        For "u", "y", "r": whether the kept periods of each block are identical
        bit for bit (a generator's signal; then the mean is the first period and
        the spread is exactly zero).
    u, y, r : (N, n_u), (N, n_y), (N, n_u) arrays
        The record's signals, for the period spread: read-only views, not
        copies (the record is on the FRF's hot path; TimeData's arrays are
        read-only copies already).
    """

    fs: float
    period: int
    first: np.ndarray
    n_kept: np.ndarray
    n_dropped: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    R: np.ndarray | None
    ref_power: np.ndarray
    excited: np.ndarray
    u_mean: np.ndarray = field(repr=False)
    y_mean: np.ndarray = field(repr=False)
    r_mean: np.ndarray | None = field(repr=False)
    repeats: dict = field(repr=False)
    u: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    r: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_blocks(self) -> int:
        return int(self.first.shape[0])

    @property
    def n_bins(self) -> int:
        return self.period // 2 + 1

    @property
    def freq_hz(self) -> np.ndarray:
        """(n_bins,) frequency of every DFT bin of one period, Hz."""
        return np.arange(self.n_bins) * self.fs / self.period

    @property
    def lines(self) -> np.ndarray:
        """(n_l,) int: bins excited in at least one block, increasing."""
        return np.flatnonzero(self.excited.any(axis=0))

    def _signal(self, x) -> tuple[np.ndarray, np.ndarray | None]:
        """``x`` as an array, and its stored block means when it is one of "u", "y", "r"."""
        if isinstance(x, str):
            if x not in ("u", "y", "r") or getattr(self, x) is None:
                raise InputError(
                    f"x: expected 'u', 'y', 'r' (when recorded) or an array, got {x!r}"
                )
            return getattr(self, x), getattr(self, f"{x}_mean")
        x = np.asarray(x)
        if x.ndim != 2 or x.shape[0] != self.u.shape[0]:
            raise InputError(
                f"x: expected shape ({self.u.shape[0]}, n) on the record's time base, got {x.shape}"
            )
        return x, None

    def periods(self, x) -> list[np.ndarray]:
        """The kept periods of a signal on this record's time base, per block.

        Parameters
        ----------
        x : (N, n) array or {"u", "y", "r"}
            Any signal sampled like the record (e.g. a residual ``y - y_model``).

        Returns
        -------
        list of (n_kept_b, period, n) arrays, one per block (views of ``x``).
        """
        x, _ = self._signal(x)
        per = x.reshape(-1, self.period, x.shape[1])
        return [per[a : a + n] for a, n in zip(self.first.tolist(), self.n_kept.tolist())]

    def mean_spectrum(self, x, *, workers: int | None = None) -> np.ndarray:
        """(n_b, n_bins, n) complex: DFT of the mean kept period of ``x`` (N, n), per block."""
        x, means = self._signal(x)
        if means is None:
            means = np.stack([_mean_period(p)[0] for p in self.periods(x)])
        return scipy.fft.rfft(means, axis=1, workers=workers)

    def deviation_spectra(self, x, block: int, *, workers: int | None = None) -> np.ndarray | None:
        """DFT of each kept period's deviation from its block's mean period.

        Parameters
        ----------
        x : (N, n) array or {"u", "y", "r"}
        block : int
            Block index.

        Returns
        -------
        (n_kept, n_bins, n) complex array, or None when the periods of ``x``
        in that block are identical (an open-loop generator's input).
        """
        name = x if isinstance(x, str) else None
        x, means = self._signal(x)
        if name is not None and self.repeats[name][block]:
            return None
        p = self.periods(x)[block]
        m = _mean_period(p)[0] if means is None else means[block]
        d = p - m
        # periods known to differ cannot all equal their mean: no need to look
        if name is None and not np.any(d):
            return None
        # along the period axis of the (period, channel) layout: as fast as along a contiguous
        # axis after a transposing copy, without the copy (which cost a third of the spread's
        # time); and no overwrite_x: rfft cannot reuse a real buffer for its complex output
        return scipy.fft.rfft(d, axis=1, workers=workers)

    def noise_var(self, x="y", *, workers: int | None = None) -> np.ndarray:
        """Variance of the block-mean DFT from the spread over periods.

        Parameters
        ----------
        x : (N, n) array or {"u", "y", "r"}
            The signal; default the output ``y``.

        Returns
        -------
        (n_b, n_bins, n) array
            ``sum_p |D_p|^2 / (n_kept (n_kept - 1))`` in the DFT's units squared
            (m^2 for ``y``); NaN for a block of one kept period.
        """
        out = self.spread_powers(x, workers=workers)
        n = self.n_kept.astype(float)
        with np.errstate(divide="ignore", invalid="ignore"):
            out /= (n * (n - 1))[:, None, None]
        out[self.n_kept < 2] = np.nan
        return out

    def spread_powers(self, x, *, workers: int | None = None) -> np.ndarray:
        """(n_b, n_bins, n): :meth:`spread_power` of every block, in one pass.

        The FRF's hot path: one deviation buffer and one spectrum buffer serve all
        blocks, since fresh multi-megabyte temporaries cost their page faults on
        every call (on the benchmark's record, 6 blocks x 11 periods x 6 channels,
        8.1 -> 6.9 ms CPU in one A/B run on a loaded 2-core machine, beside
        5.9 ms for the bare FFTs). The values are those of :meth:`spread_power`.
        """
        name = x if isinstance(x, str) else None
        x, means = self._signal(x)
        P, n_ch = self.period, x.shape[1]
        per = x.reshape(-1, P, n_ch)
        out = np.zeros((self.n_blocks, self.n_bins, n_ch))
        n_max = int(self.n_kept.max())
        dev = np.empty((n_max, P, n_ch))
        spec = np.empty((n_max, self.n_bins, n_ch), complex)
        for b, (a, m) in enumerate(zip(self.first.tolist(), self.n_kept.tolist())):
            if m < 2 or (name is not None and self.repeats[name][b]):
                continue  # one period, or identical periods: no spread
            p = per[a : a + m]
            mean = _mean_period(p)[0] if means is None else means[b]
            d = np.subtract(p, mean, out=dev[:m])
            D = _rfft_periods(d, spec[:m], workers)
            # re/im interleaved and flattened: a plain dot per element, no |.|^2 temporary
            v = D.view(np.float64).reshape(m, -1)
            sq = np.einsum("pi,pi->i", v, v)
            out[b] = (sq[0::2] + sq[1::2]).reshape(self.n_bins, n_ch)
        return out

    def spread_power(self, x, block: int, *, workers: int | None = None) -> np.ndarray:
        """(n_bins, n): ``sum_p |D_p|^2`` over the kept periods of one block (0 if identical)."""
        D = self.deviation_spectra(x, block, workers=workers)
        if D is None:
            return np.zeros((self.n_bins, self._signal(x)[0].shape[1]))
        # re/im interleaved and flattened: a plain dot per element, no |.|^2 temporary; then
        # re^2 + im^2 from the even and odd entries (a reduction over a length-2 axis is slow)
        v = D.view(np.float64).reshape(D.shape[0], -1)
        sq = np.einsum("pi,pi->i", v, v)
        return (sq[0::2] + sq[1::2]).reshape(self.n_bins, -1)

    def noise_cov(self, x="y", *, lines: np.ndarray | None = None) -> np.ndarray:
        """Sample covariance of the block-mean DFT across channels, from the period spread.

        Parameters
        ----------
        x : (N, n) array or {"u", "y", "r"}
        lines : (n_l,) int array, optional
            Bins; default :attr:`lines`.

        Returns
        -------
        (n_b, n_l, n, n) complex array
            ``sum_p D_p D_p^H / (n_kept (n_kept - 1))``; NaN for a block of one kept period.
        """
        lines = self.lines if lines is None else np.asarray(lines, int)
        n = self._signal(x)[0].shape[1]
        out = np.full((self.n_blocks, lines.size, n, n), np.nan, complex)
        for b, m in enumerate(self.n_kept.tolist()):
            if m < 2:
                continue
            D = self.deviation_spectra(x, b)
            if D is None:
                out[b] = 0.0
                continue
            D = D[:, lines]
            out[b] = np.einsum("pli,plj->lij", D, D.conj()) / (m * (m - 1))
        return out


def periodic_record(
    data,
    *,
    n_transient: int = 1,
    min_periods: int = 1,
    reference: str = "auto",
    period: int | None = None,
    workers: int | None = None,
) -> PeriodicRecord:
    """Split a periodic record into blocks, drop the transient, and take the mean-period DFTs.

    Parameters
    ----------
    data : TimeData or MultisineExperiment
        Spec 1a record: ``u`` (N, n_u) N, ``y`` (N, n_y) m, optional ``r`` (N, n_u) N,
        blocks found from the reference; or an in-memory experiment, whose
        blocks (realization x experiment) are known.
    n_transient : int
        Periods dropped at the start of every block (>= 0), see the module docstring.
    min_periods : int
        Periods a block keeps at least (>= 1); every block must have that many.
    reference : {"auto", "r", "u"}
        Signal whose blocks and excited lines count: ``"auto"`` is ``r`` when recorded.
    period : int, optional
        Samples per period; default ``data.period``.
    workers : int, optional
        Threads for the FFT (``scipy.fft`` workers).

    Returns
    -------
    PeriodicRecord

    Raises
    ------
    InputError
        Not periodic, not a whole number of periods, fewer than ``min_periods``
        periods in a block, no excitation, or bad arguments.
    """
    from workbench.experiments import MultisineExperiment

    blocks = None
    if isinstance(data, MultisineExperiment):
        n_blk, n_per = data.y.shape[0] * data.y.shape[1], data.y.shape[2]
        blocks = [(b * n_per, n_per) for b in range(n_blk)]

        def flat(a):
            return None if a is None else a.reshape(-1, a.shape[-1])

        fs, P0, u, y, r = data.fs, data.period, flat(data.u), flat(data.y), flat(data.r)
    elif isinstance(data, TimeData):
        fs, P0, u, y, r = data.fs, data.period, data.u, data.y, data.r
    else:
        raise InputError(
            f"data: expected periodic TimeData or a MultisineExperiment, got {type(data).__name__}"
        )
    P = P0 if period is None else period
    if P is None:
        raise InputError(
            "data: key 'period': expected a periodic (multisine) record with 'period' set, got none"
        )
    if int(P) != P or P < 2:
        raise InputError(f"period: expected an integer >= 2 samples, got {P}")
    P = int(P)
    N = u.shape[0]
    if N % P:
        raise InputError(
            f"period: expected a whole number of periods of {P} samples, "
            f"got {N} samples ({N / P:.3g} periods)"
        )
    n_transient, min_periods = int(n_transient), int(min_periods)
    if n_transient < 0:
        raise InputError(f"n_transient: expected an integer >= 0, got {n_transient}")
    if min_periods < 1:
        raise InputError(f"min_periods: expected an integer >= 1, got {min_periods}")
    if reference not in ("auto", "r", "u"):
        raise InputError(f"reference: expected 'auto', 'r' or 'u', got {reference!r}")
    if reference == "r" and r is None:
        raise InputError("reference: 'r' asked for, but the data has no excitation 'r'")
    use_r = r is not None and reference != "u"
    found = split_blocks(r if use_r else u, P) if blocks is None else blocks
    if not found:
        raise InputError(
            "data: expected a periodic excitation, got zero excitation in every period"
        )
    shortest = min(n for _, n in found)
    if shortest < min_periods:
        raise InputError(
            f"data: expected at least {min_periods} period(s) of {P} samples in every "
            f"experiment block, got a block of {shortest} ({N // P} periods in "
            f"{len(found)} block(s))"
        )
    drop = np.array([min(n_transient, n - min_periods) for _, n in found], int)
    first = np.array([a for a, _ in found], int) + drop
    n_kept = np.array([n for _, n in found], int) - drop

    repeats = {}

    def means(x, name):
        if x is None:
            return None
        per = x.reshape(-1, P, x.shape[1])
        out = [_mean_period(per[a : a + n]) for a, n in zip(first, n_kept)]
        repeats[name] = np.array([same for _, same in out])
        repeats[name].setflags(write=False)
        return np.stack([m for m, _ in out])

    u_mean, y_mean, r_mean = means(u, "u"), means(y, "y"), means(r, "r")

    def dft(m):
        return None if m is None else scipy.fft.rfft(m, axis=1, workers=workers)

    U, Y, R = dft(u_mean), dft(y_mean), dft(r_mean)
    X = R if use_r else U
    power = np.einsum("bfc,bfc->bf", X.real, X.real) + np.einsum("bfc,bfc->bf", X.imag, X.imag)
    power[:, 0] = 0.0
    if P % 2 == 0:
        power[:, -1] = 0.0
    peak = power.max(axis=1, keepdims=True)
    excited = (power > EXCITED_REL_POWER * peak) & (peak > 0)
    # a reference that varies from period to period (a measured u) carries noise at every
    # bin: a line must also stand out of its own noise (variance of the mean, from the spread)
    ref_name, ref_sig, ref_mean = ("r", r, r_mean) if use_r else ("u", u, u_mean)
    per = ref_sig.reshape(-1, P, ref_sig.shape[1])
    for b, (a, n) in enumerate(zip(first.tolist(), n_kept.tolist())):
        if repeats[ref_name][b] or n < 2:
            continue
        D = scipy.fft.rfft(per[a : a + n] - ref_mean[b], axis=1, workers=workers)
        var = np.sum(D.real**2 + D.imag**2, axis=(0, 2)) / (n * (n - 1))
        excited[b] &= power[b] > EXCITED_SNR * var
    for a in (first, n_kept, drop, U, Y, R, power, excited, u_mean, y_mean, r_mean):
        if a is not None:
            a.setflags(write=False)
    return PeriodicRecord(
        fs=float(fs),
        period=P,
        first=first,
        n_kept=n_kept,
        n_dropped=drop,
        U=U,
        Y=Y,
        R=R,
        ref_power=power,
        excited=excited,
        u_mean=u_mean,
        y_mean=y_mean,
        r_mean=r_mean,
        repeats=repeats,
        u=_view(u),
        y=_view(y),
        r=None if r is None else _view(r),
    )
