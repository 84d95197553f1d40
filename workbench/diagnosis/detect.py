"""Signatures: the numbers that show an effect in the data, for explanations and tests.

- :func:`phase_slope`: the phase of G_meas / G_model against frequency (a delay
  is a straight line through zero, with flat magnitude);
- :func:`where_it_shows`: the channels and the band where an added effect
  changes the response by more than the noise;
- :func:`nonlinearity`: power of a periodic record on the lines its
  excitation leaves empty, beyond the noise (the part of the output a linear
  model cannot produce);
- :func:`noise_floor`: the spec time-domain error the noise of a periodic
  record leaves, from the spread of its periods;
- :func:`white_residual`: whether a residual is white noise (Ljung-Box), where a
  record without periods gives no floor;
- :func:`frf_structure_share`: how much of an FRF's residual is not noise from line to
  line, where no ``G_var`` gives a floor;
- :func:`residual_floor`: the floor a record without periods gives after all, taking
  its noise as white: the low quantile of a residual's spectrum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage

from workbench.io.formats import TimeData

__all__ = [
    "phase_slope",
    "where_it_shows",
    "nonlinearity",
    "noise_floor",
    "periodic_misfit",
    "white_residual",
    "frf_structure_share",
    "residual_floor",
    "Where",
    "NonlinearityEvidence",
]


def phase_slope(freq: np.ndarray, G_meas: np.ndarray, G_model: np.ndarray, *, weight=None):
    """Least-squares slope of the unwrapped phase error, deg/Hz, and the magnitude error.

    Parameters
    ----------
    freq : (n_f,) array, Hz
    G_meas, G_model : (n_f, n_y, n_u) complex arrays
    weight : (n_f, n_y, n_u) array, optional
        Per-element reliability (e.g. |G| / sigma); channels are pooled with it.

    Returns
    -------
    slope_deg_per_hz : float, fitted through the origin over all lines and channels
    mag_db : float, weighted median of |20 log10 |G_meas / G_model||
    n_channels : int, channels used (with a weight share above 1 %)
    """
    ratio = G_meas / np.where(np.abs(G_model) > 0, G_model, np.inf)
    ok = np.isfinite(ratio) & (np.abs(ratio) > 0)
    w = np.abs(G_model) if weight is None else np.asarray(weight, float)
    w = np.where(ok, w, 0.0)
    ch_w = w.sum(axis=0)
    use = ch_w > 0.01 * ch_w.max() if ch_w.max() > 0 else ch_w > 0
    # pool the channels: the weighted mean of the complex ratio per line, then unwrap
    r = np.where(ok, ratio, 0.0)
    num = np.sum((w * r)[:, use], axis=1)
    phase = np.unwrap(np.angle(num))
    lw = np.sum(w[:, use], axis=1)
    slope = float(np.sum(lw * freq * phase) / max(np.sum(lw * freq**2), 1e-300))
    mag = np.abs(20 * np.log10(np.where(ok, np.abs(ratio), 1.0)))[:, use].ravel()
    mw = w[:, use].ravel()
    order = np.argsort(mag)
    cum = np.cumsum(mw[order])
    mag_db = (
        float(mag[order][np.searchsorted(cum, 0.5 * cum[-1])]) if cum.size and cum[-1] > 0 else 0.0
    )
    return np.degrees(slope), mag_db, int(use.sum())


@dataclass(frozen=True)
class Where:
    """Channels and band where an effect shows (0-based indices, Hz)."""

    inputs: tuple[int, ...]
    outputs: tuple[int, ...]
    band_hz: tuple[float, float]
    significance: np.ndarray  # (n_y, n_u) channel energies in noise units


def where_it_shows(freq: np.ndarray, dG: np.ndarray, sigma: np.ndarray) -> Where:
    """Where the change ``dG`` of the response stands out of the noise ``sigma``.

    Parameters
    ----------
    freq : (n_f,) array, Hz
    dG : (n_f, n_y, n_u) complex array
        Response after minus before adding the effect.
    sigma : (n_f, n_y, n_u) array
        Noise standard deviation of each element (same units as ``dG``).
    """
    S2 = np.abs(dG) ** 2 / np.maximum(sigma, 1e-300) ** 2
    ch = S2.sum(axis=0)
    top = ch.max() if ch.size else 0.0
    show = (ch > max(30.0, 1e-5 * top)) if top > 0 else np.zeros_like(ch, bool)
    if not show.any() and top > 0:
        show = ch >= top
    line = np.sum(np.where(show[None], S2, 0.0), axis=(1, 2))
    n_ch = max(int(show.sum()), 1)
    lt = line > max(4.0 * n_ch, 0.02 * line.max()) if line.max() > 0 else np.zeros_like(line, bool)
    if lt.any():
        band = (float(freq[lt][0]), float(freq[lt][-1]))
    else:
        band = (float(freq[0]), float(freq[-1]))
    outs = tuple(int(i) for i in np.flatnonzero(show.any(axis=1)))
    ins = tuple(int(j) for j in np.flatnonzero(show.any(axis=0)))
    return Where(inputs=ins, outputs=outs, band_hz=band, significance=ch)


@dataclass(frozen=True)
class NonlinearityEvidence:
    """Periodic output power on unexcited lines, beyond the noise.

    Attributes
    ----------
    level : float
        Estimated share of the output power not produced by a linear system.
    f_stat : float
        Periodic power / noise power on the unexcited lines (about 1 if linear).
    n_lines : int
        Unexcited lines used.
    """

    level: float
    f_stat: float
    n_lines: int
    band_hz: tuple[float, float]
    #: unexcited-line power of the last period over the first kept one (a transient decays)
    stationarity: float = 1.0
    #: the evidence is the periods' spread, not the unexcited lines (the response does not
    #: repeat; ``level`` and ``f_stat`` are then the spread's: diagnose's
    #: ``_unrepeated_evidence``)
    unrepeated: bool = False


def nonlinearity(data: TimeData, y_model: np.ndarray | None = None) -> NonlinearityEvidence | None:
    """Test a periodic record for nonlinear distortion (None when it cannot be tested).

    With ``y_model`` (N, n_y), the simulated output of the best linear model, the
    test runs on y - y_model: the transient from rest, common to both, cancels
    (lightly damped low modes may not settle within a period).

    Notes
    -----
    In every experiment block (:mod:`workbench.signals.periodic`) the first period is
    dropped (transient from rest or from the switch), and periods of different
    blocks are never averaged together; the statistics below are pooled over
    blocks. The excited lines are those where the excitation (r, or u in open
    loop) has power in some block. On the other
    lines inside the excited band, a linear time-invariant plant driven by a
    periodic excitation gives no periodic output: the mean over periods there
    holds noise only, with variance sigma^2/P. Power beyond that is
    distortion; its share of the total periodic output power, scaled by the
    share of lines it was measured on, is the reported level (Pintelon &
    Schoukens, System Identification, 2nd ed., ch. 3: detection of
    nonlinear distortions with random-phase multisines).
    """
    rec = _record(data)
    if rec is None:
        return None
    y_all = data.y if y_model is None else data.y - y_model
    lines = rec.lines
    if lines.size < 3:
        return None
    excited = np.zeros(rec.n_bins, bool)
    excited[lines] = True
    lo, hi = lines[0], lines[-1]
    k = np.arange(rec.n_bins)
    # the lowest octave is left out: a transient or drift from rest leaks into it
    unexc = (~excited) & (k >= 2 * lo) & (k <= hi) & (k > 0)
    if unexc.sum() < 10:
        return None
    # per experiment block: mean over its periods and the noise variance of that mean (periods
    # of different experiments are never averaged together); pooled over blocks below
    pw_b, nz_b, p_first, p_last = [], [], 0.0, 0.0
    for yb in rec.periods(y_all):
        Y = np.fft.rfft(_detrend(yb), axis=1)  # (n_per, n_bins, n_y)
        pw_b.append(np.abs(Y.mean(axis=0)) ** 2)
        nz_b.append(Y.var(axis=0, ddof=1) / yb.shape[0])  # variance of the mean
        # distortion is stationary; a transient from rest that has not settled decays
        p_first += np.sum(np.abs(Y[0, unexc]) ** 2)
        p_last += np.sum(np.abs(Y[-1, unexc]) ** 2)
    Ym2, noise = sum(pw_b), sum(nz_b)  # (n_bins, n_y), summed over blocks
    # odd- and even-order distortion fall on odd and even lines: test each parity apart
    # (pooled power over pooled noise variance of the mean, about 1 for a linear plant)
    band = (k >= lo) & (k <= hi)
    p_total = np.sum(np.abs(rec.Y[:, band]) ** 2)
    f_stat = 0.0
    distortion = 0.0
    for parity in (0, 1):
        sel = unexc & (k % 2 == parity)
        if sel.sum() < 5:
            continue
        pw = np.sum(Ym2[sel], axis=1)
        nz = np.maximum(np.sum(noise[sel], axis=1), 1e-300)
        f_stat = max(f_stat, float(pw.sum() / nz.sum()))
        excess = max(pw.sum() - nz.sum(), 0.0)
        distortion += excess * np.sum(band & (k % 2 == parity)) / sel.sum()
    f = rec.freq_hz
    return NonlinearityEvidence(
        level=float(min(distortion / max(p_total, 1e-300), 1.0)),
        f_stat=f_stat,
        n_lines=int(unexc.sum()),
        band_hz=(float(f[lo]), float(f[hi])),
        stationarity=float(p_last / max(p_first, 1e-300)),
    )


def _record(data: TimeData):
    """The periodic record of the detectors: in every block the first period dropped.

    None when ``data`` is not periodic or a block has fewer than 3 periods (2
    must stay for a noise estimate).
    """
    from workbench.core.errors import InputError
    from workbench.signals.periodic import periodic_record

    if not data.period:
        return None
    try:
        rec = periodic_record(data, n_transient=1, min_periods=2)
    except InputError:
        return None
    return rec if np.all(rec.n_dropped == 1) else None


def _detrend(x: np.ndarray) -> np.ndarray:
    """Remove a ramp and offset common to the periods (n_per, P, n): rigid-body drift.

    The slope comes from the difference between the last and the first period,
    which is zero for a periodic signal, so no periodic component is created.
    """
    n_per, P = x.shape[:2]
    if n_per < 2:
        return x
    slope = (x[-1] - x[0]).mean(axis=0) / ((n_per - 1) * P)  # per sample, (n,)
    t = np.arange(n_per * P).reshape(n_per, P)[..., None]
    return x - slope * t


def periodic_misfit(data: TimeData, y_model: np.ndarray) -> float | None:
    """Power of the period-synchronous residual over what the noise explains (about 1 if right).

    Parameters
    ----------
    data : TimeData with ``period`` and at least 3 periods
    y_model : (N, n_y) array, simulated output

    Returns
    -------
    F = ||mean residual period||^2 / (sum of its noise variances), or None when
    the record is not periodic. The first period of every experiment block
    (transient) is dropped; the noise variance of the mean comes from the spread
    over the periods of each block, pooled over blocks.
    """
    rec = _record(data)
    if rec is None:
        return None
    power, var_mean = 0.0, 0.0
    for e in rec.periods(data.y - y_model):
        # offsets and slow drift are not the linear model's concern
        e = e - e.mean(axis=1, keepdims=True)
        power += np.sum(e.mean(axis=0) ** 2)
        var_mean += e.var(axis=0, ddof=1).sum() / e.shape[0]
    return float(power / max(var_mean, 1e-300))


def _deviations(xb: np.ndarray) -> np.ndarray:
    """Each period (n_per, P, n) less its own mean and slope (a drift or an unsettled slow
    transient changes little within a period; 2 of ``P`` degrees of freedom)."""
    P = xb.shape[1]
    t = np.arange(P) - 0.5 * (P - 1)
    d = xb - xb.mean(axis=1, keepdims=True)
    return d - (d * t[None, :, None]).sum(axis=1, keepdims=True) / (t @ t) * t[None, :, None]


def _period_spread(rec, x: np.ndarray) -> float:
    """Power of ``x`` (N, n) about its blocks' mean periods, per sample summed over channels:
    each kept period's :func:`_deviations`, their variance over the periods (ddof 1) at each
    sample, averaged over the samples and blocks."""
    var, n = 0.0, 0
    for xb in rec.periods(x):
        var += float(_deviations(xb).var(axis=0, ddof=1).sum())
        n += xb.shape[1]
    return var / max(n, 1)


def _white_spread(rec, x: np.ndarray) -> float:
    """:func:`_period_spread` with the noise taken as white: each channel's variance from the
    median over frequency of the deviations' power spectrum, summed over the periods.

    White noise spreads evenly over the bins, so the median is its level (a scaled
    chi-square with ``2 (n_per - 1)`` degrees of freedom per bin); what is not periodic and
    not noise - friction's stick-slip, a drift - sits in part of the bins and moves the median
    less than the mean (a casegen beam with slight friction: the spread 1700x its noise, the
    median 40x). The lowest bins (what the mean and slope removal leaves) and the last are
    not used; with fewer than 8 bins left the plain spread is returned.
    """
    import scipy.stats

    var, n = 0.0, 0
    for xb in rec.periods(x):
        m, P = xb.shape[:2]
        d = _deviations(xb)
        S = (np.abs(np.fft.rfft(d - d.mean(axis=0), axis=1)) ** 2).sum(axis=0)[3:-1]
        if S.shape[0] < 8:
            return _period_spread(rec, x)
        # E|D|^2 summed over the periods is (m - 1) P sigma^2: chi2(2 (m - 1)) x P sigma^2 / 2
        s2 = np.median(S, axis=0) * 2.0 / (P * scipy.stats.chi2.median(2 * (m - 1)))
        var += float(s2.sum()) * P
        n += P
    return var / max(n, 1)


def noise_floor(
    data: TimeData, y_model: np.ndarray | None = None, *, white: bool = False
) -> float | None:
    """The spec time-domain error that the record's noise alone leaves, ``||noise|| / ||y||``.

    The output noise is estimated from the spread of the kept periods about their block's
    mean period (:func:`_period_spread`), its variance taken as stationary over the whole
    record (the dropped first periods too). The spread holds the noise plus whatever is
    not periodic: a slow mode's transient that has not settled (a beam on a soft
    suspension: 40x the noise) or a drift. With ``y_model`` (N, n_y), a linear model's
    simulated output, the spread of the residual ``y - y_model`` is taken too (the
    transient common to both cancels; a drift the model adds does not) and the smaller
    of the two is the estimate (each is the noise or more).

    What a model that is right leaves against the record, the steady state and the
    transient from rest alike: a from-rest simulation that misses the record by more while
    its period-synchronous residual is noise (:func:`periodic_misfit` ~ 1) misses a drift
    (a twice-integrated force error).

    ``white``: each spread is also estimated with the noise taken as white
    (:func:`_white_spread`, robust to a non-periodic part in some bins) and the smaller
    taken. An estimate for a decision that is only cheaper when the floor is high (with
    coloured noise it is low).

    Returns
    -------
    float or None
        None when the record is not periodic (:func:`_record`).
    """
    rec = _record(data)
    if rec is None:
        return None
    norm = float(np.linalg.norm(data.y))
    if norm == 0:
        return None
    spreads = [_period_spread] + ([_white_spread] if white else [])
    xs = [data.y] + ([data.y - y_model] if y_model is not None else [])
    var = min(f(rec, x) for f in spreads for x in xs)
    return float(np.sqrt(var * data.y.shape[0]) / norm)


def white_residual(resid: np.ndarray, *, max_lag: int = 20, false_alarm: float = 1e-3) -> bool:
    """Whether every output's residual is white: the Ljung-Box test of its autocorrelation.

    ``resid`` (N, n_y): a record's output residual. Per output, ``Q = N (N + 2) sum_k
    r_k^2 / (N - k)`` over lags 1..``max_lag`` (``r_k`` the normalized autocorrelation) is
    chi2(max_lag) for white noise (G. M. Ljung and G. E. P. Box, Biometrika 65, 1978); white
    when every output's Q stays below the level a white residual passes with probability
    ``1 - false_alarm`` (Bonferroni over the outputs).

    What a record that is not periodic offers in place of a noise floor: a model that
    leaves white output noise (the sensor noise of an output-error fit) leaves nothing a
    dynamic element would explain, while a misfit through the plant's dynamics (a port
    element's distortion beyond its linearization) is coloured. Coloured sensor noise fails
    the test too: the caller must treat False as "unknown", not as "misfit".
    """
    import scipy.stats

    from workbench.validate.compare import xcorr

    e = np.asarray(resid, float)
    N, n_y = e.shape
    L = int(min(max_lag, N // 4))
    if L < 1:
        return False
    r = xcorr(e, e, L)[L + 1 :]  # lags 1..L, (L, n_y, n_y)
    r = r[:, np.arange(n_y), np.arange(n_y)]  # each output's own
    k = np.arange(1, L + 1)[:, None]
    Q = N * (N + 2) * np.sum(r**2 / (N - k), axis=0)
    return bool(np.all(Q < scipy.stats.chi2.isf(false_alarm / n_y, L)))


def frf_structure_share(
    E: np.ndarray, *, false_alarm: float = 1e-3, window: int = 41, min_lines: int = 64
) -> float:
    """An upper bound on the share of an FRF residual's power that is not noise independent
    from line to line: what any further model term could remove.

    ``E`` (n_f, n_y, n_u) complex: the measured minus the modelled FRF on its lines (in
    frequency order), weighted per line or not. Noise averaged per line (a periodic
    excitation's lines; an FRF of averaged spectra without leakage) is independent from line
    to line, zero mean, its variance changing slowly with the line. A model error is smooth
    in amplitude from line to line (a mode's, a delay's, a lag's; its phase may turn), so
    per channel ``S = sum_k conj(e_k) e_k+1`` holds about its power, ``|S| >= c P_s`` (``c``
    near 1), while noise leaves ``|S|^2 / D`` Exp(1)-distributed (``D = sum_k |e_k|^2
    |e_k+1|^2``, whatever its level does). An error confined to a few lines (a mode narrower
    than the spacing) shows instead as lines far above their ``m = window - 1`` neighbours'
    mean (noise: the ratio F(2, 2m), above ``x`` with probability ``(1 + x / m)^-m``). The
    bound: ``(sum_ch |S_ch| + sqrt(sum_ch D_ch ln(1 / false_alarm)) + the lines' excess over
    that level where it passes the Bonferroni F level) / sum |e|^2``; 1 with fewer than
    ``min_lines`` lines.

    What an FRF without ``G_var`` offers in place of a noise floor: a finding must remove a
    large share of the misfit (a third), which the bound rules out when it is small. Noise
    alone leaves about ``0.9 / sqrt(n_f) + 2.6 / sqrt(n_f n_ch)`` (0.06 on 2000 lines of 6
    channels; more where a few lines hold most of its power); leakage (a Welch estimate's
    neighbouring bins) correlates noise and raises it, erring towards searching on.
    """
    e = np.asarray(E, complex)
    n_f = e.shape[0]
    if n_f < max(min_lines, window):
        return 1.0
    e = e.reshape(n_f, -1)
    p = np.abs(e) ** 2
    total = float(p.sum())
    if not total > 0:
        return 0.0
    S = np.abs(np.sum(np.conj(e[:-1]) * e[1:], axis=0))
    D = float(np.sum(p[:-1] * p[1:]))
    m = window - 1  # the neighbours' mean: the window's, the line itself left out
    level = (window * scipy.ndimage.uniform_filter1d(p, window, axis=0, mode="nearest") - p) / m
    x = m * ((p.size / false_alarm) ** (1 / m) - 1)
    spikes = float(np.sum(np.where(p > x * level, p - level, 0.0)))
    return min(1.0, (float(S.sum()) + np.sqrt(D * np.log(1 / false_alarm)) + spikes) / total)


def residual_floor(
    data: TimeData, resid: np.ndarray, *, nperseg: int = 256, q: float = 0.1
) -> float | None:
    """The spec error white output noise would leave, estimated from a residual's spectrum.

    ``resid`` (N, n_y): the record's output residual against a model. Per output, the
    Welch power spectrum (``nperseg`` samples, half overlap, linear detrend) is taken over
    frequency; its ``q`` quantile, divided by the chi-square's (``2 K`` degrees of freedom
    for ``K`` segments, the spread of white noise's bins about their level), is the level
    of white noise, and ``level * fs / 2`` its variance. Returns ``sqrt(sum var * N) /
    ||y||``, comparable with the spec error and with :func:`noise_floor`; None for fewer
    than 4 segments or 8 bins.

    What a record without periods offers in place of their spread: a model's misfit through
    the plant's dynamics (a mode it lacks, the images of modes above Nyquist) sits in part
    of the bins, and a low quantile reads the noise under it (a resonance with 100x the
    noise's power: 1.06x the floor at ``q`` 0.1, 1.5x at the median), so the estimate is
    the noise or a little more. More where the misfit is broadband (a static compliance on
    a broadband input: 1.2x on an indep3 beam record given its nominal model, 5x at the
    median); less for coloured noise (its low bins below the mean). For decisions that are
    only stricter when it is low.
    """
    import scipy.signal
    import scipy.stats

    e = np.asarray(resid, float)
    N = e.shape[0]
    nperseg = int(min(nperseg, N))
    K = 2 * N // nperseg - 1
    norm = float(np.linalg.norm(data.y))
    if K < 4 or norm == 0:
        return None
    _, P = scipy.signal.welch(e, fs=data.fs, nperseg=nperseg, axis=0, detrend="linear")
    P = P[3:-1]  # the lowest bins hold what the detrend leaves, the last is Nyquist's
    if P.shape[0] < 8:
        return None
    level = np.quantile(P, q, axis=0) * (2 * K) / scipy.stats.chi2.ppf(q, 2 * K)
    return float(np.sqrt(np.sum(level * data.fs / 2) * N) / norm)
