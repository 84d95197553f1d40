"""Frequency-response estimation from time data.

Data flow::

    MultisineExperiment (in memory) --.
                                      +--> frf_multisine(...) --> FrfEstimate(frf, lines)
    TimeData with `period` (a file) --'
    TimeData (noise, any loop)      -----> frf_h1(...)        --> FrfEstimate(frf)
    either                          -----> estimate_frf(..., method="auto")

Every estimate uses a reference signal ``x_ref``: the excitation ``r`` when
the data has one (closed loop, or open loop with the excitation recorded),
else the applied input ``u``. Per frequency line, with columns over
independent experiments (multisine blocks) or segments (H1)::

    G = S_yr S_ur^-1 = (Y R^H) (U R^H)^-1

With ``r = u`` this is the least-squares / H1 estimate ``Y U^H (U U^H)^-1``
(``Y U^-1`` for a square design); with ``r`` in a closed loop it is the
indirect, "3-point" estimate through the reference, which stays unbiased when
the noise on ``y`` feeds back into ``u`` (Pintelon & Schoukens, *System
Identification*, 2nd ed., 2012, section 2.7 and chapter 9; Wellstead, 1981).

**Zero-order hold.** The DFT ratio of sampled data is the frequency response
of the ZOH-discretized plant. The estimate is divided by
:func:`workbench.core.lti.zoh_frf` (``zoh="compensate"``, the default, spec 1b) to
return the pseudo continuous-time FRF. This is exact up to aliasing: the
discrete response also holds ``G(j(w + k ws))`` for ``k != 0``; for a plant
rolling off as 1/f^2 (a mass) that is about 1.5 % of ``|G|`` at fs/8 and
about 4 % at fs/4, so near Nyquist the compensated FRF is not the continuous
one. ``zoh="none"`` returns the discrete-time FRF.

**Multisines.** The record of a multisine experiment is a sequence of blocks,
each a number of identical periods of one excitation (one experiment of one
realization); a file concatenates them with ``period`` set. Blocks, dropped
transient periods, period averages and excited lines are those of
:func:`workbench.signals.periodic.periodic_record` (one rule for the whole workbench):
in every block the first ``n_transient`` periods are dropped and the DFT of
the mean period taken; the excited lines are the bins where the reference
carries power (:data:`workbench.signals.periodic.EXCITED_REL_POWER`) unless given.

``G_var`` (per element, ``E|G_hat - G|^2``) comes from the spread over periods
(``variance="noise"``, default): per block, the residual ``e_p = Y_p - G U_p`` of
period p scatters around its mean with the noise alone, and
``G_hat - G = sum_b e_mean_b W_b`` with ``W = R^H (U R^H)^-1``, so
``var G_ij = sum_b var(e_mean_ib) |W_bj|^2``. With ``variance="total"`` and at
least two groups of ``n_u`` consecutive blocks (realizations), ``G_var`` is the
sample variance of the per-realization estimates divided by their number,
which also holds the stochastic nonlinear distortion.

The lines the multisine leaves out (even lines; odd lines of a random-odd
design) show the noise plus nonlinear distortion: :class:`LineAnalysis`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np

from workbench.core import lti
from workbench.core.errors import DataWarning, InputError
from workbench.io.formats import FrfData, TimeData
from workbench.signals.periodic import periodic_record

__all__ = [
    "FrfEstimate",
    "LineAnalysis",
    "estimate_frf",
    "frf_multisine",
    "frf_h1",
]

EXCITED, ODD_FREE, EVEN_FREE = 0, 1, 2
_COND_LIMIT = 1e12  # refuse an input matrix (U R^H) more ill-conditioned than this (rank lost)
_COND_WARN = 1e6  # warn above this: random-phase designs now and then give such lines


@dataclass(frozen=True)
class LineAnalysis:
    """Output spectrum of a multisine experiment at every DFT bin of the excited band.

    Parameters
    ----------
    freq : (n_bins,) array
        Bin frequencies, Hz, from the lowest to the highest excited line.
    category : (n_bins,) int array
        0 excited, 1 odd bin left out (odd distortion + noise), 2 even bin left
        out (even distortion + noise).
    y_power : (n_bins, n_y) array
        Mean over blocks of ``|Y|^2`` of the period-averaged output, as squared
        sine amplitude (m^2).
    noise_var : (n_bins, n_y) array
        Variance of the period-averaged output from the spread over periods
        (m^2), mean over blocks; NaN with a single period per block.
    """

    freq: np.ndarray
    category: np.ndarray
    y_power: np.ndarray
    noise_var: np.ndarray

    def __post_init__(self):
        for name in ("freq", "category", "y_power", "noise_var"):
            a = np.array(getattr(self, name))
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def excess_db(self, category: int) -> np.ndarray:
        """Power at the bins of ``category`` over the noise there, dB, per output, shape (n_y,).

        About 0 dB when those bins hold only noise; a nonlinearity raises the
        left-out odd (category 1) or even (category 2) bins above it. NaN if the
        design has no such bins or no noise estimate.
        """
        sel = self.category == category
        if not np.any(sel):
            return np.full(self.y_power.shape[1], np.nan)
        p = self.y_power[sel].mean(axis=0)
        n = self.noise_var[sel].mean(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            return 10 * np.log10(p / n)


@dataclass(frozen=True)
class FrfEstimate:
    """An estimated FRF with its diagnostics.

    Parameters
    ----------
    frf : FrfData
        The estimate (spec 1b), ZOH compensated unless asked otherwise;
        ``frf.G_var`` is the variance selected by ``variance``.
    method : str
        ``"multisine"`` or ``"h1"``.
    reference : str
        ``"r"`` (indirect, through the excitation) or ``"u"``.
    n_averages : int
        Periods averaged per block (multisine) or segments (H1).
    n_blocks : int
        Independent excitations (multisine blocks; H1: segments).
    G_var_noise : (n_f, n_y, n_u) array or None
        Variance from the spread over periods (multisine) or the residual (H1).
    G_var_total : (n_f, n_y, n_u) array or None
        Variance from the spread over realizations (multisine, >= 2 realizations).
    lines : LineAnalysis or None
        Non-excited-line analysis (multisine only).
    """

    frf: FrfData
    method: str
    reference: str
    n_averages: int
    n_blocks: int
    G_var_noise: np.ndarray | None = None
    G_var_total: np.ndarray | None = None
    lines: LineAnalysis | None = None


# ------------------------------------------------------------------- helpers
def _zoh_divisor(freq: np.ndarray, fs: float, zoh: str) -> np.ndarray:
    if zoh == "compensate":
        return lti.zoh_frf(freq, fs)
    if zoh == "none":
        return np.ones(freq.size, complex)
    raise InputError(f"zoh: expected 'compensate' or 'none', got {zoh!r}")


def _inverse(B: np.ndarray, what: str) -> np.ndarray:
    """Inverse of a stack (n_f, n_u, n_u) of input matrices U R^H; refuses singular ones."""
    # condition of the equilibrated matrix: channels in N and N m differ in scale, not in rank.
    # Rows scaled to unit norm, then columns: Bs = diag(1/r) B diag(1/c), from |B|^2 alone
    A2 = B.real**2 + B.imag**2
    r2 = np.einsum("fij->fi", A2)  # (n_f, n_u), squared row norms
    r2 = np.where(r2 > 0, r2, 1.0)
    c2 = np.einsum("fij,fi->fj", A2, 1.0 / r2)  # squared column norms after the row scaling
    c2 = np.where(c2 > 0, c2, 1.0)
    r, c = np.sqrt(r2), np.sqrt(c2)
    # the scale 1 / (r_i c_j) in A2's buffer: every fresh temporary of this size costs its
    # page faults on every call (a third of this function's time on the benchmark's lines)
    s = np.multiply(r[:, :, None], c[:, None, :], out=A2)
    np.divide(1.0, s, out=s)
    Bs = B * s
    # Frobenius-norm condition ||Bs|| ||Bs^-1||: within a factor n_u of the 2-norm one, and
    # free once the inverse is formed: ||Bs|| = sqrt(n_u), the columns having unit norm (a
    # zero column leaves the matrix singular, and its inverse infinite, anyway)
    Binv_s = None
    with np.errstate(all="ignore"):
        try:
            Binv_s = np.linalg.inv(Bs)
            v = Binv_s.view(np.float64)
            cond = np.sqrt(B.shape[1] * np.einsum("fij,fij->f", v, v))
        except np.linalg.LinAlgError:
            cond = np.linalg.cond(Bs)
    bad = ~np.isfinite(cond) | (cond > _COND_LIMIT)
    if np.any(bad):
        raise InputError(
            f"{what}: the excitation does not separate the {B.shape[1]} inputs at "
            f"{int(bad.sum())} of {B.shape[0]} lines "
            f"(condition number up to {np.nanmax(cond):.3g}); "
            f"expected at least {B.shape[1]} independent experiments (multisine blocks) or "
            "a random excitation on every input"
        )
    poor = cond > _COND_WARN
    if np.any(poor):
        warnings.warn(
            f"{what}: the input matrix is poorly conditioned (condition number > {_COND_WARN:g}) "
            f"at {int(poor.sum())} of {B.shape[0]} lines; their variance is large. An orthogonal "
            "multisine design avoids this",
            DataWarning,
            stacklevel=3,
        )
    if Binv_s is None:
        return np.linalg.inv(B)
    # B = diag(r) Bs diag(c), so B^-1 = diag(1/c) Bs^-1 diag(1/r): no second inverse; the
    # scale 1 / (c_i r_j) is s transposed, and Binv_s is ours to overwrite
    Binv_s *= np.swapaxes(s, 1, 2)
    return Binv_s


def _power_sum(D: np.ndarray) -> np.ndarray:
    """``sum_p |D_p|^2`` over the first axis of a complex array (p, ...), without temporaries."""
    # re/im interleaved and flattened: a plain dot per element; then re^2 + im^2 from the
    # even and odd entries (a reduction over a length-2 axis is slow)
    v = D.view(np.float64).reshape(D.shape[0], -1) if D.flags.c_contiguous else None
    if v is None:
        return np.einsum("p...,p...->...", D.real, D.real) + np.einsum(
            "p...,p...->...", D.imag, D.imag
        )
    sq = np.einsum("pi,pi->i", v, v)
    return (sq[0::2] + sq[1::2]).reshape(D.shape[1:])


# ----------------------------------------------------------------- multisine
def frf_multisine(
    data,
    *,
    n_transient: int = 1,
    lines: np.ndarray | None = None,
    zoh: Literal["compensate", "none"] = "compensate",
    variance: Literal["noise", "total"] = "noise",
    reference: Literal["auto", "r", "u"] = "auto",
    workers: int | None = None,
) -> FrfEstimate:
    """FRF from a periodic multisine experiment.

    Parameters
    ----------
    data : MultisineExperiment or TimeData
        In memory (blocks known) or a record with ``period`` set (blocks found
        from the excitation, module docstring).
    n_transient : int
        Periods dropped at the start of every block.
    lines : (n_lines,) int array, optional
        Excited DFT bins of one period; default: found from the reference.
    zoh : {"compensate", "none"}
        Divide by the zero-order-hold response (spec 1b) or not.
    variance : {"noise", "total"}
        Which variance goes into ``frf.G_var`` (module docstring).
    reference : {"auto", "r", "u"}
        ``"auto"``: ``r`` when recorded, else ``u``.
    workers : int, optional
        Threads for the FFT (``scipy.fft`` workers).

    Returns
    -------
    FrfEstimate
        ``frf.freq`` are the excited lines, Hz.
    """
    from workbench.experiments import MultisineExperiment

    if isinstance(data, MultisineExperiment):
        if lines is None:
            lines = data.design.lines
    elif isinstance(data, TimeData):
        if data.period is None:
            raise InputError(
                "data: key 'period': expected a periodic (multisine) record with 'period' set; "
                "use frf_h1 (method 'h1') for a non-periodic record"
            )
    else:
        raise InputError(
            f"data: expected a MultisineExperiment or TimeData, got {type(data).__name__}"
        )
    rec = periodic_record(data, n_transient=n_transient, reference=reference, workers=workers)
    if np.any(rec.n_dropped < int(n_transient)):
        raise InputError(
            f"n_transient: every block must keep a period after dropping {int(n_transient)}; "
            f"the shortest block has {int(np.min(rec.n_kept + rec.n_dropped))} period(s)"
        )
    fs, period = rec.fs, rec.period
    n_u, n_y = rec.u.shape[1], rec.y.shape[1]
    names = dict(input_names=data.input_names, output_names=data.output_names)
    use_r = rec.R is not None and reference != "u"

    # ---- period-averaged DFTs per block (the record's), as sine amplitudes
    scale = 2.0 / period  # DFT -> sine amplitude
    Ym, Um = rec.Y * scale, rec.U * scale  # (n_b, n_bins, n_y), (n_b, n_bins, n_u)
    Rm = rec.R * scale if use_r else Um
    n_b, n_bins = rec.n_blocks, rec.n_bins
    n_per = rec.n_kept.tolist()

    # ---- excited lines
    if lines is None:
        lines = rec.lines
    lines = np.asarray(lines, int)
    if lines.size == 0 or lines.min() < 1 or lines.max() >= n_bins or np.any(np.diff(lines) <= 0):
        raise InputError(
            f"lines: expected strictly increasing bins in [1, {n_bins - 1}], got {lines!r}"
        )
    if n_b < n_u:
        raise InputError(
            f"data: {n_b} multisine block(s) for {n_u} inputs; expected at least {n_u} "
            "experiments with independent excitation (a single multisine applied to all "
            "inputs at once does not separate them): use method 'h1' on random data or "
            "record n_u experiments"
        )

    # ---- G = (Y R^H)(U R^H)^-1 per excited line
    # a band of consecutive lines (a full multisine) is a slice: views, not gathered copies
    sel = slice(lines[0], lines[-1] + 1) if lines[-1] - lines[0] + 1 == lines.size else lines
    Yl = np.moveaxis(Ym[:, sel], 0, -1)  # (n_l, n_y, n_b)
    Ul = np.moveaxis(Um[:, sel], 0, -1)  # (n_l, n_u, n_b)
    RlH = np.conj(np.moveaxis(Rm[:, sel], 0, 1))  # (n_l, n_b, n_u)
    W = RlH @ _inverse(Ul @ RlH, "data")  # R^H (U R^H)^-1, (n_l, n_b, n_u)
    G = Yl @ W  # (n_l, n_y, n_u)

    # ---- variance from the spread over periods
    have_periods = min(n_per) >= 2
    noise_bins = np.full((n_bins, n_y), np.nan)
    if have_periods:
        # variance of the mean of the periods, per block
        norm = scale**2 / (rec.n_kept * (rec.n_kept - 1.0))  # (n_b,)
        u_repeats = rec.repeats["u"]
        if np.all(u_repeats):
            # the output's spread over periods, every block (one pass, buffers shared)
            sq_y = rec.spread_powers("y", workers=workers)  # (n_b, n_bins, n_y)
        else:
            sq_y = np.zeros((n_b, n_bins, n_y))
        # where the input repeats exactly (open-loop generator), the residual e_p of each
        # period around the block mean is the output's deviation
        var_e = np.empty((n_b, lines.size, n_y))
        GT = np.swapaxes(G, 1, 2)  # (n_l, n_u, n_y)
        for i in range(n_b):
            if u_repeats[i]:
                if not np.all(u_repeats):
                    sq_y[i] = rec.spread_power("y", i, workers=workers)
                var_e[i] = sq_y[i, sel] * norm[i]
                continue
            dU = rec.deviation_spectra("u", i, workers=workers)[:, sel]  # (P, n_l, n_u)
            # residual of each period around its block mean, e_p = dY_p - G dU_p
            GdU = np.swapaxes(np.swapaxes(dU, 0, 1) @ GT, 0, 1)  # (P, n_l, n_y)
            e = np.empty(GdU.shape, complex)  # C order: _power_sum's fast path
            dY = rec.deviation_spectra("y", i, workers=workers)  # (P, n_bins, n_y) or None
            if dY is None:  # a noise-free output
                np.negative(GdU, out=e)
            else:
                sq_y[i] = _power_sum(dY)
                np.subtract(dY[:, sel], GdU, out=e)
            var_e[i] = _power_sum(e) * norm[i]
        noise_bins = np.einsum("bfy,b->fy", sq_y, norm) / n_b
        # (n_l, n_y, n_b) @ (n_l, n_b, n_u)
        G_var_noise = np.moveaxis(var_e, 0, -1) @ (W.real**2 + W.imag**2)
    else:
        G_var_noise = None

    # ---- variance from the spread over realizations (groups of n_u blocks)
    G_var_total = None
    n_groups = n_b // n_u if n_b % n_u == 0 else 0
    if n_groups >= 2:
        Yg = Yl.reshape(lines.size, n_y, n_groups, n_u)
        Ug = Ul.reshape(lines.size, n_u, n_groups, n_u)
        Rg = np.conj(RlH).reshape(lines.size, n_groups, n_u, n_u)  # (l, g, b, u): R^T per group
        Gg = np.empty((n_groups, lines.size, n_y, n_u), complex)
        for g in range(n_groups):
            RH = np.conj(Rg[:, g])  # (l, b, u)
            Gg[g] = Yg[:, :, g] @ RH @ _inverse(Ug[:, :, g] @ RH, "data")
        G_var_total = np.sum(np.abs(Gg - Gg.mean(axis=0)) ** 2, axis=0) / (
            n_groups * (n_groups - 1)
        )

    if variance == "noise":
        G_var = G_var_noise
    elif variance == "total":
        if G_var_total is None:
            raise InputError(
                f"variance: 'total' needs at least 2 realizations of {n_u} blocks, got {n_b} blocks"
            )
        G_var = G_var_total
    else:
        raise InputError(f"variance: expected 'noise' or 'total', got {variance!r}")
    if G_var is None:
        warnings.warn(
            "one period per block after dropping the transient: no variance estimate; "
            "record more periods",
            DataWarning,
            stacklevel=2,
        )

    freq = lines * fs / period
    z = _zoh_divisor(freq, fs, zoh)
    G = G / z[:, None, None]
    zz = np.abs(z)[:, None, None] ** 2
    if G_var is not None:
        G_var = G_var / zz
    G_var_noise = None if G_var_noise is None else G_var_noise / zz
    G_var_total = None if G_var_total is None else G_var_total / zz

    # ---- non-excited lines
    band = np.arange(lines.min(), lines.max() + 1)
    Yb = Ym[:, band[0] : band[-1] + 1]  # a view
    category = np.where(band % 2 == 1, ODD_FREE, EVEN_FREE)
    category[np.isin(band, lines)] = EXCITED
    analysis = LineAnalysis(
        freq=band * fs / period,
        category=category,
        y_power=np.mean(Yb.real**2 + Yb.imag**2, axis=0),
        noise_var=noise_bins[band],
    )
    return FrfEstimate(
        frf=FrfData(freq=freq, G=G, G_var=G_var, fs=fs, **names),
        method="multisine",
        reference="r" if use_r else "u",
        n_averages=min(n_per),
        n_blocks=n_b,
        G_var_noise=G_var_noise,
        G_var_total=G_var_total,
        lines=analysis,
    )


# ------------------------------------------------------------------------ H1
def frf_h1(
    data: TimeData,
    *,
    nperseg: int | None = None,
    overlap: float = 0.5,
    window: str = "hann",
    zoh: Literal["compensate", "none"] = "compensate",
    reference: Literal["auto", "r", "u"] = "auto",
    workers: int | None = None,
) -> FrfEstimate:
    """Welch-averaged H1 estimate ``S_yx S_ux^-1`` (x = r or u) for random excitation.

    Parameters
    ----------
    data : TimeData
        Open- or closed-loop record.
    nperseg : int, optional
        Segment length, samples; default the largest power of two that gives
        at least ``max(16, 4 n_u)`` averages at the given overlap.
    overlap : float
        Segment overlap as a share of ``nperseg``, in [0, 1).
    window : str
        A ``scipy.signal.get_window`` name (periodic form, as ``scipy.signal.csd``).
    zoh : {"compensate", "none"}
    reference : {"auto", "r", "u"}
        ``"auto"``: ``r`` when recorded (the closed-loop indirect estimate),
        else ``u``; ``"u"`` on closed-loop data gives the classical, biased H1.
    workers : int, optional
        Threads for the FFT.

    Returns
    -------
    FrfEstimate
        ``frf.freq`` are the bins ``k fs / nperseg``, 1 <= k < nperseg / 2.

    Notes
    -----
    Each segment has its mean removed and is windowed. ``G_var`` uses the
    residual ``V_s = Y_s - G U_s`` of every segment: ``sigma_i^2 = sum_s
    |V_si|^2 / (n_seg - n_u)`` and ``var G_ij = sigma_i^2 sum_s |W_sj|^2``
    with ``W = R^H (U R^H)^-1``; the correlation between overlapping segments
    (1/6 for a Hann window at 50 %) is neglected in it. Leakage biases lightly
    damped resonances by about (resolution / half-power bandwidth)^2.
    """
    import scipy.signal

    if not isinstance(data, TimeData):
        raise InputError(f"data: expected TimeData, got {type(data).__name__}")
    if not 0 <= overlap < 1:
        raise InputError(f"overlap: expected a share in [0, 1), got {overlap}")
    if reference not in ("auto", "r", "u"):
        raise InputError(f"reference: expected 'auto', 'r' or 'u', got {reference!r}")
    if reference == "r" and data.r is None:
        raise InputError("reference: 'r' asked for, but the data has no excitation 'r'")
    use_r = data.r is not None and reference != "u"
    N, n_u = data.n_samples, data.n_u
    if nperseg is None:
        n_avg = max(16, 4 * n_u)
        nperseg = 2 ** int(np.floor(np.log2(N / (1 + (n_avg - 1) * (1 - overlap)))))
    nperseg = int(nperseg)
    if not 8 <= nperseg <= N:
        raise InputError(f"nperseg: expected 8 <= nperseg <= N = {N}, got {nperseg}")
    step = max(1, int(round(nperseg * (1 - overlap))))
    n_seg = 1 + (N - nperseg) // step
    if n_seg <= n_u:
        raise InputError(
            f"nperseg: {n_seg} segments for {n_u} inputs; expected more segments than inputs "
            "(shorten nperseg)"
        )
    win = scipy.signal.get_window(window, nperseg)

    def spectra(x):
        seg = np.lib.stride_tricks.sliding_window_view(x, nperseg, axis=0)[::step]  # (s, ch, n)
        seg = seg - seg.mean(axis=-1, keepdims=True)
        X = scipy.fft.rfft(seg * win, axis=-1, workers=workers)[..., 1 : (nperseg + 1) // 2]
        return np.moveaxis(X, -1, 0)  # (n_f, s, ch)

    Yf = spectra(data.y)
    Uf = spectra(data.u)
    Rf = spectra(data.r) if use_r else Uf
    RH = np.conj(Rf)  # (n_f, s, n_u)
    B = np.swapaxes(Uf, 1, 2) @ RH  # (n_f, n_u, n_u) = sum_s U R^H
    W = RH @ _inverse(B, "data")  # (n_f, s, n_u)
    G = np.swapaxes(Yf, 1, 2) @ W  # (n_f, n_y, n_u) = S_yr S_ur^-1
    V = Yf - Uf @ np.swapaxes(G, 1, 2)  # (n_f, s, n_y)
    sigma2 = np.sum(np.abs(V) ** 2, axis=1) / (n_seg - n_u)  # (n_f, n_y)
    G_var = sigma2[:, :, None] * np.sum(np.abs(W) ** 2, axis=1)[:, None, :]

    freq = np.arange(1, (nperseg + 1) // 2) * data.fs / nperseg
    z = _zoh_divisor(freq, data.fs, zoh)
    G = G / z[:, None, None]
    G_var = G_var / np.abs(z)[:, None, None] ** 2
    return FrfEstimate(
        frf=FrfData(
            freq=freq,
            G=G,
            G_var=G_var,
            fs=data.fs,
            input_names=data.input_names,
            output_names=data.output_names,
        ),
        method="h1",
        reference="r" if use_r else "u",
        n_averages=n_seg,
        n_blocks=n_seg,
        G_var_noise=G_var,
    )


def estimate_frf(
    data,
    *,
    method: Literal["auto", "multisine", "h1"] = "auto",
    zoh: Literal["compensate", "none"] = "compensate",
    reference: Literal["auto", "r", "u"] = "auto",
    n_transient: int = 1,
    nperseg: int | None = None,
    overlap: float = 0.5,
) -> FrfEstimate:
    """One entry point: ``"auto"`` picks the multisine estimator for periodic data, else H1."""
    from workbench.experiments import MultisineExperiment

    if method == "auto":
        periodic = isinstance(data, MultisineExperiment) or (
            isinstance(data, TimeData) and data.period is not None
        )
        method = "multisine" if periodic else "h1"
    if method == "multisine":
        return frf_multisine(data, n_transient=n_transient, zoh=zoh, reference=reference)
    if method == "h1":
        if isinstance(data, MultisineExperiment):
            data = data.to_time_data()
        return frf_h1(data, nperseg=nperseg, overlap=overlap, zoh=zoh, reference=reference)
    raise InputError(f"method: expected 'auto', 'multisine' or 'h1', got {method!r}")
