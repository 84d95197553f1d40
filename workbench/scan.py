"""Scan setpoints and the tracking figures lithography judges them by.

Data flow::

    point_to_point(distance, limits, fs) / scan(velocity, scan_length, limits, fs)
        -> ScanProfile (t, position, velocity, acceleration, jerk, snap; constant-velocity window)
    ScanProfile.position as the reference r of workbench.sim.closed_loop -> error e = r - y
    tracking_figures(e, fs, window_s=, during=profile.constant_velocity_s)
        -> TrackingFigures (max |MA|, max MSD, rms per channel)

The setpoint is 4th order: its snap (4th derivative of position) is piecewise
constant, so jerk is continuous and piecewise linear. It is built as a position
step of height D filtered by four unit-area moving averages of durations
T1 >= T2 >= T3 >= T4 (Lambrechts, Boerlage & Steinbuch, "Trajectory planning and
feedforward design for electromechanical motion systems", Control Engineering
Practice 13(2), 2005, sec. 3; the moving-average form is the same profile)::

    p(t) = D / (T1 T2 T3 T4) * sum_{S in subsets of {1..4}} (-1)^|S| (t - sigma_S)_+^4 / 4!

with sigma_S the sum of the T_i in S. The k-th derivative is the same sum with
(t - sigma_S)_+^(4-k) / (4-k)!, exact at every sample. When
T3 >= T4, T2 >= T3 + T4, T1 >= T2 + T3 + T4 the pulses of each derivative do
not overlap and the peaks are exactly
|v| = D/T1, |a| = D/(T1 T2), |j| = D/(T1 T2 T3), |snap| = D/(T1 T2 T3 T4); the
durations are chosen so that these hold and each peak is at most its limit.

Tracking figures (exposure window of ``window_s``; SEMI / ASML convention):
the moving average MA(t) = mean of e over the window ending at t and the moving
standard deviation MSD(t) = std of e over that window (population, 1/n), over
the windows that lie wholly inside the constant-velocity part; reported per
channel as max |MA|, max MSD and the rms of e over the constant-velocity part.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from workbench.core.errors import InputError

__all__ = [
    "ScanLimits",
    "ScanProfile",
    "TrackingFigures",
    "point_to_point",
    "scan",
    "tracking_figures",
    "moving_average_std",
]


def _positive(name: str, value) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name}: expected a finite value > 0, got {value!r}")
    return v


@dataclass(frozen=True)
class ScanLimits:
    """Bounds of a 4th-order setpoint, SI units.

    Parameters
    ----------
    velocity : float
        Max |v|, m/s (rad/s for a rotation).
    acceleration : float
        Max |a|, m/s^2.
    jerk : float
        Max |j|, m/s^3.
    snap : float
        Max |d^4 p / dt^4|, m/s^4.
    """

    velocity: float
    acceleration: float
    jerk: float
    snap: float

    def __post_init__(self):
        for name in ("velocity", "acceleration", "jerk", "snap"):
            object.__setattr__(self, name, _positive(f"ScanLimits.{name}", getattr(self, name)))


@dataclass(frozen=True)
class ScanProfile:
    """A sampled 4th-order setpoint (from rest to rest).

    Attributes
    ----------
    t : (N,) array
        Sample times, s (t[k] = k / fs).
    position, velocity, acceleration, jerk, snap : (N,) arrays
        m, m/s, m/s^2, m/s^3, m/s^4, exact at the samples.
    fs : float
        Sampling frequency, Hz.
    distance : float
        Total move, m (``position[-1] == distance`` once the move is over).
    durations_s : (4,) tuple
        T1 >= T2 >= T3 >= T4 of the moving-average construction, s.
    constant_velocity_s : (2,) tuple
        [start, end] of the constant-velocity part, s (start == end: none).
    """

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    snap: np.ndarray
    fs: float
    distance: float
    durations_s: tuple[float, float, float, float]
    constant_velocity_s: tuple[float, float]

    def __post_init__(self):
        n = np.asarray(self.t).shape
        for name in ("t", "position", "velocity", "acceleration", "jerk", "snap"):
            a = np.array(getattr(self, name), dtype=float)
            if a.ndim != 1 or a.shape != n:
                raise InputError(f"ScanProfile.{name}: expected shape {n}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def move_s(self) -> float:
        """Duration of the move, s (T1 + T2 + T3 + T4)."""
        return float(sum(self.durations_s))

    def reference(self, n_ch: int, channel: int, *, sign: float = 1.0) -> np.ndarray:
        """The position on ``channel`` of an (N, n_ch) reference, zeros elsewhere (m)."""
        if not 0 <= channel < n_ch:
            raise InputError(f"channel: expected 0 <= channel < {n_ch}, got {channel}")
        r = np.zeros((self.t.size, n_ch))
        r[:, channel] = sign * self.position
        return r


def _durations(distance: float, lim: ScanLimits) -> tuple[float, float, float, float]:
    """T1..T4 with each derivative's peak <= its limit and the pulses non-overlapping.

    Chosen from the snap side: T4 = j/s, T3 = a/j, T2 = v/a, T1 = D/v, each
    raised where needed to T3 >= T4, T2 >= T3 + T4, T1 >= T2 + T3 + T4. Raising a
    duration only lowers the peaks, so every limit holds; when a limit is not
    binding (a short move) the move is not time-optimal.
    """
    T4 = lim.jerk / lim.snap
    T3 = max(lim.acceleration / lim.jerk, T4)
    T2 = max(lim.velocity / lim.acceleration, T3 + T4)
    T1 = max(distance / lim.velocity, T2 + T3 + T4)
    return T1, T2, T3, T4


def _evaluate(t: np.ndarray, distance: float, T) -> np.ndarray:
    """(5, N): position and its first four derivatives at ``t`` (closed form, module notes)."""
    out = np.zeros((5, t.size))
    scale = distance / float(np.prod(T))
    fact = (24.0, 6.0, 2.0, 1.0, 1.0)
    for subset in itertools.product((0, 1), repeat=4):
        sigma = float(np.dot(subset, T))
        sign = -1.0 if sum(subset) % 2 else 1.0
        tau = np.maximum(t - sigma, 0.0)
        on = (t >= sigma).astype(float)  # the Heaviside for snap (tau^0)
        for k in range(5):
            power = 4 - k
            term = tau**power if power else on
            out[k] += sign * term / fact[k]
    out *= scale
    # after the move: at rest at the target, exactly (the sum cancels there only to rounding)
    done = t >= sum(T)
    out[0, done] = distance
    out[1:, done] = 0.0
    return out


def _profile(distance: float, T, fs: float, settle_s: float, lead_s: float) -> ScanProfile:
    fs = _positive("fs", fs)
    settle_s = float(settle_s)
    lead_s = float(lead_s)
    if settle_s < 0 or lead_s < 0:
        raise InputError(f"settle_s, lead_s: expected >= 0 s, got {settle_s!r}, {lead_s!r}")
    n = int(np.ceil((lead_s + sum(T) + settle_s) * fs)) + 1
    t = np.arange(n) / fs
    vals = _evaluate(t - lead_s, distance, T)
    T1, T2, T3, T4 = T
    cv = (lead_s + T2 + T3 + T4, lead_s + T1)
    return ScanProfile(
        t=t, position=vals[0], velocity=vals[1], acceleration=vals[2], jerk=vals[3],
        snap=vals[4], fs=fs, distance=distance, durations_s=tuple(T),
        constant_velocity_s=cv,
    )  # fmt: skip


def point_to_point(
    distance: float, limits: ScanLimits, fs: float, *, lead_s: float = 0.0, settle_s: float = 0.0
) -> ScanProfile:
    """A rest-to-rest move over ``distance`` (m, > 0) within ``limits``, sampled at ``fs`` (Hz).

    ``lead_s`` of rest before the move and ``settle_s`` after it are added.

    Examples
    --------
    >>> p = point_to_point(0.01, ScanLimits(0.25, 10.0, 2e3, 1e6), 5000.0)
    >>> float(p.position[-1]), round(float(abs(p.velocity).max()), 12)
    (0.01, 0.25)
    """
    d = _positive("distance", distance)
    if not isinstance(limits, ScanLimits):
        raise InputError(f"limits: expected a ScanLimits, got {type(limits).__name__}")
    return _profile(d, _durations(d, limits), fs, settle_s, lead_s)


def scan(
    velocity: float,
    scan_length: float,
    limits: ScanLimits,
    fs: float,
    *,
    lead_s: float = 0.0,
    settle_s: float = 0.0,
) -> ScanProfile:
    """A scan: accelerate to ``velocity`` (m/s), hold it over ``scan_length`` (m), stop.

    The constant-velocity part lasts scan_length / velocity seconds; the
    acceleration, jerk and snap stay within ``limits`` (``limits.velocity``
    must allow ``velocity``). The total distance is velocity * T1.
    """
    v = _positive("velocity", velocity)
    length = _positive("scan_length", scan_length)
    if not isinstance(limits, ScanLimits):
        raise InputError(f"limits: expected a ScanLimits, got {type(limits).__name__}")
    if v > limits.velocity:
        raise InputError(
            f"velocity: expected at most limits.velocity = {limits.velocity:g} m/s, got {v:g}"
        )
    at = ScanLimits(v, limits.acceleration, limits.jerk, limits.snap)
    _, T2, T3, T4 = _durations(0.0, at)
    T1 = length / v + T2 + T3 + T4
    return _profile(v * T1, (T1, T2, T3, T4), fs, settle_s, lead_s)


# ------------------------------------------------------------------ tracking figures
@dataclass(frozen=True)
class TrackingFigures:
    """Tracking figures per channel over the constant-velocity part.

    Attributes
    ----------
    ma_max : (n_ch,) array
        max over the exposure windows of |moving average of e|, units of e.
    msd_max : (n_ch,) array
        max over the exposure windows of the moving standard deviation of e.
    rms : (n_ch,) array
        rms of e over the constant-velocity part.
    window_s : float
        Exposure window, s.
    n_windows : int
        Number of windows evaluated (each wholly inside the part).
    """

    ma_max: np.ndarray
    msd_max: np.ndarray
    rms: np.ndarray
    window_s: float
    n_windows: int

    def __post_init__(self):
        for name in ("ma_max", "msd_max", "rms"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def as_dict(self, names=None) -> dict:
        """JSON-ready: {figure: {channel name: value}}, plus window_s and n_windows."""
        names = list(names) if names is not None else [f"y{i}" for i in range(self.rms.size)]
        out: dict = {"window_s": self.window_s, "n_windows": self.n_windows}
        for key in ("ma_max", "msd_max", "rms"):
            out[key] = {n: float(v) for n, v in zip(names, getattr(self, key), strict=True)}
        return out


def moving_average_std(e: np.ndarray, n_window: int) -> tuple[np.ndarray, np.ndarray]:
    """(MA, MSD) of each column of ``e`` over windows of ``n_window`` samples.

    Parameters
    ----------
    e : (N, n_ch) array
    n_window : int
        Window length, samples (1 <= n_window <= N).

    Returns
    -------
    ma, msd : (N - n_window + 1, n_ch) arrays
        Row k: mean and population standard deviation of e[k : k + n_window].

    Notes
    -----
    Running sums of e - mean(e) (centring keeps the variance from cancelling
    out of two large sums), variance clipped at 0 against rounding.
    """
    e = np.asarray(e, float)
    if e.ndim != 2:
        raise InputError(f"e: expected shape (N, n_ch), got {e.shape}")
    n = int(n_window)
    if n != n_window or not 1 <= n <= e.shape[0]:
        raise InputError(f"n_window: expected an integer in 1..{e.shape[0]}, got {n_window!r}")
    c = e - e.mean(axis=0)
    zero = np.zeros((1, e.shape[1]))
    s1 = np.concatenate([zero, np.cumsum(c, axis=0)])
    s2 = np.concatenate([zero, np.cumsum(c * c, axis=0)])
    m1 = (s1[n:] - s1[:-n]) / n
    m2 = (s2[n:] - s2[:-n]) / n
    msd = np.sqrt(np.maximum(m2 - m1 * m1, 0.0))
    return m1 + e.mean(axis=0), msd


def tracking_figures(
    e: np.ndarray, fs: float, *, window_s: float, during: tuple[float, float] | None = None
) -> TrackingFigures:
    """Max |MA|, max MSD and rms of the error ``e`` (N, n_ch) over the part ``during``.

    Parameters
    ----------
    e : (N, n_ch) array
        Tracking error r - y sampled at ``fs`` (Hz), t[k] = k / fs.
    window_s : float
        Exposure window, s (rounded to whole samples, at least one).
    during : (t_start, t_end), optional
        The constant-velocity part, s (``ScanProfile.constant_velocity_s``);
        default the whole record. Windows wholly inside it are evaluated.
    """
    e = np.asarray(e, float)
    if e.ndim != 2 or e.shape[0] == 0:
        raise InputError(f"e: expected shape (N, n_ch) with N >= 1, got {e.shape}")
    fs = _positive("fs", fs)
    window_s = _positive("window_s", window_s)
    n_w = max(int(round(window_s * fs)), 1)
    if during is None:
        k0, k1 = 0, e.shape[0]
    else:
        t0, t1 = float(during[0]), float(during[1])
        k0 = max(int(np.ceil(t0 * fs - 1e-9)), 0)
        k1 = min(int(np.floor(t1 * fs + 1e-9)) + 1, e.shape[0])
    part = e[k0:k1]
    if part.shape[0] < n_w:
        raise InputError(
            f"window_s: expected an exposure window within the constant-velocity part "
            f"({part.shape[0]} samples), got {n_w} samples ({window_s:g} s)"
        )
    ma, msd = moving_average_std(part, n_w)
    return TrackingFigures(
        ma_max=np.max(np.abs(ma), axis=0),
        msd_max=np.max(msd, axis=0),
        rms=np.sqrt(np.mean(part**2, axis=0)),
        window_s=n_w / fs,
        n_windows=int(ma.shape[0]),
    )
