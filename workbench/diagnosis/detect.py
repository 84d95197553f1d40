"""Signatures: the numbers that show an effect in the data, for explanations and tests.

- :func:`phase_slope`: the phase of G_meas / G_model against frequency (a delay
  is a straight line through zero, with flat magnitude);
- :func:`where_it_shows`: the channels and the band where an added effect
  changes the response by more than the noise;
- :func:`nonlinearity`: power of a periodic record on the lines its
  excitation leaves empty, beyond the noise (the part of the output a linear
  model cannot produce).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.formats import TimeData

__all__ = ["phase_slope", "where_it_shows", "nonlinearity", "Where", "NonlinearityEvidence"]


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


def nonlinearity(data: TimeData, y_model: np.ndarray | None = None) -> NonlinearityEvidence | None:
    """Test a periodic record for nonlinear distortion (None when it cannot be tested).

    With ``y_model`` (N, n_y), the simulated output of the best linear model, the
    test runs on y - y_model: the transient from rest, common to both, cancels
    (lightly damped low modes may not settle within a period).

    Notes
    -----
    The first period is dropped (transient from rest). The excited lines are
    those where the excitation (r, or u in open loop) has power. On the other
    lines inside the excited band, a linear time-invariant plant driven by a
    periodic excitation gives no periodic output: the mean over periods there
    holds noise only, with variance sigma^2/P. Power beyond that is
    distortion; its share of the total periodic output power, scaled by the
    share of lines it was measured on, is the reported level (Pintelon &
    Schoukens, System Identification, 2nd ed., ch. 3: detection of
    nonlinear distortions with random-phase multisines).
    """
    P = data.period
    N = data.n_samples
    if not P or N // P < 3:
        return None
    n_per = N // P - 1
    y_all = data.y if y_model is None else data.y - y_model
    y = _detrend(y_all[P:].reshape(n_per, P, data.n_y))
    y_tot = np.fft.rfft(data.y[P:].reshape(n_per, P, data.n_y), axis=1).mean(axis=0)
    x = (data.r if data.r is not None else data.u)[P:].reshape(n_per, P, data.n_u)
    Y = np.fft.rfft(y, axis=1)  # (n_per, n_lines, n_y)
    X = np.fft.rfft(x, axis=1)
    Xm = np.abs(X.mean(axis=0)) ** 2
    px = Xm.sum(axis=1)
    excited = px > 1e-8 * px.max()
    lines = np.flatnonzero(excited)
    lines = lines[lines > 0]
    if lines.size < 3:
        return None
    lo, hi = lines[0], lines[-1]
    k = np.arange(Y.shape[1])
    # the lowest octave is left out: a transient or drift from rest leaks into it
    unexc = (~excited) & (k >= 2 * lo) & (k <= hi) & (k > 0)
    if unexc.sum() < 10:
        return None
    Ym = Y.mean(axis=0)
    noise = Y.var(axis=0, ddof=1) / n_per  # variance of the mean, per line and output
    # odd- and even-order distortion fall on odd and even lines: test each parity apart
    # (pooled power over pooled noise variance of the mean, about 1 for a linear plant)
    band = (k >= lo) & (k <= hi)
    p_total = np.sum(np.abs(y_tot[band]) ** 2)
    f_stat = 0.0
    distortion = 0.0
    for parity in (0, 1):
        sel = unexc & (k % 2 == parity)
        if sel.sum() < 5:
            continue
        pw = np.sum(np.abs(Ym[sel]) ** 2, axis=1)
        nz = np.maximum(np.sum(noise[sel], axis=1), 1e-300)
        f_stat = max(f_stat, float(pw.sum() / nz.sum()))
        excess = max(pw.sum() - nz.sum(), 0.0)
        distortion += excess * np.sum(band & (k % 2 == parity)) / sel.sum()
    f = np.fft.rfftfreq(P, 1 / data.fs)
    # distortion is stationary; a transient from rest that has not settled decays over periods
    p_per = np.sum(np.abs(Y[:, unexc]) ** 2, axis=(1, 2))
    return NonlinearityEvidence(
        level=float(min(distortion / max(p_total, 1e-300), 1.0)),
        f_stat=f_stat,
        n_lines=int(unexc.sum()),
        band_hz=(float(f[lo]), float(f[hi])),
        stationarity=float(p_per[-1] / max(p_per[0], 1e-300)),
    )


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
    the record is not periodic. The first period (transient from rest) is
    dropped; the noise variance of the mean comes from the spread over periods.
    """
    P = data.period
    N = data.n_samples
    if not P or N // P < 3:
        return None
    n_per = N // P - 1
    e = (data.y - y_model)[P:].reshape(n_per, P, data.n_y)
    e = e - e.mean(
        axis=1, keepdims=True
    )  # offsets and slow drift are not the linear model's concern
    mean = e.mean(axis=0)
    var_mean = e.var(axis=0, ddof=1).sum() / n_per
    return float(np.sum(mean**2) / max(var_mean, 1e-300))
