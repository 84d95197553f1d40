"""The controller contract that the closed-loop simulator accepts, and a state-space controller.

Every controller is an immutable design with explicit state (the verbs shared
with plants and observers)::

    state = K.init()                  # state at rest
    u, state = K.step(state, e)       # one sample: e = r - y (n_y,) -> u (n_u,)
    K.statespace()                    # the discrete python-control StateSpace e -> u, dt = 1/fs

``linear`` says whether ``step`` is exactly ``statespace()`` (no constraints,
no nonlinearity); only then may :func:`workbench.sim.closed_loop` run the loop
as one LTI system. A controller without direct feedthrough also offers
``output(state)`` (u[k] before e[k] is known), which lets the simulator step a
loop without a computation delay of its own (:class:`StrictlyProper`).

Sign convention (spec section 5): the controller maps the control error
``e = r - y`` to the plant input ``u = K e``; the loop gain is ``L = G K``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from workbench.core.errors import InputError

__all__ = ["Controller", "StrictlyProper", "ControllerState", "StateSpaceController"]


@runtime_checkable
class Controller(Protocol):
    """What every controller offers to the closed-loop simulator.

    Attributes
    ----------
    n_u : int
        Outputs (plant inputs).
    n_y : int
        Inputs (control errors, one per measured output).
    fs : float
        Sampling frequency, Hz.
    linear : bool
        True when ``step`` equals ``statespace()`` exactly.
    """

    @property
    def n_u(self) -> int: ...

    @property
    def n_y(self) -> int: ...

    @property
    def fs(self) -> float: ...

    @property
    def linear(self) -> bool: ...

    def init(self) -> Any:
        """State at rest."""

    def step(self, state: Any, e: np.ndarray) -> tuple[np.ndarray, Any]:
        """u[k] (n_u,) from e[k] = r[k] - y[k] (n_y,), and the next state."""

    def statespace(self):
        """The discrete ``control.StateSpace`` e -> u, dt = 1/fs (a linearization if not linear)."""


@runtime_checkable
class StrictlyProper(Protocol):
    """A controller whose u[k] does not depend on e[k]: ``output(state)`` gives it first."""

    def output(self, state: Any) -> np.ndarray: ...


@dataclass(frozen=True)
class ControllerState:
    """Explicit controller state: x (n_x,)."""

    x: np.ndarray


def _readonly(a, name: str) -> np.ndarray:
    a = np.array(a, float, ndmin=2)
    if a.ndim != 2 or not np.all(np.isfinite(a)):
        raise InputError(f"{name}: expected a finite 2-D matrix, got shape {a.shape}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class StateSpaceController:
    """Any discrete linear controller e -> u: x+ = A x + B e, u = C x + D e.

    Parameters
    ----------
    A, B, C, D : arrays (n_x, n_x), (n_x, n_y), (n_u, n_x), (n_u, n_y)
    fs : float
        Sampling frequency, Hz (dt = 1/fs).
    input_names : tuple of str
        Named after the measured outputs (spec 5).
    output_names : tuple of str
        Named after the plant inputs.
    delay_samples : int
        The computation delay the design assumed (spec 5, informational: the
        loop's delay is the simulator's ``delay_samples``, not in A, B, C, D).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    fs: float
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())
    delay_samples: int = 0

    def __post_init__(self):
        A, B, C, D = (_readonly(getattr(self, k), k) for k in "ABCD")
        n = A.shape[0]
        if n == 0:  # a static gain: keep consistent empty shapes
            A = _empty(0, 0)
            B = _empty(0, D.shape[1])
            C = _empty(D.shape[0], 0)
        if (
            A.shape != (n, n)
            or B.shape[0] != n
            or C.shape[1] != n
            or D.shape
            != (
                C.shape[0],
                B.shape[1],
            )
        ):
            raise InputError(
                "A, B, C, D: expected shapes (n, n), (n, n_y), (n_u, n), (n_u, n_y), got "
                f"{A.shape}, {B.shape}, {C.shape}, {D.shape}"
            )
        fs = float(self.fs)
        if not np.isfinite(fs) or fs <= 0:
            raise InputError(f"fs: expected a sampling frequency > 0 Hz, got {self.fs}")
        if int(self.delay_samples) != self.delay_samples or self.delay_samples < 0:
            raise InputError(f"delay_samples: expected an integer >= 0, got {self.delay_samples}")
        for k, v in zip("ABCD", (A, B, C, D)):
            object.__setattr__(self, k, v)
        object.__setattr__(self, "fs", fs)
        object.__setattr__(self, "delay_samples", int(self.delay_samples))
        object.__setattr__(self, "input_names", tuple(self.input_names))
        object.__setattr__(self, "output_names", tuple(self.output_names))

    # -- alternates -------------------------------------------------------------------
    @classmethod
    def from_statespace(cls, sys, *, delay_samples: int = 0) -> StateSpaceController:
        """From a discrete ``control.StateSpace`` (or LTIModel without delay) e -> u."""
        from workbench.core.lti import as_matrices

        A, B, C, D, dt = as_matrices(sys)
        if dt <= 0:
            raise InputError(f"controller: expected a discrete model (dt > 0), got dt = {dt:g}")
        if float(getattr(sys, "delay_s", 0.0)):
            raise InputError(
                "controller: expected no delay_s in the controller (the loop delay belongs to "
                "the plant / the simulator's delay_samples)"
            )
        names = {}
        for key, attr in (("input_names", "input_labels"), ("output_names", "output_labels")):
            if hasattr(sys, key):
                names[key] = tuple(getattr(sys, key))
            elif hasattr(sys, attr):
                names[key] = tuple(getattr(sys, attr))
        return cls(A, B, C, D, fs=1.0 / dt, delay_samples=delay_samples, **names)

    @classmethod
    def from_arrays(cls, arrays: dict, src: str = "controller") -> StateSpaceController:
        """From the arrays of a spec-5 controller file (``role = "controller"``)."""
        from workbench.io.formats import lti_model_from_arrays

        role = arrays.get("role")
        if role is None or str(np.asarray(role)) != "controller":
            raise InputError(f"{src}: key 'role': expected 'controller', got {role!r}")
        if "Br" in arrays or "Dr" in arrays:
            raise InputError(
                f"{src}: keys 'Br', 'Dr': two-degree-of-freedom controllers are not simulated yet"
            )
        delay = arrays.get("delay_samples")
        delay_samples = 0 if delay is None else int(np.asarray(delay).item())
        model = lti_model_from_arrays(arrays, src)
        return cls.from_statespace(model, delay_samples=delay_samples)

    @classmethod
    def read(cls, path) -> StateSpaceController:
        """Read a spec-5 controller file."""
        from workbench.io.formats import read_npz

        return cls.from_arrays(read_npz(path), src=str(path))

    # -- the protocol -----------------------------------------------------------------
    @property
    def n_u(self) -> int:
        return self.D.shape[0]

    @property
    def n_y(self) -> int:
        return self.D.shape[1]

    @property
    def n_x(self) -> int:
        return self.A.shape[0]

    @property
    def linear(self) -> bool:
        return True

    def statespace(self):
        """The discrete ``control.StateSpace`` e -> u (dt = 1/fs)."""
        import control

        kw = {}
        if self.input_names:
            kw["inputs"] = list(self.input_names)
        if self.output_names:
            kw["outputs"] = list(self.output_names)
        return control.ss(self.A, self.B, self.C, self.D, 1.0 / self.fs, **kw)

    def init(self) -> ControllerState:
        """State at rest."""
        return ControllerState(np.zeros(self.n_x))

    def output(self, state: ControllerState) -> np.ndarray:
        """u[k] before e[k] is known; only without direct feedthrough (D = 0)."""
        if np.any(self.D):
            raise InputError("output: needs a controller without direct feedthrough (D = 0)")
        return self.C @ state.x

    def step(self, state: ControllerState, e: np.ndarray) -> tuple[np.ndarray, ControllerState]:
        """u[k] (n_u,) from e[k] (n_y,), and the next state."""
        e = np.asarray(e, float)
        return self.C @ state.x + self.D @ e, ControllerState(self.A @ state.x + self.B @ e)


def _empty(r: int, c: int) -> np.ndarray:
    a = np.zeros((r, c))
    a.setflags(write=False)
    return a
