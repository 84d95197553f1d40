"""Switchable physical effects of a plant: one frozen configuration shared by every plant.

Each field is one effect of the spec's vocabulary (shared/spec/data-format.md,
section 3), with its parameters in SI units. The default of every field is
"off", except the measurement chain (noise, quantization), which each plant
sets to its own nominal machine values.

Where each effect acts (the signal chain of every plant)::

    u ─► delay ─► saturation ─► actuator lag ─► input crosstalk ─► mechanics ─►
         output crosstalk ─► sensor lag ─► (+ noise, quantization on the raw sensors) ─► y

    mechanics = rigid-body modes (or suspension modes) + flexible modes (with
                frequency/damping errors) + extra modes + residual (high) modes,
                with friction and a cubic spring acting at the input ports.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.core.errors import InputError, describe

__all__ = ["ExtraMode", "Effects", "as_channel_vector"]


def _tuple(value, name: str) -> tuple[float, ...]:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.ndim != 1 or not np.all(np.isfinite(arr) | np.isinf(arr)):
        raise InputError(f"{name}: expected a number or a 1-D sequence, got {describe(value)}")
    return tuple(float(v) for v in arr)


def as_channel_vector(value, n: int, name: str) -> np.ndarray:
    """Broadcast a scalar or a length-``n`` sequence to an (n,) float array.

    Raises
    ------
    InputError
        If ``value`` has neither one element nor ``n``.
    """
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.size == 1:
        return np.full(n, float(arr[0]))
    if arr.shape != (n,):
        raise InputError(f"{name}: expected a scalar or {n} values, got {describe(value)}")
    return arr.copy()


@dataclass(frozen=True)
class ExtraMode:
    """A flexible mode that the nominal machine does not have (a "missing mode").

    Parameters
    ----------
    freq_hz : float
        Undamped natural frequency, Hz (> 0).
    damping : float
        Modal damping ratio, - (>= 0).
    b : (n_u,) sequence
        Input participation of the mass-normalized mode: the modal force per
        unit of each plant input, 1/sqrt(kg) (per N) or rad-based analogue.
    c : (n_y,) sequence
        Output participation: each plant output per unit modal displacement,
        m/sqrt(kg)-normalized so that the mode contributes
        ``c b^T / (s^2 + 2 damping w s + w^2)`` to G(s).
    """

    freq_hz: float
    damping: float
    b: tuple[float, ...]
    c: tuple[float, ...]

    def __post_init__(self):
        if not (np.isfinite(self.freq_hz) and self.freq_hz > 0):
            raise InputError(
                f"ExtraMode.freq_hz: expected a positive frequency in Hz, got {self.freq_hz!r}"
            )
        if not (np.isfinite(self.damping) and self.damping >= 0):
            raise InputError(f"ExtraMode.damping: expected a ratio >= 0, got {self.damping!r}")
        object.__setattr__(self, "b", _tuple(self.b, "ExtraMode.b"))
        object.__setattr__(self, "c", _tuple(self.c, "ExtraMode.c"))


def _matrix_or_none(value, name: str):
    if value is None:
        return None
    arr = np.array(value, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected a square finite matrix or None, got {describe(value)}")
    arr.setflags(write=False)
    return arr


def _optional_tuple(value, name: str):
    return None if value is None else _tuple(value, name)


@dataclass(frozen=True)
class Effects:
    """The physical effects of a plant, each a parameterized switch.

    Parameters
    ----------
    delay_s : float
        Input time delay (computation delay, amplifier latency), s. 0 = off.
    extra_modes : tuple of ExtraMode
        Modes present in the machine but not in its nominal description. () = off.
    mode_freq_error : None or sequence
        Relative error of each nominal flexible mode's frequency (0.03 = the true
        mode is 3 % higher), one value per flexible mode or one for all. None = off.
    mode_damping_error : None or sequence
        Relative error of each flexible mode's damping ratio (-0.5 = half the
        damping), one per flexible mode or one for all. None = off.
    residual_max_hz : float
        Include the plant's own structural modes above the Nyquist frequency up
        to this frequency, Hz: their static part is the residual compliance of
        truncated modes. 0 = off.
    actuator_cutoff_hz : None or float or (n_u,) sequence
        First-order lag 1/(1 + s/w_c) on each plant input (amplifier, coil
        inductance), Hz; ``inf`` for an input without lag. None = off.
    sensor_cutoff_hz : None or float or (n_y,) sequence
        First-order low-pass on each plant output, Hz; ``inf`` = none. None = off.
    suspension_freq_hz : None or float or (n_rigid,) sequence
        A parasitic spring to the world (cable slab, flexures): every
        rigid-body mode becomes a suspension mode at this frequency, Hz. None = off.
    suspension_damping : float
        Damping ratio of the suspension modes, -.
    crosstalk_input : None or (n_u, n_u) array
        Static coupling at the inputs (misaligned actuators): the mechanics is
        driven by (I + crosstalk_input) u. None = off.
    crosstalk_output : None or (n_y, n_y) array
        Static coupling at the outputs (misaligned sensors): the plant
        measures (I + crosstalk_output) y. None = off.
    friction_force : None or float or (n_u,) sequence
        Coulomb friction at each input port (collocated with the input), N
        (N m for a rotational input). Smooth: F = -friction_force tanh(v / friction_velocity).
        None = off.
    friction_velocity : float
        Velocity scale of the smooth Coulomb friction, m/s (rad/s).
    cubic_stiffness : None or float or (n_u,) sequence
        Hardening spring at each input port, F = -k3 d^3, N/m^3 (N m/rad^3). None = off.
    saturation : None or float or (n_u,) sequence
        Symmetric saturation of each (delayed) input command, N (N m). None = off.
    noise_std : None or float or (n_raw,) sequence
        Standard deviation of white noise on each raw sensor, m. None = the
        plant's nominal value; 0 = no noise.
    quantization : None or float
        Resolution of the raw sensors, m. None = the plant's nominal value; 0 = none.
    substeps : None or int
        Substeps per sample of the nonlinear simulation (friction, cubic spring).
        None = automatic, from the friction law: the fewest with
        h F_c mobility / v0 <= 1/64 (h the substep, s; mobility the port's
        driving-point velocity per unit force and second, 1/kg), 32..128, and 8
        without friction (``plants.sim`` says why). An integer >= 1 overrides it.

    Notes
    -----
    An effect that a plant cannot have (a suspension for a plant without
    rigid-body modes) is refused when the plant is built.
    """

    delay_s: float = 0.0
    extra_modes: tuple[ExtraMode, ...] = ()
    mode_freq_error: tuple[float, ...] | None = None
    mode_damping_error: tuple[float, ...] | None = None
    residual_max_hz: float = 0.0
    actuator_cutoff_hz: tuple[float, ...] | None = None
    sensor_cutoff_hz: tuple[float, ...] | None = None
    suspension_freq_hz: tuple[float, ...] | None = None
    suspension_damping: float = 0.02
    crosstalk_input: np.ndarray | None = field(default=None, compare=False)
    crosstalk_output: np.ndarray | None = field(default=None, compare=False)
    friction_force: tuple[float, ...] | None = None
    friction_velocity: float = 1e-4
    cubic_stiffness: tuple[float, ...] | None = None
    saturation: tuple[float, ...] | None = None
    noise_std: tuple[float, ...] | None = None
    quantization: float | None = None
    substeps: int | None = None

    def __post_init__(self):
        if not (np.isfinite(self.delay_s) and self.delay_s >= 0):
            raise InputError(f"Effects.delay_s: expected a delay >= 0 in s, got {self.delay_s!r}")
        modes = tuple(
            ExtraMode(**m) if isinstance(m, dict) else m for m in self.extra_modes
        )  # scenario files give modes as mappings
        for m in modes:
            if not isinstance(m, ExtraMode):
                raise InputError(
                    f"Effects.extra_modes: expected ExtraMode items, got {describe(m)}"
                )
        object.__setattr__(self, "extra_modes", modes)
        for name in (
            "mode_freq_error",
            "mode_damping_error",
            "actuator_cutoff_hz",
            "sensor_cutoff_hz",
            "suspension_freq_hz",
            "friction_force",
            "cubic_stiffness",
            "saturation",
            "noise_std",
        ):
            object.__setattr__(self, name, _optional_tuple(getattr(self, name), f"Effects.{name}"))
        for name in ("actuator_cutoff_hz", "sensor_cutoff_hz", "saturation"):
            v = getattr(self, name)
            if v is not None and any(x <= 0 for x in v):
                raise InputError(f"Effects.{name}: expected values > 0 (inf = none), got {v!r}")
        for name in ("friction_force", "cubic_stiffness", "noise_std"):
            v = getattr(self, name)
            if v is not None and any(not (np.isfinite(x) and x >= 0) for x in v):
                raise InputError(f"Effects.{name}: expected finite values >= 0, got {v!r}")
        if self.mode_freq_error is not None and any(x <= -1 for x in self.mode_freq_error):
            raise InputError(
                "Effects.mode_freq_error: expected relative errors > -1, "
                f"got {self.mode_freq_error!r}"
            )
        if self.mode_damping_error is not None and any(x < -1 for x in self.mode_damping_error):
            raise InputError(
                "Effects.mode_damping_error: expected relative errors >= -1, "
                f"got {self.mode_damping_error!r}"
            )
        if self.suspension_freq_hz is not None and any(
            not (np.isfinite(x) and x > 0) for x in self.suspension_freq_hz
        ):
            raise InputError(
                "Effects.suspension_freq_hz: expected frequencies > 0 in Hz, "
                f"got {self.suspension_freq_hz!r}"
            )
        if not (self.suspension_damping >= 0):
            raise InputError(
                f"Effects.suspension_damping: expected >= 0, got {self.suspension_damping!r}"
            )
        if not (self.residual_max_hz >= 0):
            raise InputError(
                f"Effects.residual_max_hz: expected >= 0 Hz, got {self.residual_max_hz!r}"
            )
        if not (np.isfinite(self.friction_velocity) and self.friction_velocity > 0):
            raise InputError(
                "Effects.friction_velocity: expected a velocity > 0 in m/s, "
                f"got {self.friction_velocity!r}"
            )
        if self.quantization is not None and not (
            np.isfinite(self.quantization) and self.quantization >= 0
        ):
            raise InputError(
                f"Effects.quantization: expected a resolution >= 0 in m, got {self.quantization!r}"
            )
        if self.substeps is not None:
            n = self.substeps
            integral = isinstance(n, (int, np.integer)) or (
                isinstance(n, (float, np.floating)) and float(n).is_integer()
            )
            if isinstance(n, (bool, np.bool_)) or not integral or n < 1:
                raise InputError(
                    f"Effects.substeps: expected None (automatic) or an integer >= 1, got {n!r}"
                )
            object.__setattr__(self, "substeps", int(n))
        object.__setattr__(
            self,
            "crosstalk_input",
            _matrix_or_none(self.crosstalk_input, "Effects.crosstalk_input"),
        )
        object.__setattr__(
            self,
            "crosstalk_output",
            _matrix_or_none(self.crosstalk_output, "Effects.crosstalk_output"),
        )

    @property
    def is_nonlinear(self) -> bool:
        """True when friction, a cubic spring or saturation is switched on."""
        return any(
            v is not None and any(x > 0 and np.isfinite(x) for x in v)
            for v in (self.friction_force, self.cubic_stiffness)
        ) or (self.saturation is not None and any(np.isfinite(x) for x in self.saturation))
