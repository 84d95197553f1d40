"""Abscissas of imported data: a time axis gives a sampling frequency; frequency lines are checked.

The spec keeps no time vector: a record is uniformly sampled at ``fs`` Hz. A
file's time axis is accepted when every sample instant lies on one uniform grid
to within the axis' own resolution (the last printed digit of a text file, 1e-6
of a step otherwise); ``fs`` is then the shortest decimal number whose grid
reproduces the instants as well (a CSV time column printed to 6 decimals at
3 kHz gives 3000 Hz, not 2999.9997 Hz).
"""

from __future__ import annotations

import numpy as np

from workbench.core.errors import InputError

__all__ = ["rate_from_time_axis", "rate_from_printed_step", "frequency_lines"]


def _shortest(value: float, fits) -> float:
    """The number with the fewest significant digits near ``value`` for which ``fits`` holds."""
    for digits in range(1, 18):
        candidate = float(f"{value:.{digits}g}")
        if candidate > 0 and fits(candidate):
            return candidate
    return value


def _stated(rate: float, fits, stated: float | None, stated_by: str, where: str) -> float:
    """``stated`` (a rate the map or a tag gives) when it fits the axis, else the shortest fit."""
    if stated is None:
        return _shortest(rate, fits)
    if not fits(stated):
        raise InputError(
            f"{where}: gives {_shortest(rate, fits):.10g} Hz, {stated_by} says {stated:.10g} Hz"
        )
    return float(stated)


def rate_from_time_axis(
    t: np.ndarray,
    where: str,
    resolution: float | np.ndarray = 0.0,
    stated: float | None = None,
    stated_by: str = "",
) -> float:
    """Sampling frequency (Hz) of a uniform time axis ``t`` (s, shape (N,)).

    Refused (one line, ``where`` naming file and field): fewer than two
    instants, a time that does not increase, and instants off the uniform grid
    by more than ``resolution`` (s, scalar or per instant (N,); at least 1e-6 of
    a step): a dropped sample,
    a jittery logger clock. A rate ``stated`` elsewhere (the map: ``stated_by``)
    is taken when its grid fits the instants as well, refused otherwise.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    n = t.size
    if n < 2:
        raise InputError(f"{where}: expected a time axis of at least 2 samples, got {n}")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{where}: expected finite times, got a NaN or infinite value")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        raise InputError(
            f"{where}: expected increasing time, got t[{k}] = {t[k]:.10g} s followed by "
            f"t[{k + 1}] = {t[k + 1]:.10g} s"
        )
    step = (t[-1] - t[0]) / (n - 1)
    k = np.arange(n)
    bound = np.maximum(np.asarray(resolution, float), 1e-6 * step)
    typical = np.median(steps)
    if np.any(np.abs(t - (t[0] + k * step)) > bound) or np.any(
        np.abs(steps - typical) > 0.25 * typical
    ):
        j = int(np.argmax(np.abs(steps - typical)))
        raise InputError(
            f"{where}: expected a uniform time axis (step {typical:.6g} s), got a step of "
            f"{steps[j]:.6g} s between samples {j} and {j + 1}"
        )

    def fits(fs: float) -> bool:
        return bool(np.all(np.abs(t - (t[0] + k / fs)) <= bound))

    return _stated(1.0 / step, fits, stated, stated_by, where)


def rate_from_printed_step(
    step: float, where: str, digits: int = 6, stated: float | None = None, stated_by: str = ""
) -> float:
    """Sampling frequency (Hz) from a time step printed to ``digits`` significant digits.

    A universal file writes the abscissa increment as ``E13.5`` (6 digits):
    3 kHz is ``3.33333E-04``. The rate is the shortest number whose step prints
    the same, 3000 Hz, not 1 / 3.33333e-4 = 3000.003 Hz; a rate ``stated``
    elsewhere is taken when its step prints the same, refused otherwise.
    """
    if not step > 0:
        raise InputError(f"{where}: expected a time step > 0 s, got {step:g}")
    printed = f"{step:.{digits - 1}e}"
    return _stated(
        1.0 / step,
        lambda fs: f"{1.0 / fs:.{digits - 1}e}" == printed,
        stated,
        stated_by,
        where,
    )


def frequency_lines(freq: np.ndarray, where: str) -> tuple[np.ndarray, bool]:
    """Check frequency lines (Hz, shape (n_f,)); return them without a 0 Hz line, and whether
    one was dropped.

    The spec's lines are strictly increasing and > 0. A first line at 0 Hz (a
    DC line, as modal-test systems write) is dropped; duplicate lines, lines
    that go down and negative lines are refused.
    """
    f = np.asarray(freq, dtype=float).reshape(-1)
    if f.size < 1:
        raise InputError(f"{where}: expected at least one frequency line, got none")
    if not np.all(np.isfinite(f)):
        raise InputError(f"{where}: expected finite frequencies, got a NaN or infinite value")
    steps = np.diff(f)
    if np.any(steps == 0):
        k = int(np.flatnonzero(steps == 0)[0])
        raise InputError(
            f"{where}: expected distinct frequency lines, got {f[k]:.10g} Hz twice "
            f"(lines {k} and {k + 1})"
        )
    if np.any(steps < 0):
        k = int(np.flatnonzero(steps < 0)[0])
        raise InputError(
            f"{where}: expected increasing frequency lines, got {f[k]:.10g} Hz followed by "
            f"{f[k + 1]:.10g} Hz (lines {k} and {k + 1})"
        )
    dropped = bool(f[0] == 0.0)
    if dropped:
        f = f[1:]
    if f.size < 1 or f[0] <= 0:
        got = "only the 0 Hz line" if f.size < 1 else f"{f[0]:.10g} Hz"
        raise InputError(f"{where}: expected frequency lines > 0 Hz, got {got}")
    return f, dropped
