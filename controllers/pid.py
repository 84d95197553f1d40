"""Decentralized PID / lead-lag + low-pass (+ notch) controller, discrete time.

Per input channel ``j`` the loop closes over one sensor ``sensor_index[j]``
with the continuous design

    K_j(s) = kp (1 + w_i / s) (1 + s / w_z) / (1 + s / w_p) w_lp^2 / (s^2 + 2 z_lp w_lp s + w_lp^2)
             [ (s^2 + 2 z_nz w_n s + w_n^2) / (s^2 + 2 z_np w_n s + w_n^2) ]

discretized with the bilinear (Tustin) map, every corner frequency pre-warped
so that it lands exactly where it was asked for in the discrete controller
(Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed.,
sec. 6.3.1). ``delay_samples`` (default 1) adds the controller's own
computation delay: the output at sample k is computed from the measurements up
to k - 1, the usual timing of a digital motion controller, and the one the
shared example record was made with (its ``u - r`` is exactly 0 at k = 0 and
does not depend on ``y[k]``).

The controller implements :class:`controllers.protocol.Controller`: it maps the
control error ``e = r - y`` to the plant input ``u = K e`` (spec section 5).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.signal

from controllers.protocol import ControllerState
from workbench.core.errors import InputError

__all__ = ["PidChannel", "DecentralizedController", "ControllerState", "tune_pid"]


@dataclass(frozen=True)
class PidChannel:
    """One loop of the decentralized controller (continuous-time parameters).

    Parameters
    ----------
    kp : float
        Proportional gain, N/m (or N m/rad), at the lead's geometric centre.
    f_i_hz : float
        Integrator corner, Hz (0 = no integral action).
    f_lead_zero_hz, f_lead_pole_hz : float
        Lead zero and pole, Hz (equal = no lead).
    f_lp_hz : float
        Second-order low-pass corner, Hz (0 = none).
    lp_damping : float
        Damping ratio of the low-pass.
    notch_hz : float
        Notch centre, Hz (0 = none).
    notch_depth_damping, notch_width_damping : float
        Damping ratios of the notch's zeros and poles (depth = their ratio).
    """

    kp: float
    f_i_hz: float = 0.0
    f_lead_zero_hz: float = 1.0
    f_lead_pole_hz: float = 1.0
    f_lp_hz: float = 0.0
    lp_damping: float = 0.7
    notch_hz: float = 0.0
    notch_depth_damping: float = 0.01
    notch_width_damping: float = 0.3

    def __post_init__(self):
        for name in ("kp", "f_lead_zero_hz", "f_lead_pole_hz"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise InputError(f"{name}: expected a finite value > 0, got {v}")
        for name in ("f_i_hz", "f_lp_hz", "notch_hz", "lp_damping"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise InputError(f"{name}: expected a finite value >= 0, got {v}")

    def transfer_function(self, *, fs: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) polynomial coefficients in s of K_j(s), highest power first.

        With ``fs`` given, the corners are pre-warped for a Tustin map at ``fs``.
        """

        def w(f_hz: float) -> float:
            if fs is None:
                return 2 * np.pi * f_hz
            if f_hz >= fs / 2:
                raise InputError(
                    f"corner frequency {f_hz:g} Hz: expected below fs/2 = {fs / 2:g} Hz"
                )
            return 2 * fs * np.tan(np.pi * f_hz / fs)

        num = np.array([self.kp])
        den = np.array([1.0])
        if self.f_i_hz > 0:  # 1 + w_i/s = (s + w_i)/s
            num = np.polymul(num, [1.0, w(self.f_i_hz)])
            den = np.polymul(den, [1.0, 0.0])
        wz, wp = w(self.f_lead_zero_hz), w(self.f_lead_pole_hz)
        num = np.polymul(num, [1.0 / wz, 1.0])
        den = np.polymul(den, [1.0 / wp, 1.0])
        if self.f_lp_hz > 0:
            wl = w(self.f_lp_hz)
            num = np.polymul(num, [wl**2])
            den = np.polymul(den, [1.0, 2 * self.lp_damping * wl, wl**2])
        if self.notch_hz > 0:
            wn = w(self.notch_hz)
            num = np.polymul(num, [1.0, 2 * self.notch_depth_damping * wn, wn**2])
            den = np.polymul(den, [1.0, 2 * self.notch_width_damping * wn, wn**2])
        return num, den


@dataclass(frozen=True)
class DecentralizedController:
    """Diagonal (decentralized) discrete controller ``u = K(z) e``, e = r - y.

    Parameters
    ----------
    channels : tuple of PidChannel
        One loop per plant input (n_u).
    fs : float
        Sampling frequency, Hz.
    n_y : int
        Number of plant outputs the controller reads.
    sensor_index : tuple of int, optional
        Output that each input's loop feeds back (default: output j for input j).
    delay_samples : int
        Controller computation delay, samples (0 or more; default 1).

    Notes
    -----
    The discrete matrices (A, B, C, D) of the map e (n_y) -> u (n_u) are built
    once on construction; ``step`` is x+ = A x + B e, u = C x + D e. With the
    set point 0 of the experiments, e = -y.
    """

    channels: tuple[PidChannel, ...]
    fs: float
    n_y: int
    sensor_index: tuple[int, ...] = ()
    delay_samples: int = 1
    _abcd: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        channels = tuple(self.channels)
        if not channels or not all(isinstance(c, PidChannel) for c in channels):
            raise InputError("channels: expected a non-empty tuple of PidChannel")
        n_u = len(channels)
        idx = (
            tuple(range(n_u)) if not self.sensor_index else tuple(int(i) for i in self.sensor_index)
        )
        if len(idx) != n_u or any(not 0 <= i < self.n_y for i in idx):
            raise InputError(
                f"sensor_index: expected {n_u} output indices in [0, {self.n_y}), "
                f"got {self.sensor_index!r}"
            )
        if int(self.delay_samples) < 0:
            raise InputError(f"delay_samples: expected an integer >= 0, got {self.delay_samples}")
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "sensor_index", idx)
        object.__setattr__(self, "delay_samples", int(self.delay_samples))
        object.__setattr__(self, "fs", float(self.fs))
        blocks = [self._channel_ss(c) for c in channels]
        A = scipy.linalg.block_diag(*[b[0] for b in blocks])
        B = np.zeros((A.shape[0], self.n_y))
        C = scipy.linalg.block_diag(*[b[2] for b in blocks])
        D = np.zeros((n_u, self.n_y))
        row = 0
        for j, (a, b, _c, d) in enumerate(blocks):
            B[row : row + a.shape[0], idx[j]] = b[:, 0]
            D[j, idx[j]] = d[0, 0]
            row += a.shape[0]
        for M in (A, B, C, D):
            M.setflags(write=False)
        object.__setattr__(self, "_abcd", (A, B, C, D))

    def _channel_ss(self, ch: PidChannel):
        num, den = ch.transfer_function(fs=self.fs)
        numd, dend = scipy.signal.bilinear(num, den, fs=self.fs)  # polynomial Tustin map
        a, b, c, d = scipy.signal.tf2ss(numd, dend)
        a, b, c, d = (np.atleast_2d(np.asarray(m, float)) for m in (a, b, c, d))
        if a.size == 0:
            a, b, c = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0))
        for _ in range(self.delay_samples):  # q+ = c x + d e ; u = q
            n = a.shape[0]
            a = np.block([[a, np.zeros((n, 1))], [c, np.zeros((1, 1))]])
            b = np.vstack([b, d])
            c = np.hstack([np.zeros((1, n)), np.ones((1, 1))])
            d = np.zeros((1, 1))
        return a, b, c, d

    @property
    def n_u(self) -> int:
        return len(self.channels)

    @property
    def n_x(self) -> int:
        return self._abcd[0].shape[0]

    @property
    def linear(self) -> bool:
        """Always True: ``step`` is exactly :meth:`statespace`."""
        return True

    @property
    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Discrete (A, B, C, D) of e (n_y) -> u (n_u), read-only."""
        return self._abcd

    def statespace(self):
        """The controller as a discrete ``control.StateSpace`` (dt = 1/fs) from e to u."""
        import control

        A, B, C, D = self._abcd
        return control.ss(A, B, C, D, 1.0 / self.fs)

    def frf(self, freq_hz) -> np.ndarray:
        """Frequency response of e -> u, (n_f, n_u, n_y); the loop gain is G K."""
        from workbench.core import lti

        return lti.frf(self.statespace(), freq_hz)

    def init(self) -> ControllerState:
        """State at rest."""
        return ControllerState(np.zeros(self.n_x))

    def output(self, state: ControllerState) -> np.ndarray:
        """u[k] before e[k] is known; only for delay_samples >= 1 (then D = 0)."""
        if self.delay_samples < 1:
            raise InputError(
                "output: needs delay_samples >= 1 (a controller without direct feedthrough)"
            )
        return self._abcd[2] @ state.x

    def step(self, state: ControllerState, e: np.ndarray) -> tuple[np.ndarray, ControllerState]:
        """Controller output u[k] (n_u,) from e[k] = r[k] - y[k] (n_y,), and the next state."""
        A, B, C, D = self._abcd
        e = np.asarray(e, float)
        return C @ state.x + D @ e, ControllerState(A @ state.x + B @ e)


def tune_pid(
    mass,
    *,
    crossover_hz: float | np.ndarray,
    fs: float,
    n_y: int | None = None,
    sensor_index: tuple[int, ...] = (),
    lead_ratio: float = 3.0,
    integrator_ratio: float = 10.0,
    lowpass_ratio: float = 6.0,
    lp_damping: float = 0.7,
    notch_hz: np.ndarray | None = None,
    delay_samples: int = 1,
) -> DecentralizedController:
    """Tune a decentralized lead-lag PID per channel for a crossover on a rigid body.

    Parameters
    ----------
    mass : float or (n_u,) array
        Rigid-body mass (kg) or inertia (kg m^2) seen by each loop.
    crossover_hz : float or (n_u,) array
        Loop crossover per channel, Hz.
    fs : float
        Sampling frequency, Hz.
    n_y : int, optional
        Plant outputs (default n_u).
    sensor_index : tuple of int
        Output fed back by each input's loop (default the same index).
    lead_ratio : float
        Lead zero at fc / ratio, pole at fc * ratio (53 deg phase lead for 3).
    integrator_ratio : float
        Integrator corner at fc / ratio.
    lowpass_ratio : float
        Low-pass corner at fc * ratio (capped at 0.45 fs).
    lp_damping : float
    notch_hz : (n_u,) array, optional
        Notch centre per channel, Hz (0 or NaN = none).
    delay_samples : int
        Controller computation delay, samples.

    Returns
    -------
    DecentralizedController
        With ``|K_j(j w_c) / (m_j w_c^2)| = 1`` at each crossover (the
        controller's delay and the ZOH are left out of the gain, only shift
        the phase).
    """
    mass = np.atleast_1d(np.asarray(mass, float))
    fc = np.broadcast_to(np.asarray(crossover_hz, float), mass.shape)
    if np.any(~np.isfinite(mass) | (mass <= 0)):
        raise InputError(f"mass: expected masses/inertias > 0, got {mass}")
    if np.any(~np.isfinite(fc) | (fc <= 0) | (fc * lead_ratio >= fs / 2)):
        raise InputError(
            f"crossover_hz: expected 0 < fc and fc * lead_ratio < fs/2 = {fs / 2:g} Hz, got {fc}"
        )
    notch = np.zeros(mass.size) if notch_hz is None else np.nan_to_num(np.asarray(notch_hz, float))
    channels = []
    for j in range(mass.size):
        shape = PidChannel(
            kp=1.0,
            f_i_hz=fc[j] / integrator_ratio,
            f_lead_zero_hz=fc[j] / lead_ratio,
            f_lead_pole_hz=fc[j] * lead_ratio,
            f_lp_hz=min(fc[j] * lowpass_ratio, 0.45 * fs),
            lp_damping=lp_damping,
            notch_hz=float(notch[j]),
        )
        num, den = shape.transfer_function()
        s = 2j * np.pi * fc[j]
        gain = abs(np.polyval(num, s) / np.polyval(den, s))
        kp = mass[j] * (2 * np.pi * fc[j]) ** 2 / gain
        channels.append(
            PidChannel(
                kp=kp,
                f_i_hz=shape.f_i_hz,
                f_lead_zero_hz=shape.f_lead_zero_hz,
                f_lead_pole_hz=shape.f_lead_pole_hz,
                f_lp_hz=shape.f_lp_hz,
                lp_damping=lp_damping,
                notch_hz=shape.notch_hz,
            )
        )
    return DecentralizedController(
        channels=tuple(channels),
        fs=fs,
        n_y=mass.size if n_y is None else int(n_y),
        sensor_index=sensor_index,
        delay_samples=delay_samples,
    )
