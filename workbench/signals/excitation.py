"""Excitation signals: multisines, white noise and steps.

Data flow::

    multisine(fs=, period=, band_hz=, n_ch=, rms=, kind=, design=, rng=) -> Multisine
        .lines          (n_lines,)  excited DFT bins of one period
        .coef           (R, n_exp, n_lines, n_ch) complex line amplitudes
        .one_period()   (R, n_exp, period, n_ch)  one period of every signal
    white_noise(...)  -> (N, n_ch)        step_signal(...) -> (N, n_ch)

A multisine is periodic with ``period`` samples; line ``k`` sits at
``k * fs / period`` Hz. Every signal is real and built from its positive-frequency
line amplitudes ``c``::

    x[n] = sum_l Re(c_l exp(j 2 pi k_l n / period)),   rfft(x over one period)[k_l] = c_l period / 2

Designs (Pintelon & Schoukens, *System Identification: A Frequency Domain
Approach*, 2nd ed., 2012, sections 2.6-2.7 and 3.7):

- ``kind="full"``: every bin in the band; ``"odd"``: odd bins only (even bins
  detect even nonlinear distortion); ``"random_odd"``: odd bins with one line
  left out at random in every group of ``group`` consecutive odd lines (the
  left-out odd lines detect odd distortion as well).
- ``design="independent"``: ``n_exp`` experiments (default ``n_ch``), every
  channel of every experiment an independent random-phase multisine.
  ``design="orthogonal"``: one random-phase multisine per channel, multiplied
  across the experiments by the entries of an orthogonal matrix ``T`` (a
  Hadamard sign pattern when ``n_exp`` is a power of two, otherwise the unit
  modulus DFT matrix), so the input matrix of every line is ``diag(c) T`` with
  ``T T^H = n_exp I``: perfectly conditioned (Dobrowiecki, Schoukens & Pintelon,
  IEEE TIM 55(1), 2006).
- ``R`` realizations draw new random phases, so averaging over them reduces
  the stochastic nonlinear distortion as well as the noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg

from workbench.core.errors import InputError

__all__ = [
    "Multisine",
    "multisine",
    "multisine_lines",
    "white_noise",
    "step_signal",
    "crest_factor",
    "as_rng",
]


def as_rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    """A ``np.random.Generator`` from a generator or an integer seed.

    ``None`` is refused: every experiment is seeded and reproducible.
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise InputError(
        f"rng: expected a numpy.random.Generator or an integer seed, got {rng!r}; "
        "pass rng=np.random.default_rng(seed)"
    )


def _per_channel(value, n_ch: int, name: str) -> np.ndarray:
    a = np.asarray(value, float)
    if a.ndim == 0:
        a = np.full(n_ch, float(a))
    if a.shape != (n_ch,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InputError(
            f"{name}: expected a value >= 0 or {n_ch} values >= 0 (one per channel), got {value!r}"
        )
    return a


def multisine_lines(
    *,
    fs: float,
    period: int,
    band_hz: tuple[float, float],
    kind: Literal["full", "odd", "random_odd"] = "random_odd",
    group: int = 4,
    rng: np.random.Generator | int,
) -> np.ndarray:
    """Excited DFT bins of one period.

    Parameters
    ----------
    fs : float
        Sampling frequency, Hz.
    period : int
        Samples per period; the frequency resolution is ``fs / period`` Hz.
    band_hz : (float, float)
        Lowest and highest excited frequency, Hz, inclusive, within (0, fs/2).
    kind : {"full", "odd", "random_odd"}
        See the module docstring.
    group : int
        For ``"random_odd"``: one odd line in each group of ``group`` is left out.
    rng : Generator or int

    Returns
    -------
    (n_lines,) int array, strictly increasing bins k, 1 <= k < period / 2.
    """
    period = int(period)
    if period < 4:
        raise InputError(f"period: expected at least 4 samples, got {period}")
    f_lo, f_hi = (float(b) for b in band_hz)
    df = fs / period
    if not (0 < f_lo <= f_hi < fs / 2):
        raise InputError(
            f"band_hz: expected 0 < low <= high < fs/2 = {fs / 2:g} Hz, got ({f_lo:g}, {f_hi:g})"
        )
    k = np.arange(max(1, int(np.ceil(f_lo / df - 1e-9))), int(np.floor(f_hi / df + 1e-9)) + 1)
    k = k[k < period / 2]
    if kind == "full":
        lines = k
    elif kind in ("odd", "random_odd"):
        lines = k[k % 2 == 1]
        if kind == "random_odd":
            if group < 2:
                raise InputError(f"group: expected an integer >= 2, got {group}")
            rng = as_rng(rng)
            keep = np.ones(lines.size, bool)
            for start in range(0, lines.size - group + 1, group):
                keep[start + rng.integers(group)] = False
            lines = lines[keep]
    else:
        raise InputError(f"kind: expected 'full', 'odd' or 'random_odd', got {kind!r}")
    if lines.size == 0:
        raise InputError(
            f"band_hz: no {kind} line of resolution {df:g} Hz lies in ({f_lo:g}, {f_hi:g}) Hz; "
            "widen the band or lengthen the period"
        )
    return lines.astype(int)


def _orthogonal_matrix(n_ch: int, n_exp: int) -> np.ndarray:
    """(n_ch, n_exp) matrix with orthogonal rows of unit-modulus entries."""
    if n_exp < n_ch:
        raise InputError(
            f"n_exp: an orthogonal design needs at least n_ch = {n_ch} experiments, got {n_exp}"
        )
    if n_exp & (n_exp - 1) == 0:
        return scipy.linalg.hadamard(n_exp)[:n_ch].astype(complex)
    idx = np.arange(n_exp)
    return np.exp(-2j * np.pi * np.outer(idx, idx) / n_exp)[:n_ch]


@dataclass(frozen=True)
class Multisine:
    """A periodic multisine design: line amplitudes of every channel, experiment, realization.

    Parameters
    ----------
    fs : float
        Sampling frequency, Hz.
    period : int
        Samples per period.
    lines : (n_lines,) int array
        Excited DFT bins of one period (frequency ``lines * fs / period`` Hz).
    coef : (R, n_exp, n_lines, n_ch) complex array
        Line amplitudes c (units of the signal, e.g. N): the signal is
        ``sum_l Re(c_l exp(j 2 pi k_l n / period))``.
    kind : str
        ``"full"``, ``"odd"`` or ``"random_odd"`` (which lines are left out).
    """

    fs: float
    period: int
    lines: np.ndarray
    coef: np.ndarray
    kind: str = "full"

    def __post_init__(self):
        lines = np.array(self.lines, dtype=int)
        coef = np.array(self.coef, dtype=complex)
        if (
            lines.ndim != 1
            or np.any(np.diff(lines) <= 0)
            or lines[0] < 1
            or lines[-1] >= self.period / 2
        ):
            raise InputError(
                f"lines: expected strictly increasing bins in [1, period/2), got {self.lines!r}"
            )
        if coef.ndim != 4 or coef.shape[2] != lines.size:
            raise InputError(
                f"coef: expected shape (R, n_exp, {lines.size}, n_ch), got {coef.shape}"
            )
        for name, a in (("lines", lines), ("coef", coef)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "period", int(self.period))
        object.__setattr__(self, "fs", float(self.fs))

    @property
    def n_realizations(self) -> int:
        return self.coef.shape[0]

    @property
    def n_exp(self) -> int:
        return self.coef.shape[1]

    @property
    def n_ch(self) -> int:
        return self.coef.shape[3]

    @property
    def freq(self) -> np.ndarray:
        """Excited frequencies, Hz, shape (n_lines,)."""
        return self.lines * self.fs / self.period

    def one_period(self) -> np.ndarray:
        """One period of every signal, shape (R, n_exp, period, n_ch)."""
        spec = np.zeros(self.coef.shape[:2] + (self.period // 2 + 1, self.n_ch), complex)
        spec[:, :, self.lines, :] = self.coef * (self.period / 2)
        return np.fft.irfft(spec, n=self.period, axis=2)

    def signal(self, n_periods: int) -> np.ndarray:
        """``n_periods`` periods of every signal, shape (R, n_exp, n_periods * period, n_ch)."""
        return np.tile(self.one_period(), (1, 1, int(n_periods), 1))


def multisine(
    *,
    fs: float,
    period: int,
    band_hz: tuple[float, float],
    n_ch: int,
    rms: float | np.ndarray = 1.0,
    kind: Literal["full", "odd", "random_odd"] = "random_odd",
    design: Literal["independent", "orthogonal"] = "independent",
    n_exp: int | None = None,
    n_realizations: int = 1,
    group: int = 4,
    rng: np.random.Generator | int,
) -> Multisine:
    """Random-phase multisine design with flat amplitude spectrum.

    Parameters
    ----------
    fs : float
        Sampling frequency, Hz.
    period : int
        Samples per period.
    band_hz : (float, float)
        Excited band, Hz.
    n_ch : int
        Number of input channels.
    rms : float or (n_ch,) array
        Root-mean-square value of each channel's signal (signal units, e.g. N).
    kind : {"full", "odd", "random_odd"}
        Which lines are excited (module docstring).
    design : {"independent", "orthogonal"}
        Phases across experiments (module docstring).
    n_exp : int, optional
        Number of experiments, default ``n_ch`` (at least ``n_ch`` so that
        every input direction is excited at every line).
    n_realizations : int
        Number R of independent random-phase realizations.
    group : int
        Group size of the random-odd design.
    rng : Generator or int

    Returns
    -------
    Multisine
    """
    rng = as_rng(rng)
    n_ch = int(n_ch)
    if n_ch < 1:
        raise InputError(f"n_ch: expected at least 1 channel, got {n_ch}")
    n_exp = n_ch if n_exp is None else int(n_exp)
    if n_exp < 1 or n_realizations < 1:
        raise InputError(f"n_exp, n_realizations: expected >= 1, got {n_exp} and {n_realizations}")
    rms = _per_channel(rms, n_ch, "rms")
    lines = multisine_lines(fs=fs, period=period, band_hz=band_hz, kind=kind, group=group, rng=rng)
    n_l = lines.size
    amp = rms * np.sqrt(2.0 / n_l)  # sum of n_l cosines of amplitude a has rms a sqrt(n_l / 2)
    if design == "independent":
        phase = rng.uniform(0, 2 * np.pi, (n_realizations, n_exp, n_l, n_ch))
        coef = amp * np.exp(1j * phase)
    elif design == "orthogonal":
        T = _orthogonal_matrix(n_ch, n_exp)  # (n_ch, n_exp)
        phase = rng.uniform(0, 2 * np.pi, (n_realizations, 1, n_l, n_ch))
        coef = amp * np.exp(1j * phase) * T.T[None, :, None, :]
    else:
        raise InputError(f"design: expected 'independent' or 'orthogonal', got {design!r}")
    return Multisine(fs=fs, period=period, lines=lines, coef=coef, kind=kind)


def white_noise(
    n_samples: int,
    n_ch: int,
    *,
    fs: float,
    rms: float | np.ndarray = 1.0,
    band_hz: tuple[float, float] | None = None,
    rng: np.random.Generator | int,
) -> np.ndarray:
    """Gaussian white (or band-limited) noise, shape (n_samples, n_ch).

    Parameters
    ----------
    n_samples, n_ch : int
    fs : float
        Sampling frequency, Hz.
    rms : float or (n_ch,) array
        Root-mean-square value per channel (signal units).
    band_hz : (float, float), optional
        If given, the spectrum outside the band is zeroed (an ideal brick-wall
        filter over the whole record) and the result rescaled to ``rms``.
    rng : Generator or int
    """
    rng = as_rng(rng)
    rms = _per_channel(rms, int(n_ch), "rms")
    x = rng.standard_normal((int(n_samples), int(n_ch)))
    if band_hz is not None:
        f_lo, f_hi = (float(b) for b in band_hz)
        if not (0 <= f_lo < f_hi <= fs / 2):
            raise InputError(
                f"band_hz: expected 0 <= low < high <= fs/2 = {fs / 2:g} Hz, got {band_hz!r}"
            )
        X = np.fft.rfft(x, axis=0)
        f = np.fft.rfftfreq(x.shape[0], 1 / fs)
        X[(f < f_lo) | (f > f_hi)] = 0
        x = np.fft.irfft(X, n=x.shape[0], axis=0)
    std = x.std(axis=0)
    return x / np.where(std > 0, std, 1.0) * rms


def step_signal(
    n_samples: int,
    *,
    amplitude: float | np.ndarray,
    n_ch: int,
    start_sample: int = 0,
) -> np.ndarray:
    """Steps of ``amplitude`` (per channel) from sample ``start_sample`` on.

    Returns
    -------
    (n_samples, n_ch) array
    """
    amp = np.asarray(amplitude, float)
    amp = np.broadcast_to(amp, (int(n_ch),)) if amp.ndim == 0 else amp
    if amp.shape != (int(n_ch),):
        raise InputError(f"amplitude: expected a scalar or {n_ch} values, got shape {amp.shape}")
    if not 0 <= start_sample < n_samples:
        raise InputError(
            f"start_sample: expected 0 <= start_sample < n_samples = {n_samples}, "
            f"got {start_sample}"
        )
    x = np.zeros((int(n_samples), int(n_ch)))
    x[int(start_sample) :] = amp
    return x


def crest_factor(x: np.ndarray) -> np.ndarray:
    """Peak over rms of each column of ``x`` (..., N, n_ch), shape (..., n_ch)."""
    x = np.asarray(x, float)
    rms = np.sqrt(np.mean(x**2, axis=-2))
    return np.max(np.abs(x), axis=-2) / np.where(rms > 0, rms, np.inf)
