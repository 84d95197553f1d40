"""A mechanical plant: modal mechanics, effects, and a measurement chain, behind a ZOH.

:class:`MechanicalPlant` implements the :class:`plants.base.Plant` contract for
every plant built from modes (the wafer stage, the beam). Data flow::

    u (N, n_u) ─► delay ─► saturation ─► [LinearChain: actuator lag, input crosstalk,
        modes + port nonlinearities, output crosstalk, sensor lag] ─► y_lin (N, n_y)
    y_lin ─► raw sensors: y_raw = raw_map y_lin + noise, quantized ─► y = decouple y_raw

The raw sensors are the physical ones (the stage's 9 interferometer axes, the
beam's 5 probes): noise and quantization act there; ``decouple`` is the static
sensor-to-output matrix of the machine (decouple @ raw_map = I).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import control
import numpy as np

from workbench.compiled import SampledStep
from workbench.core.errors import InputError, describe

from .effects import Effects, as_channel_vector
from .modal import LinearChain, ModalSet, apply_modal_effects
from .sim import DiscreteChain

__all__ = ["MechanicalPlant", "MechanicalPlantState"]


@dataclass(frozen=True)
class MechanicalPlantState:
    """Explicit state for closed-loop stepping.

    Parameters
    ----------
    x : (n_x,) array
        State of the continuous chain at the current sample instant.
    u_hist : (m + 2, n_u) array
        Past inputs u[k-1], u[k-2], ..., for the delay line.
    rng : numpy.random.Generator
        Source of the measurement noise.
    """

    x: np.ndarray
    u_hist: np.ndarray
    rng: np.random.Generator


@dataclass(frozen=True, eq=False)
class MechanicalPlant:
    """A plant made of modes, effects and a measurement chain.

    Parameters
    ----------
    name : str
        Registry name ('wafer_stage', 'beam').
    fs : float
        Sampling frequency, Hz.
    input_names, output_names : tuple of str
        Channel names, lengths n_u and n_y.
    nominal_modes : ModalSet
        Rigid-body (or suspension) and flexible modes of the nominal machine.
    residual_modes : ModalSet or None
        The machine's structural modes above Nyquist (switched on by
        ``Effects.residual_max_hz``).
    effects : Effects
        The physical effects switched on.
    raw_map : (n_raw, n_y) array
        Raw sensor readings per output-coordinate displacement (noise-free).
    decouple : (n_y, n_raw) array
        The machine's static raw-sensor-to-output matrix.
    noise_std : (n_raw,) array
        Nominal white noise on each raw sensor, m (used when Effects.noise_std is None).
    quantization : float
        Nominal raw sensor resolution, m (used when Effects.quantization is None).
    inherent_modes : ModalSet or None
        Modes that the machine always has but its nominal description does not
        (the beam's in-plane modes seen by a tilted sensor); kind 'extra'.
    """

    name: str
    fs: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    nominal_modes: ModalSet
    residual_modes: ModalSet | None
    effects: Effects
    raw_map: np.ndarray
    decouple: np.ndarray
    noise_std: np.ndarray
    quantization: float
    inherent_modes: ModalSet | None = None

    def __post_init__(self):
        if not (np.isfinite(self.fs) and self.fs > 0):
            raise InputError(f"MechanicalPlant.fs: expected a frequency > 0 in Hz, got {self.fs!r}")
        if not isinstance(self.effects, Effects):
            raise InputError(
                f"MechanicalPlant.effects: expected Effects, got {describe(self.effects)}"
            )
        n_u, n_y = self.nominal_modes.n_u, self.nominal_modes.n_y
        if len(self.input_names) != n_u or len(self.output_names) != n_y:
            raise InputError(
                f"MechanicalPlant: expected {n_u} input and {n_y} output names, "
                f"got {len(self.input_names)} and {len(self.output_names)}"
            )
        M = np.array(self.raw_map, float)
        T = np.array(self.decouple, float)
        if M.ndim != 2 or M.shape[1] != n_y or T.shape != (n_y, M.shape[0]):
            raise InputError(
                f"MechanicalPlant: raw_map must be (n_raw, {n_y}) and decouple ({n_y}, n_raw), "
                f"got {M.shape} and {T.shape}"
            )
        for a in (M, T):
            a.setflags(write=False)
        object.__setattr__(self, "raw_map", M)
        object.__setattr__(self, "decouple", T)
        noise = as_channel_vector(self.noise_std, M.shape[0], "MechanicalPlant.noise_std")
        noise.setflags(write=False)
        object.__setattr__(self, "noise_std", noise)
        # build eagerly so that a bad effect is refused here, not at first use
        _ = self.chain.matrices

    # -- the contract ----------------------------------------------------------------------
    @property
    def n_u(self) -> int:
        return self.nominal_modes.n_u

    @property
    def n_y(self) -> int:
        return self.nominal_modes.n_y

    @property
    def delay_s(self) -> float:
        return float(self.effects.delay_s)

    @property
    def n_raw(self) -> int:
        return self.raw_map.shape[0]

    @cached_property
    def modes(self) -> ModalSet:
        """The true modes (nominal modes changed by the effects, plus inherent ones)."""
        modes = apply_modal_effects(
            self.nominal_modes, self.residual_modes, self.effects, n_u=self.n_u, n_y=self.n_y
        )
        if self.inherent_modes is not None and self.inherent_modes.n_modes:
            inh = self.inherent_modes
            keep = inh.freq_hz <= max(self.fs / 2, self.effects.residual_max_hz)
            modes = modes.concat(inh.select(keep))
        return modes

    @cached_property
    def chain(self) -> LinearChain:
        return LinearChain(self.modes, self.effects)

    @cached_property
    def discrete(self) -> DiscreteChain:
        return DiscreteChain(self.chain, self.fs, self.delay_s)

    def linear_model(self) -> control.StateSpace:
        """True linear part, continuous, without the delay: a ``control.StateSpace`` (N -> m)."""
        return chain_statespace(self.chain, self.input_names, self.output_names)

    def frf(self, freq_hz) -> np.ndarray:
        """True linear frequency response with the delay, (n_f, n_y, n_u), at ``freq_hz`` (Hz)."""
        return self.chain.frf(freq_hz, delay_s=self.delay_s)

    def nominal_model(self) -> control.StateSpace:
        """The model an engineer has: nominal modes only, no effects, continuous, no delay."""
        return chain_statespace(
            LinearChain(self.nominal_modes), self.input_names, self.output_names
        )

    def nominal_modal_model(self):
        """The nominal modes as a :class:`workbench.modal.model.ModalModel`."""
        return self.nominal_modes.to_modal(
            input_names=self.input_names, output_names=self.output_names
        )

    def with_effects(self, **changes: Any) -> MechanicalPlant:
        """The same machine with some effect fields changed (``Effects`` field names)."""
        return dataclasses.replace(self, effects=replace_effects(self.effects, changes))

    # -- measurement -------------------------------------------------------------------------
    @property
    def measurement_noise_std(self) -> np.ndarray:
        """Noise std of each raw sensor in force, (n_raw,), m."""
        if self.effects.noise_std is None:
            return np.array(self.noise_std)
        return as_channel_vector(self.effects.noise_std, self.n_raw, "Effects.noise_std")

    @property
    def measurement_quantization(self) -> float:
        """Raw sensor resolution in force, m (0 = none)."""
        q = self.effects.quantization
        return float(self.quantization if q is None else q)

    @cached_property
    def _identity_sensors(self) -> bool:
        return self.raw_map.shape[0] == self.n_y and bool(
            np.array_equal(self.raw_map, np.eye(self.n_y))
            and np.array_equal(self.decouple, np.eye(self.n_y))
        )

    def measure(self, y_lin: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured outputs (N, n_y) from noise-free outputs ``y_lin`` (N, n_y).

        Noise and quantization act on the raw sensors, then the decoupling.
        """
        y_lin = np.asarray(y_lin, float)
        raw = y_lin if self._identity_sensors else y_lin @ self.raw_map.T
        std = self.measurement_noise_std
        if np.any(std > 0):
            raw = raw + rng.standard_normal(raw.shape) * std
        q = self.measurement_quantization
        if q > 0:
            raw = q * np.round(raw / q)
        return raw if self._identity_sensors else raw @ self.decouple.T

    def _check_u(self, u) -> np.ndarray:
        u = np.asarray(u, float)
        if u.ndim != 2 or u.shape[1] != self.n_u or not np.all(np.isfinite(u)):
            raise InputError(f"u: expected a finite (N, {self.n_u}) array, got {describe(u)}")
        return u

    @staticmethod
    def _check_rng(rng) -> np.random.Generator:
        if not isinstance(rng, np.random.Generator):
            raise InputError(f"rng: expected a numpy.random.Generator, got {describe(rng)}")
        return rng

    def simulate(self, u: np.ndarray, *, rng: np.random.Generator) -> np.ndarray:
        """Open-loop response from rest, with every effect, noise and quantization.

        Parameters
        ----------
        u : (N, n_u) array
            Input samples (N or N m), held over each sample interval.
        rng : numpy.random.Generator
            Source of the measurement noise.

        Returns
        -------
        (N, n_y) array
            y[k] sampled at k / fs (m or rad).
        """
        u = self._check_u(u)
        rng = self._check_rng(rng)
        return self.measure(self.discrete.simulate(u), rng)

    def simulate_noise_free(self, u: np.ndarray) -> np.ndarray:
        """As :meth:`simulate`, without noise and quantization."""
        return self.discrete.simulate(self._check_u(u))

    # -- closed loop ---------------------------------------------------------------------------
    def init(self, rng: np.random.Generator) -> MechanicalPlantState:
        """Rest state for :meth:`step`."""
        rng = self._check_rng(rng)
        m = self.discrete.zoh[3]
        return MechanicalPlantState(np.zeros(self.chain.n_x), np.zeros((m + 2, self.n_u)), rng)

    def step(
        self, state: MechanicalPlantState, u_k: np.ndarray
    ) -> tuple[np.ndarray, MechanicalPlantState]:
        """Measured y[k] at k / fs, then advance with u[k] held over [k/fs, (k+1)/fs).

        Parameters
        ----------
        state : MechanicalPlantState
        u_k : (n_u,) array
            Input for this sample, N (N m).

        Returns
        -------
        y_k : (n_y,) array
        state : MechanicalPlantState
        """
        d = self.discrete
        Ad, B0, B1, m = d.zoh
        u_k = np.asarray(u_k, float).reshape(self.n_u)
        hist = np.vstack([u_k[None, :], state.u_hist[:-1]])  # u[k], u[k-1], ...
        y = self.chain.matrices["C"] @ state.x
        y = self.measure(y[None, :], state.rng)[0]
        if d.nonlinear:
            x_next = d.advance_nonlinear(state.x, d.saturate(hist[m]), d.saturate(hist[m + 1]))
        else:
            x_next = Ad @ state.x + B0 @ d.saturate(hist[m]) + B1 @ d.saturate(hist[m + 1])
        return y, MechanicalPlantState(x_next, hist, state.rng)

    def sampled_step(self) -> SampledStep | None:
        """What :meth:`step` does, as matrices and static nonlinearities (compiled closed loop).

        None when a port force (friction, cubic spring) needs the substep loop.
        """
        d = self.discrete
        if d.nonlinear:
            return None
        Ad, B0, B1, m = d.zoh
        C = self.chain.matrices["C"]
        return SampledStep(
            A=Ad,
            B0=B0,
            B1=B1,
            m=m,
            C=C,
            D=np.zeros((C.shape[0], self.n_u)),  # step() reads y = C x
            saturation=d.saturation,
            raw_map=self.raw_map,
            decouple=self.decouple,
            noise_std=self.measurement_noise_std,
            quantization=self.measurement_quantization,
        )


def check_field_names(cls, fields: dict[str, Any], label: str) -> None:
    """Refuse (:class:`InputError`, one line) names in ``fields`` that are not fields of ``cls``.

    ``label`` names the configuration in the message (``"effects"``, ``"StageConfig"``).
    """
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(fields) - names)
    if unknown:
        raise InputError(
            f"{label}: unknown field(s) {unknown}; expected names from {sorted(names)}"
        )


def replace_effects(base: Effects, changes: dict[str, Any]) -> Effects:
    """``base`` with the named fields changed; an unknown name is an :class:`InputError`."""
    check_field_names(Effects, changes, "effects")
    return dataclasses.replace(base, **changes)


def chain_statespace(chain: LinearChain, input_names, output_names) -> control.StateSpace:
    """A linear chain's matrices as a continuous ``control.StateSpace`` with channel names."""
    m = chain.matrices
    return control.ss(
        m["A"],
        m["B"],
        m["C"],
        m["D"],
        inputs=list(input_names),
        outputs=list(output_names),
    )
