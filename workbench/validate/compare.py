"""Compare a model with a measurement: where does it fit within noise, where does it fail?

:func:`compare` takes a python-control ``StateSpace`` and a
:class:`~workbench.io.formats.FrfData` or :class:`~workbench.io.formats.TimeData`
and returns a frozen :class:`Comparison`:

- the spec's one error figure (``workbench.core.lti.relative_error_frf`` /
  ``relative_error_time``) and per-channel errors;
- a noise-normalized error per frequency line and channel, ``z``, and the
  bands where the model fails (contiguous runs of lines, per channel, where
  a smoothed ``z`` exceeds a threshold chosen from the noise law);
- time data: simulation errors from rest (the spec measure) and from the
  initial state estimated by least squares (``error_estimated_start``; a
  record need not start at rest), one-step-ahead prediction errors, and, from
  the estimated-start residual, the residual spectra, the residual/input
  cross-correlation with 99 % bounds and the failing bands.

Data flow::

    model --lti.frf / sim.simulate_zoh--> G_model / y_model
    data  ----------------------------->  G_meas, G_var / y, u, r
                  |
                  v
       z per line & channel --running median--> bands above threshold
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal
import scipy.special
import scipy.stats

from workbench import sim
from workbench.core import lti
from workbench.core.arrays import readonly
from workbench.io.formats import FrfData, TimeData, check_model_matches
from workbench.signals.quality import runs

__all__ = ["Band", "Comparison", "FrfDetail", "TimeDetail", "compare", "band_threshold", "xcorr"]


def _ro(a) -> np.ndarray | None:
    return None if a is None else readonly(a)


# ---------------------------------------------------------------- results
@dataclass(frozen=True)
class Band:
    """A band of contiguous lines where the model fails on one channel.

    ``input`` is None for time data (the residual of an output has no input
    index). ``peak`` is the largest smoothed statistic in the band, ``median``
    the median of the unsmoothed statistic over its lines.
    """

    output: int
    input: int | None
    f_lo_hz: float
    f_hi_hz: float
    n_lines: int
    peak: float
    median: float

    def as_dict(self) -> dict:
        return {
            "output": self.output,
            "input": self.input,
            "band_hz": [self.f_lo_hz, self.f_hi_hz],
            "n_lines": self.n_lines,
            "peak": self.peak,
            "median": self.median,
        }


@dataclass(frozen=True)
class FrfDetail:
    """FRF comparison detail. Shapes: ``freq_hz`` (n_f,), the rest (n_f, n_y, n_u)."""

    freq_hz: np.ndarray
    G_meas: np.ndarray
    G_model: np.ndarray
    G_var: np.ndarray | None
    z: np.ndarray | None  # |G_meas - G_model|^2 / G_var, or None without G_var

    def __post_init__(self):
        for name in ("freq_hz", "G_meas", "G_model", "G_var", "z"):
            object.__setattr__(self, name, _ro(getattr(self, name)))


@dataclass(frozen=True)
class TimeDetail:
    """Time comparison detail.

    Attributes
    ----------
    fs : float
        Sampling frequency, Hz.
    y, y_model, y_pred : (N, n_y) arrays
        Measured output, the model's ZOH simulation from rest, and its
        one-step-ahead Kalman prediction (m).
    y_model_x0 : (N, n_y) array or None
        The ZOH simulation from the initial state estimated by least squares
        (None when it could not be estimated; see ``x0_note``).
    sim_error, pred_error : (n_y,) arrays
        ||y_i - yhat_i|| / ||y_i|| per output, simulation from rest and prediction.
    sim_error_x0 : (n_y,) array or None
        The same for the simulation from the estimated initial state.
    residual_from : {"estimated start", "rest"}
        Which simulation the residual spectra, cross-correlation and bands use:
        the estimated start when it is available.
    psd_freq_hz : (n_w,) array
    psd_residual, psd_output : (n_w, n_y) arrays
        Welch PSDs of the simulation residual and of y (m^2/Hz).
    xcorr_lags : (2L+1,) int array
        Lags tau in samples; xcorr[k] correlates e(t) with x(t - tau).
    xcorr : (2L+1, n_y, n_u) array
        Normalized cross-correlation of the residual with ``xcorr_against``.
    xcorr_bound : float
        99 % bound 2.58 / sqrt(N) (MATLAB ``resid`` style).
    xcorr_exceeds : (n_y, n_u) bool array
        Some lag of the pair is outside the bound. The bound is per lag: a
        right model has about 1 % of lags outside, so over 2L+1 lags a pair
        exceeds by chance fairly often; ``xcorr_outside`` is the better summary.
    xcorr_outside : float
        Fraction of (lag, output, input) outside the bound: ~0.01 for a right
        model with white residual or white excitation.
    xcorr_against : {"r", "u"}
        The excitation used: ``r`` when present (in a closed loop ``u`` is
        correlated with the noise, ``r`` is not), else ``u``.
    """

    fs: float
    y: np.ndarray
    y_model: np.ndarray
    y_pred: np.ndarray
    sim_error: np.ndarray
    pred_error: np.ndarray
    psd_freq_hz: np.ndarray
    psd_residual: np.ndarray
    psd_output: np.ndarray
    xcorr_lags: np.ndarray
    xcorr: np.ndarray
    xcorr_bound: float
    xcorr_exceeds: np.ndarray
    xcorr_outside: float
    xcorr_against: str
    y_model_x0: np.ndarray | None = None
    sim_error_x0: np.ndarray | None = None
    residual_from: str = "rest"
    x0_note: str = ""

    def __post_init__(self):
        for name in (
            "y",
            "y_model",
            "y_model_x0",
            "sim_error_x0",
            "y_pred",
            "sim_error",
            "pred_error",
            "psd_freq_hz",
            "psd_residual",
            "psd_output",
            "xcorr_lags",
            "xcorr",
            "xcorr_exceeds",
        ):
            object.__setattr__(self, name, _ro(getattr(self, name)))


@dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare`.

    Attributes
    ----------
    kind : {"frf", "time"}
    error : float
        The spec's relative error (shared/spec/data-format.md, section 3); for
        time data the simulation from rest.
    error_estimated_start : float or None
        Time data: the same measure with the initial state estimated by least
        squares (None for FRF data or when it could not be estimated).
    error_per_channel : array
        FRF: (n_y, n_u), mean over lines of |G_meas,ij - G_model,ij| /
        ||G_meas||_F (the element's share of the spec measure). Time: (n_y,),
        ||y_i - y_model,i|| / ||y_i||.
    map_freq_hz : (n_m,) array
    error_map : (n_m, n_y, n_u) or (n_m, n_y) array
        The smoothed per-line statistic the bands are chosen from (see
        ``map_label``); NaN-free.
    map_label : str
    criterion : str
        How the failing bands were chosen, in words, with the threshold.
    threshold : float
    failing_bands : tuple of Band
    z_mean : float or None
        Mean of the noise-normalized error z over all lines and channels
        (about ``z_expected`` for a model that is right within noise), None when
        the data carry no noise information.
    z_mean_per_channel : array or None
        FRF (n_y, n_u), time (n_y,).
    z_expected : float or None
        The mean of z for a right model: 1 for an FRF with G_var (Exp(1)),
        d / (d - 2) for a periodic record's F(2, d) (2 for three kept periods).
    error_noise_floor : float or None
        Periodic time data: the error the record's noise alone leaves over the whole
        record, its variance from the period-to-period spread
        (:func:`workbench.diagnosis.detect.noise_floor`); None otherwise. The bands test
        the steady state's excited lines only; ``whole_record_ratio`` (the residual's error
        over this floor, ``as_dict``) also sees a misfit between the lines and in the
        first, dropped period (a lightly damped mode between the lines rings there).
    notes : tuple of str
        What was assumed or could not be done.
    """

    kind: str
    error: float
    error_per_channel: np.ndarray
    map_freq_hz: np.ndarray
    error_map: np.ndarray
    map_label: str
    criterion: str
    threshold: float
    failing_bands: tuple[Band, ...]
    z_mean: float | None
    z_mean_per_channel: np.ndarray | None
    delay_s: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    notes: tuple[str, ...] = ()
    error_estimated_start: float | None = None
    z_expected: float | None = None
    error_noise_floor: float | None = None
    frf: FrfDetail | None = field(default=None, repr=False)
    time: TimeDetail | None = field(default=None, repr=False)

    def __post_init__(self):
        for name in ("error_per_channel", "map_freq_hz", "error_map", "z_mean_per_channel"):
            object.__setattr__(self, name, _ro(getattr(self, name)))

    @property
    def within_noise(self) -> bool:
        """True when no band fails (meaningful only with a noise reference)."""
        return not self.failing_bands

    @property
    def whole_record_ratio(self) -> float | None:
        """Periodic time data: the error of the residual the bands are read from (from the
        estimated start where there is one, else from rest) over ``error_noise_floor``;
        about 1 for a right model, the whole record's transient and every line included."""
        if self.error_noise_floor is None or self.time is None or self.error_noise_floor <= 0:
            return None
        t = self.time
        y_model = t.y_model_x0 if t.residual_from == "estimated start" else t.y_model
        return lti.relative_error_time(t.y, y_model) / self.error_noise_floor

    def as_dict(self) -> dict:
        """A JSON-ready summary (no per-line arrays)."""
        out = {
            "kind": self.kind,
            "error": self.error,
            "error_measure": (
                "mean over lines of ||G_meas - G_model||_F / ||G_meas||_F"
                if self.kind == "frf"
                else "||Y - Y_model||_F / ||Y||_F, ZOH simulation from rest"
            ),
            "error_estimated_start": self.error_estimated_start,
            "delay_s": self.delay_s,
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "error_per_channel": self.error_per_channel.tolist(),
            "z_mean": self.z_mean,
            "z_mean_per_channel": None
            if self.z_mean_per_channel is None
            else self.z_mean_per_channel.tolist(),
            "z_expected": self.z_expected,
            "error_noise_floor": self.error_noise_floor,
            "whole_record_ratio": self.whole_record_ratio,
            "criterion": self.criterion,
            "threshold": self.threshold,
            "within_noise": self.within_noise,
            "failing_bands": [b.as_dict() for b in self.failing_bands],
            "notes": list(self.notes),
        }
        if self.time is not None:
            t = self.time
            out["error_from_rest"] = self.error
            out["simulation_error_per_output"] = t.sim_error.tolist()
            out["simulation_error_estimated_start_per_output"] = (
                None if t.sim_error_x0 is None else t.sim_error_x0.tolist()
            )
            out["residual_from"] = t.residual_from
            out["prediction_error_per_output"] = t.pred_error.tolist()
            out["xcorr_against"] = t.xcorr_against
            out["xcorr_bound"] = t.xcorr_bound
            out["xcorr_max_abs"] = np.abs(t.xcorr).max(axis=0).tolist()
            out["xcorr_exceeds"] = t.xcorr_exceeds.tolist()
            out["xcorr_outside_fraction"] = t.xcorr_outside
        return out


# -------------------------------------------------------------- statistics
def band_threshold(window: int, false_alarm: float, n_windows: int, sf_inverse) -> float:
    """Threshold on the running median of ``window`` i.i.d. lines.

    The median of ``window`` (odd) values exceeds T when at least
    h = window // 2 + 1 of them do; with q = P(z > T) that is the binomial tail
    P(Binom(window, q) >= h). The per-window probability is
    ``false_alarm / n_windows`` (Bonferroni over the windows tested), q is solved
    from it and T = sf_inverse(q).

    Parameters
    ----------
    window : int
        Lines per running median (odd).
    false_alarm : float
        Probability that a model which is right within noise shows any band.
    n_windows : int
        Number of windows tested: the callers count every position of the running
        median on every channel (lines x channels). The windows overlap, so this
        is a bound; counting only disjoint windows (lines x channels / window)
        under-counts them: on right models (Monte Carlo, 400 draws each of 120-461
        lines x 4-15 channels) any band showed up 0-1.25 % of the time for a nominal
        0.1 %, and 0-0.25 % with every position counted.
    sf_inverse : callable
        Inverse survival function of the per-line statistic under the noise law.
    """
    h = window // 2 + 1
    p = min(0.5, false_alarm / max(1, n_windows))
    q = scipy.optimize.brentq(
        lambda q: scipy.stats.binom.sf(h - 1, window, q) - p, 1e-300, 1 - 1e-12, xtol=1e-300
    )
    return float(sf_inverse(q))


#: degrees of freedom above which variance estimates count as exact (z ~ Exp(1)): F(2, 400)
#: and Exp(1) differ by 2 % at the thresholds used
EXACT_VARIANCE_DOF = 400.0


def variance_dof(var: np.ndarray) -> float | None:
    """Degrees of freedom of variance estimates, from their scatter between neighbouring lines.

    ``var`` (n_f, ...) holds estimated variances along axis 0 (frequency lines). An
    estimate from n averages of complex data is the true variance times chi2(d) / d,
    d = 2 (n - 1), independently from line to line, while the true variance varies
    smoothly with frequency. The second difference of ``log var`` along the lines
    removes the smooth part and leaves the estimates' scatter: Var(log chi2(d) / d) =
    psi'(d / 2) (trigamma), so the second difference has variance 6 psi'(d / 2), and its
    median absolute value (robust to the few lines where the true variance bends
    sharply, at a resonance) is 0.6745 sqrt(6 psi'(d / 2)) to the normal approximation.
    Monte Carlo (400 lines x 6 channels, 50 draws): d = 2, 6, 10, 38, 100 estimated as
    2.27, 6.3, 10.4, 38.5, 99 (median).

    Returns d, or None when the estimates scatter no more than d =
    :data:`EXACT_VARIANCE_DOF` (an exact, smooth variance) or there are too few lines
    (fewer than 20 second differences) to tell.
    """
    v = np.asarray(var, float)
    if v.shape[0] < 3:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        lv = np.where(v > 0, np.log(np.where(v > 0, v, 1.0)), np.nan)
    d2 = (lv[:-2] - 2 * lv[1:-1] + lv[2:]).ravel()
    d2 = d2[np.isfinite(d2)]
    if d2.size < 20:
        return None
    psi1 = (np.median(np.abs(d2)) / 0.6744897501960817) ** 2 / 6
    half = EXACT_VARIANCE_DOF / 2
    if psi1 <= scipy.special.polygamma(1, half):
        return None
    lo = 1e-3
    if psi1 >= scipy.special.polygamma(1, lo):
        return 2 * lo
    return 2 * scipy.optimize.brentq(lambda x: scipy.special.polygamma(1, x) - psi1, lo, half)


def right_model_z_mean(dof: float | None) -> float | None:
    """The mean of z for a right model: 1 under Exp(1) (``dof`` None, an exact G_var), d / (d -
    2) under F(2, d); None where that mean is not finite (d <= 2.5: G_var from about two
    averages)."""
    if dof is None:
        return 1.0
    return dof / (dof - 2) if dof > 2.5 else None


def _running_median(x: np.ndarray, window: int) -> np.ndarray:
    """Median over ``window`` lines along axis 0; every window lies inside the data
    (near the ends the window is shifted, not padded)."""
    n = x.shape[0]
    if n <= window:
        return np.broadcast_to(np.median(x, axis=0), x.shape).copy()
    med = np.median(np.lib.stride_tricks.sliding_window_view(x, window, axis=0), axis=-1)
    idx = np.clip(np.arange(n) - window // 2, 0, n - window)
    return med[idx]


def _bands(
    stat: np.ndarray, raw: np.ndarray, freq: np.ndarray, threshold: float, gap: int
) -> list[Band]:
    """Per channel: runs of lines where ``stat`` > threshold, merged over ``gap`` lines."""
    out = []
    flat_stat = stat.reshape(stat.shape[0], -1)
    flat_raw = raw.reshape(raw.shape[0], -1)
    chans = list(np.ndindex(*stat.shape[1:]))
    above = flat_stat > threshold
    for c in np.flatnonzero(above.any(axis=0)):
        idx = chans[c]
        for s, e in runs(above[:, c], gap=gap):
            out.append(
                Band(
                    output=int(idx[0]),
                    input=int(idx[1]) if len(idx) > 1 else None,
                    f_lo_hz=float(freq[s]),
                    f_hi_hz=float(freq[e - 1]),
                    n_lines=int(e - s),
                    peak=float(flat_stat[s:e, c].max()),
                    median=float(np.median(flat_raw[s:e, c])),
                )
            )
    return out


# ------------------------------------------------------------------- FRF
def _model_frf(model, freq: np.ndarray, delay_s: float, notes: list[str]) -> np.ndarray:
    _, _, _, _, dt = lti.as_matrices(model)
    G = lti.frf(model, freq, delay_s=delay_s)
    if dt > 0:
        # a discrete model carries the ZOH; the spec's FRF has it compensated
        G = G / lti.zoh_frf(freq, 1.0 / dt)[:, None, None]
        notes.append(
            f"discrete model (dt = {dt:g} s): its response is divided by the ZOH factor to "
            "compare with the ZOH-compensated FRF"
        )
    return G


def _compare_frf(model, data: FrfData, *, delay_s, window, false_alarm, gap, rel_threshold):
    notes: list[str] = []
    Gm = _model_frf(model, data.freq, delay_s, notes)
    dG = data.G - Gm
    err = lti.relative_error_frf(data.G, Gm)
    line_norm = np.linalg.norm(data.G, axis=(1, 2))
    line_norm = np.where(line_norm > 0, line_norm, np.inf)
    per_channel = np.mean(np.abs(dG) / line_norm[:, None, None], axis=0)
    w = min(window, data.n_f) | 1
    if data.G_var is not None and np.any(data.G_var > 0):
        var = data.G_var
        floor = np.min(var[var > 0])
        if np.any(var <= 0):
            notes.append(f"G_var = 0 on some lines: floored at {floor:g} (the smallest variance)")
        z = np.abs(dG) ** 2 / np.maximum(var, floor)
        stat = _running_median(z, w)
        n_windows = z.size  # every position of the running median, every channel
        # G_var estimated from a few averages scatters (chi2): z is then F(2, d), whose tail
        # is far heavier than Exp(1)'s (6 averages: a right model showed a band in 19-27 %
        # of Monte Carlo draws against the Exp(1) threshold)
        dof = variance_dof(var)
        z_expected = right_model_z_mean(dof)
        if dof is None:
            law = "Exp(1) (G_var as smooth as an exact variance)"
            thr = band_threshold(w, false_alarm, n_windows, lambda q: -np.log(q))
        else:
            law = (
                f"F(2, {dof:.3g}), the degrees of freedom of G_var estimated from its scatter "
                f"between neighbouring lines (about {dof / 2 + 1:.3g} averages)"
            )
            thr = band_threshold(w, false_alarm, n_windows, lambda q: scipy.stats.f.isf(q, 2, dof))
            notes.append(
                f"G_var scatters as an estimate from about {dof / 2 + 1:.3g} averages: "
                f"z ~ F(2, {dof:.3g})"
                + (f", mean {z_expected:.3g} for a right model" if z_expected else "")
            )
        criterion = (
            f"z = |G_meas - G_model|^2 / G_var per line and element, ~ {law} "
            f"for a right model; band where the running median over {w} lines exceeds "
            f"{thr:.3g}, the threshold at which a right model shows any band with "
            f"probability {false_alarm:g} (binomial tail of the median, Bonferroni over "
            f"{n_windows} windows); runs merged over gaps of {gap} lines"
        )
        z_mean = float(z.mean())
        z_mean_pc = z.mean(axis=0)
        raw, label = z, f"running median of z over {w} lines"
    else:
        z = None
        mag = np.abs(data.G)
        rel = np.abs(dG) / np.where(mag > 0, mag, np.inf)
        stat = _running_median(rel, w)
        thr = rel_threshold
        criterion = (
            f"no G_var: noise unknown, so failure cannot be told from noise; bands where the "
            f"running median over {w} lines of |G_meas - G_model| / |G_meas| exceeds "
            f"{thr:g} (a relative error, not a noise test)"
        )
        notes.append("the measurement has no G_var: relative errors only")
        z_mean = z_mean_pc = z_expected = None
        raw, label = rel, f"running median of the relative error over {w} lines"
    bands = _bands(stat, raw, data.freq, thr, gap)
    return Comparison(
        kind="frf",
        error=err,
        error_per_channel=per_channel,
        map_freq_hz=data.freq,
        error_map=stat,
        map_label=label,
        criterion=criterion,
        threshold=thr,
        failing_bands=tuple(bands),
        z_mean=z_mean,
        z_mean_per_channel=z_mean_pc,
        delay_s=delay_s,
        input_names=data.input_names,
        output_names=data.output_names,
        notes=tuple(notes),
        z_expected=z_expected,
        frf=FrfDetail(freq_hz=data.freq, G_meas=data.G, G_model=Gm, G_var=data.G_var, z=z),
    )


# ------------------------------------------------------------------ time
def kalman_predict(
    model, u: np.ndarray, y: np.ndarray, fs: float, *, delay_s: float = 0.0, noise: float = 0.01
) -> np.ndarray:
    """One-step-ahead prediction of y by a steady-state Kalman predictor.

    Parameters
    ----------
    model : control.StateSpace
        Continuous (ZOH-discretized at ``fs`` with the input delay) or
        discrete with dt = 1 / fs.
    u : (N, n_u) array
        Applied input (N).
    y : (N, n_y) array
        Measured output (m).
    noise : float
        Assumed noise level relative to the signals: a force disturbance at each
        plant input with standard deviation ``noise * rms(u_j)`` and sensor noise
        with ``noise * rms(y_i)``.

    Returns
    -------
    (N, n_y) array
        yhat[k] = C xhat[k|k-1] + D u[k], from xhat[0] = 0.

    Notes
    -----
    A deterministic model has no noise model, and its one-step predictor is
    its simulation. The predictor here assumes a small disturbance at the
    plant input (the physical disturbance of a motion stage) and small sensor
    noise, so that rigid-body drift and initial conditions are corrected from
    the measured output while the model's dynamics over one sample are
    tested: x[k+1] = Ad x[k] + B0 u[k-m] + B1 u[k-m-1] + K (y[k] - yhat[k]),
    K the steady-state gain from the discrete Riccati equation.
    """
    A, B, C, D, dt = lti.as_matrices(model)
    N, n = u.shape[0], A.shape[0]
    if dt > 0:
        Ad, B0, B1, m = A, B, np.zeros_like(B), 0
    else:
        Ad, B0, B1, m = sim.c2d_zoh(A, B, 1.0 / fs, delay_s=delay_s)
    um = np.zeros_like(u)
    if m < N:
        um[m:] = u[: N - m]
    um1 = np.zeros_like(u)
    if m + 1 < N:
        um1[m + 1 :] = u[: N - m - 1]
    drive = um @ B0.T + um1 @ B1.T
    feed = um @ D.T
    if n == 0:
        return feed
    rms_u = np.sqrt(np.mean(u**2, axis=0)) + 1e-300
    rms_y = np.sqrt(np.mean(y**2, axis=0)) + 1e-300
    Bd = B0 + B1
    Q = Bd @ np.diag((noise * rms_u) ** 2) @ Bd.T
    Q = Q + 1e-9 * (np.trace(Q) / n + 1e-300) * np.eye(n)  # uncontrollable states
    R = np.diag((noise * rms_y) ** 2)
    P = scipy.linalg.solve_discrete_are(Ad.T, C.T, Q, R)
    K = Ad @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    F = Ad - K @ C
    yhat = np.empty_like(y)
    x = np.zeros(n)
    inj = drive + (y - feed) @ K.T
    for k in range(N):
        yhat[k] = C @ x
        x = F @ x + inj[k]
    return yhat + feed


def xcorr(e: np.ndarray, x: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalized cross-correlation, (2L+1, n_y, n_u): sum_t e(t) x(t - tau) / norms."""
    N = e.shape[0]
    e = e - e.mean(axis=0)
    x = x - x.mean(axis=0)
    nfft = int(2 ** np.ceil(np.log2(2 * N)))
    E = np.fft.rfft(e, nfft, axis=0)
    X = np.fft.rfft(x, nfft, axis=0)
    c = np.fft.irfft(E[:, :, None] * np.conj(X[:, None, :]), nfft, axis=0)
    lags = np.arange(-max_lag, max_lag + 1)
    c = c[lags % nfft]
    norm = np.sqrt(np.sum(e**2, axis=0))[:, None] * np.sqrt(np.sum(x**2, axis=0))[None, :]
    return c / np.where(norm > 0, norm, np.inf)


def _periodic_z(data: TimeData, resid: np.ndarray):
    """Per-line noise test of the residual of periodic data.

    Returns (freq (n_l,), z (n_l, n_y), dof1, dof2) or None. Blocks and
    transient are those of :func:`workbench.signals.periodic.periodic_record`: in each
    experiment block the first period is dropped while at least 3 remain
    (transients). Per block b of M_b kept periods, the mean residual spectrum
    is compared with the period-to-period scatter, pooled over blocks:
    z = sum_b M_b |mean_b E|^2 / s^2 / n_b ~ F(2 n_b, 2 sum_b (M_b - 1)) when
    the residual is noise (for one block z = |mean E|^2 / (s^2 / M) ~ F(2, 2(M-1))).
    Periods of different experiments are never averaged together: their
    residuals differ when the model is wrong. Only lines excited by r (or u)
    in some block are kept: that is where model errors show.
    """
    from workbench.core.errors import InputError
    from workbench.signals.periodic import periodic_record

    if data.period is None:
        return None
    try:
        rec = periodic_record(data, n_transient=1, min_periods=3)
    except InputError:
        try:  # a block of 2 periods: keep both
            rec = periodic_record(data, n_transient=0, min_periods=2)
        except InputError:
            return None
    lines = rec.lines
    if lines.size == 0:
        return None
    M = rec.n_kept
    mean = rec.mean_spectrum(resid)[:, lines]  # (n_b, n_l, n_y)
    spread = sum(rec.spread_power(resid, b)[lines] for b in range(rec.n_blocks))
    s2 = np.maximum(spread / np.sum(M - 1), 1e-300)
    z = np.einsum("b,bly->ly", M.astype(float), np.abs(mean) ** 2) / s2 / rec.n_blocks
    freq = lines * data.fs / data.period
    return freq, z, 2 * rec.n_blocks, 2 * int(np.sum(M - 1))


def _fit_note(model, data: TimeData, delay_s: float) -> str:
    """The identification fit (x0 by least squares) of ``workbench identify --validate``."""
    import control

    from workbench.ident.validate import simulation_fit

    d = delay_s * data.fs
    if abs(d - round(d)) > 1e-9:
        return "fit with estimated initial state: not computed for a fractional-sample delay"
    A, B, C, D, dt = lti.as_matrices(model)
    if not dt:
        Ad, Bd, _, _ = sim.c2d_zoh(A, B, 1.0 / data.fs)
        model = control.ss(Ad, Bd, C, D, 1.0 / data.fs)
    try:
        f = simulation_fit(model, data, input_delay=int(round(d)))
    except (np.linalg.LinAlgError, ValueError) as exc:
        return f"fit with estimated initial state: failed ({exc})"
    return "identification " + f.describe(list(data.output_names))


def estimated_start(model, data: TimeData, y_rest: np.ndarray):
    """The simulation from the initial state estimated by least squares, or (None, why).

    The free response ``C Ad^k x0`` does not depend on the input or its delay,
    so ``x0`` is the least-squares fit of the model's free response to the
    from-rest residual ``y - y_rest``, every output unweighted (the minimum of the
    relative error reported): :func:`workbench.ident.validate.estimate_x0`
    (the one implementation) on the model with its input removed. The few
    inputs applied before the record that a delay still holds are not
    estimated (they act like a short extra transient).
    """
    import control

    from workbench.ident.validate import DivergentModel, estimate_x0, simulate

    A, _, C, _, dt = lti.as_matrices(model)
    n, n_y = A.shape[0], C.shape[0]
    if n == 0:
        return None, "the model has no state: nothing to estimate"
    Ad = A if dt > 0 else scipy.linalg.expm(A / data.fs)
    free = control.ss(Ad, np.zeros((n, 1)), C, np.zeros((n_y, 1)), 1.0 / data.fs)
    zero = np.zeros((data.n_samples, 1))
    try:
        # unweighted: the start that minimizes the error reported (the spec's Frobenius
        # norm); weighting each output by the rms of its residual moved it off that minimum
        # (a CD player arm model with a slow mode: 0.303 for the minimum's 0.266)
        x0 = estimate_x0(free, zero, data.y - y_rest, weighted=False)
        with np.errstate(over="ignore", invalid="ignore"):
            y_free = simulate(free, zero, x0)
    except (DivergentModel, np.linalg.LinAlgError, ValueError) as exc:
        return None, f"initial state not estimated ({' '.join(str(exc).split())})"
    if not np.all(np.isfinite(y_free)):
        return None, "initial state not estimated (the free response overflows)"
    return y_rest + y_free, ""


#: whole-record error over the noise floor above which compare notes a misfit its bands (the
#: steady state's excited lines) do not test
WHOLE_RECORD_RATIO = 1.1


def _whole_record_floor(data: TimeData, y_model, bands, notes: list) -> float | None:
    """The periodic record's whole-record noise floor (:attr:`Comparison.error_noise_floor`),
    a note where the residual's error is above :data:`WHOLE_RECORD_RATIO` of it while no
    band fails: what the steady state's lines do not show."""
    # at call time: workbench.diagnosis imports this module
    from workbench.diagnosis.detect import noise_floor

    floor = noise_floor(data, y_model)
    if floor is None or floor <= 0:
        return None
    ratio = lti.relative_error_time(data.y, y_model) / floor  # Comparison.whole_record_ratio
    notes.append(
        f"whole record: the residual's error is {ratio:.3g}x the error the noise alone leaves "
        "(noise from the period-to-period spread, over every sample and line)"
    )
    if ratio > WHOLE_RECORD_RATIO and not bands:
        notes.append(
            f"the steady state's excited lines are within noise, but the whole record is "
            f"{ratio:.3g}x its noise floor: a misfit between the excited lines or in the "
            "first period's transient (a lightly damped mode between the lines rings there), "
            "which the bands do not test"
        )
    return floor


def _compare_time(model, data: TimeData, *, delay_s, window, false_alarm, gap, max_lag, noise):
    notes = [
        "error (spec measure): simulation from rest (zero initial state) with the recorded u",
        "residual/excitation cross-correlation bounds 2.58/sqrt(N) assume a white residual or "
        "a white excitation; with a periodic excitation and coloured noise they are optimistic",
    ]
    y = data.y
    ym = sim.simulate_zoh(model, data.u, data.fs, delay_s=delay_s)
    err = lti.relative_error_time(y, ym)
    ym_x0, x0_note = estimated_start(model, data, ym)
    notes.append(_fit_note(model, data, delay_s))
    ny = np.linalg.norm(y, axis=0)
    sim_err = np.linalg.norm(y - ym, axis=0) / np.where(ny > 0, ny, np.inf)
    if ym_x0 is not None:
        err_x0 = lti.relative_error_time(y, ym_x0)
        sim_err_x0 = np.linalg.norm(y - ym_x0, axis=0) / np.where(ny > 0, ny, np.inf)
        resid, residual_from = y - ym_x0, "estimated start"
        notes.append(
            "error with estimated start: initial state by least squares "
            "(workbench.ident.validate.estimate_x0); the residual spectra, cross-correlation "
            "and failing bands use this simulation, so a record that does not start at rest "
            "is not read as model error"
        )
    else:
        err_x0 = sim_err_x0 = None
        resid, residual_from = y - ym, "rest"
        notes.append(f"{x0_note}: residual spectra and bands from the simulation from rest")
    try:
        yp = kalman_predict(model, data.u, y, data.fs, delay_s=delay_s, noise=noise)
        notes.append(
            f"one-step prediction: steady-state Kalman predictor assuming input disturbance "
            f"and sensor noise at {noise:g} x the rms of u and y"
        )
    except (np.linalg.LinAlgError, ValueError) as exc:
        yp = ym
        notes.append(f"Kalman predictor failed ({exc}); prediction error = simulation error")
    pred_err = np.linalg.norm(y - yp, axis=0) / np.where(ny > 0, ny, np.inf)
    nper = data.period if data.period is not None else min(data.n_samples, 1024)
    f_w, p_e = scipy.signal.welch(resid, fs=data.fs, nperseg=nper, axis=0)
    _, p_y = scipy.signal.welch(y, fs=data.fs, nperseg=nper, axis=0)
    exc, against = (data.r, "r") if data.r is not None else (data.u, "u")
    L = int(min(max_lag, data.n_samples - 1))
    xc = xcorr(resid, exc, L)
    bound = 2.58 / np.sqrt(data.n_samples)
    exceeds = np.abs(xc).max(axis=0) > bound
    per = _periodic_z(data, resid)
    if per is not None:
        freq, z, dof1, dof2 = per
        w = min(window, freq.size) | 1
        stat = _running_median(z, w)
        n_windows = z.size  # every position of the running median, every output
        thr = band_threshold(w, false_alarm, n_windows, lambda q: scipy.stats.f.isf(q, dof1, dof2))
        n_b = dof1 // 2
        M = f"{dof2 // 2 + 1}" if n_b == 1 else f"M_b, pooled over {n_b} experiment blocks"
        criterion = (
            f"periodic data: per excited line and output, z = |mean residual spectrum|^2 / "
            f"(period-to-period variance / {M}) ~ F({dof1}, {dof2}) when the residual is noise; "
            f"band where the running median over {w} lines exceeds {thr:.3g} (probability "
            f"{false_alarm:g} of any band for a right model; binomial tail, Bonferroni over "
            f"{n_windows} windows); runs merged over gaps of {gap} lines"
        )
        z_mean = float(z.mean())
        z_pc = z.mean(axis=0)
        z_expected = dof2 / (dof2 - 2) if dof2 > 2 else None
        bands = _bands(stat, z, freq, thr, gap)
        floor = _whole_record_floor(data, y - resid, bands, notes)
        label = f"running median of z over {w} lines"
        # F(2, d) has mean d / (d - 2), not 1
        if z_expected is not None:
            notes.append(f"z ~ F({dof1}, {dof2}): mean {z_expected:.3g} for a right model")
    else:
        freq = f_w[1:]
        stat = p_e[1:] / np.where(p_y[1:] > 0, p_y[1:], np.inf)
        thr = float("nan")
        criterion = (
            "non-periodic data: no noise reference, so no band is declared failing; the map "
            "shows the residual-to-output PSD ratio"
        )
        notes.append("non-periodic record: noise cannot be separated from model error per band")
        z_mean, z_pc, z_expected, bands, floor = None, None, None, [], None
        label = "Welch PSD of the residual / PSD of y"
    return Comparison(
        kind="time",
        error=err,
        error_per_channel=sim_err,
        map_freq_hz=freq,
        error_map=stat,
        map_label=label,
        criterion=criterion,
        threshold=thr,
        failing_bands=tuple(bands),
        z_mean=z_mean,
        z_mean_per_channel=z_pc,
        delay_s=delay_s,
        input_names=data.input_names,
        output_names=data.output_names,
        notes=tuple(notes),
        error_estimated_start=err_x0,
        z_expected=z_expected,
        error_noise_floor=floor,
        time=TimeDetail(
            fs=data.fs,
            y=y,
            y_model=ym,
            y_model_x0=ym_x0,
            sim_error_x0=sim_err_x0,
            residual_from=residual_from,
            x0_note=x0_note,
            y_pred=yp,
            sim_error=sim_err,
            pred_error=pred_err,
            psd_freq_hz=f_w,
            psd_residual=p_e,
            psd_output=p_y,
            xcorr_lags=np.arange(-L, L + 1),
            xcorr=xc,
            xcorr_bound=float(bound),
            xcorr_exceeds=exceeds,
            xcorr_outside=float(np.mean(np.abs(xc) > bound)),
            xcorr_against=against,
        ),
    )


# ---------------------------------------------------------------- public
def compare(
    model,
    data: FrfData | TimeData,
    *,
    delay_s: float = 0.0,
    window: int = 9,
    false_alarm: float = 1e-3,
    gap_lines: int = 3,
    rel_threshold: float = 0.1,
    max_lag: int = 25,
    predictor_noise: float = 0.01,
    model_src: str = "model",
    data_src: str = "data",
) -> Comparison:
    """Compare a model with a measurement.

    Parameters
    ----------
    model : LTIModel, control.StateSpace or model file path
        Continuous (dt = 0) or discrete model, n_u inputs, n_y outputs; an
        LTIModel's input delay is part of it.
    data : FrfData or TimeData
        The measurement (n_y x n_u like the model).
    delay_s : float
        Input delay added to the model's own, s.
    window : int
        Lines in the running median of the per-line statistic (made odd).
    false_alarm : float
        Probability that a model which is right within noise shows any failing
        band; sets the threshold with the number of lines and channels.
    gap_lines : int
        Failing runs separated by at most this many lines are merged.
    rel_threshold : float
        FRF without ``G_var``: relative error above which a band is listed.
    max_lag : int
        Largest lag of the residual/input cross-correlation, samples.
    predictor_noise : float
        Relative noise level assumed by the one-step predictor (time data).

    Returns
    -------
    Comparison

    Raises
    ------
    InputError
        When the model's input/output count does not match the data.
    """
    from workbench.core.model import as_model

    lti_model = as_model(model)
    check_model_matches(lti_model, data, model_src=model_src, data_src=data_src)
    delay_s = float(delay_s)
    if not np.isfinite(delay_s) or delay_s < 0:
        from workbench.core.errors import InputError

        raise InputError(f"delay_s: expected a finite delay >= 0 s, got {delay_s:g}")
    # the model's own delay travels with it; delay_s adds to it
    delay_s += lti_model.delay_s
    model = lti_model.without_delay().to_statespace()
    window = max(1, int(window)) | 1
    if isinstance(data, FrfData):
        return _compare_frf(
            model,
            data,
            delay_s=delay_s,
            window=window,
            false_alarm=false_alarm,
            gap=gap_lines,
            rel_threshold=rel_threshold,
        )
    if isinstance(data, TimeData):
        return _compare_time(
            model,
            data,
            delay_s=delay_s,
            window=window,
            false_alarm=false_alarm,
            gap=gap_lines,
            max_lag=max_lag,
            noise=predictor_noise,
        )
    raise TypeError(f"data: expected FrfData or TimeData, got {type(data).__name__}")
