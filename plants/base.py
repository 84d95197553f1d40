"""The plant contract, and a linear plant that every richer plant can build on."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol, runtime_checkable

import numpy as np

from workbench import sim
from workbench.compiled import SampledStep
from workbench.core import lti


@runtime_checkable
class Plant(Protocol):
    """What every simulator in ``plants`` offers.

    Sampling convention (spec 1a): ``u[k]`` is held over [k/fs, (k+1)/fs);
    ``y[k]`` is sampled at k/fs. All arrays are (N, n_channels), SI units.
    """

    fs: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]

    @property
    def n_u(self) -> int: ...

    @property
    def n_y(self) -> int: ...

    @property
    def delay_s(self) -> float: ...

    def linear_model(self): ...

    def frf(self, freq_hz) -> np.ndarray: ...

    def simulate(self, u: np.ndarray, *, rng: np.random.Generator) -> np.ndarray: ...

    def init(self, rng: np.random.Generator) -> Any: ...

    def step(self, state: Any, u_k: np.ndarray) -> tuple[np.ndarray, Any]: ...


@dataclass(frozen=True)
class LinearPlantState:
    """Explicit state of :class:`LinearPlant` for closed-loop stepping."""

    x: np.ndarray
    u_hist: np.ndarray  # (m + 2, n_u): u[k-1], ..., u[k-m-2] for the delay line
    rng: np.random.Generator


@dataclass(frozen=True)
class LinearPlant:
    """A continuous LTI plant behind a ZOH, with an input delay, noise and quantization.

    Parameters
    ----------
    sys : control.StateSpace
        Continuous-time true linear dynamics (dt = 0), input N, output m.
    fs : float
        Sampling frequency, Hz.
    delay_s : float
        Input delay (computation, amplifier), s.
    noise_std : float or (n_y,) array
        Standard deviation of white sensor noise, m.
    quantization : float
        Sensor resolution, m (0 = none).
    """

    sys: Any
    fs: float
    delay_s: float = 0.0
    noise_std: float | np.ndarray = 0.0
    quantization: float = 0.0
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        if not self.input_names:
            object.__setattr__(self, "input_names", tuple(self.sys.input_labels))
        if not self.output_names:
            object.__setattr__(self, "output_names", tuple(self.sys.output_labels))

    @property
    def n_u(self) -> int:
        return self.sys.ninputs

    @property
    def n_y(self) -> int:
        return self.sys.noutputs

    def linear_model(self):
        return self.sys

    def frf(self, freq_hz) -> np.ndarray:
        return lti.frf(self.sys, freq_hz, delay_s=self.delay_s)

    def _measure(self, y: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        noise = np.broadcast_to(np.asarray(self.noise_std, float), (y.shape[-1],))
        if np.any(noise > 0):
            y = y + rng.standard_normal(y.shape) * noise
        if self.quantization > 0:
            y = self.quantization * np.round(y / self.quantization)
        return y

    def simulate(self, u: np.ndarray, *, rng: np.random.Generator) -> np.ndarray:
        y = sim.simulate_zoh(self.sys, u, self.fs, delay_s=self.delay_s)
        return self._measure(y, rng)

    @cached_property
    def _discrete(self):
        A, B, C, D, _ = lti.as_matrices(self.sys)
        Ad, B0, B1, m = sim.c2d_zoh(A, B, 1.0 / self.fs, delay_s=self.delay_s)
        return Ad, B0, B1, m, C, D

    def init(self, rng: np.random.Generator) -> LinearPlantState:
        Ad, B0, B1, m, C, D = self._discrete
        return LinearPlantState(np.zeros(Ad.shape[0]), np.zeros((m + 2, self.n_u)), rng)

    def step(self, state: LinearPlantState, u_k: np.ndarray) -> tuple[np.ndarray, LinearPlantState]:
        """Output y[k] at k/fs, then advance the state with u[k] held over the sample."""
        Ad, B0, B1, m, C, D = self._discrete
        hist = np.vstack([np.asarray(u_k, float)[None, :], state.u_hist[:-1]])  # u[k], u[k-1], ...
        y = C @ state.x + D @ hist[m]
        y = self._measure(y[None, :], state.rng)[0]
        x_next = Ad @ state.x + B0 @ hist[m] + B1 @ hist[m + 1]
        return y, LinearPlantState(x_next, hist, state.rng)

    def sampled_step(self) -> SampledStep:
        """What :meth:`step` does, as matrices (compiled closed loop); no saturation."""
        Ad, B0, B1, m, C, D = self._discrete
        n_y = C.shape[0]
        return SampledStep(
            A=Ad,
            B0=B0,
            B1=B1,
            m=m,
            C=C,
            D=D,
            saturation=np.full(self.n_u, np.inf),
            raw_map=np.eye(n_y),
            decouple=np.eye(n_y),
            noise_std=np.broadcast_to(np.asarray(self.noise_std, float), (n_y,)),
            quantization=self.quantization,
        )
