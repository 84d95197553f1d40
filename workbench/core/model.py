"""The one linear time-invariant model type of the workbench: :class:`LTIModel`.

A frozen state-space model with its exact input delay and channel names::

    y = C x + D u(t - delay_s),   x' = A x + B u(t - delay_s)   (dt = 0, continuous)
    x[k+1] = A x[k] + B u(k dt - delay_s), y[k] = C x[k] + D u(k dt - delay_s)   (dt > 0)

Conversions, all in this module or one call away:

- python-control ``StateSpace``: :meth:`LTIModel.from_statespace`,
  :meth:`LTIModel.to_statespace` (a ``StateSpace`` cannot hold a delay: it is
  realized as Pade states, or as shift states for a discrete model, only on
  request, ``pade_order=``; otherwise a model with a delay is refused);
- spec model file (``shared/spec/data-format.md`` section 2, plus the
  workbench's ``delay_s`` key, kept exact): :meth:`LTIModel.read`,
  :meth:`LTIModel.write`, through :mod:`workbench.io.formats` (the one reader);
- anything that names a model (``LTIModel``, ``StateSpace``, path):
  :func:`as_model`.

The delay is one scalar for every input, s: the spec's ``delay_s`` (a model
file key and the ``time_delay`` finding's parameter) is a scalar.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from workbench.core.arrays import readonly
from workbench.core.errors import InputError, describe

__all__ = [
    "LTIModel",
    "as_model",
    "pole_summary",
    "dc_gain",
    "pade_delay",
    "pade_order",
    "with_pade",
]

_SRC = "model"


def _matrix(value, key: str) -> np.ndarray:
    from workbench.io.formats import _array, _real

    a = _array(value, _SRC, key)
    if a.ndim != 2:
        raise InputError(f"{_SRC}: key '{key}': expected a 2-D matrix, got {describe(a)}")
    return _real(a, _SRC, key)


def _nonneg_scalar(value, key: str, expected: str) -> float:
    a = np.asarray(value)
    if (
        a.size != 1
        or a.ndim > 1
        or a.dtype.hasobject
        or np.iscomplexobj(a)
        or not (np.issubdtype(a.dtype, np.number) or a.dtype == bool)
    ):
        raise InputError(f"{_SRC}: key '{key}': expected a real scalar, got {describe(a)}")
    v = float(a.reshape(()))
    if not np.isfinite(v) or v < 0:
        raise InputError(f"{_SRC}: key '{key}': expected {expected}, got {v:g}")
    return v


@dataclass(frozen=True, eq=False)  # == of array fields is ambiguous: identity equality
class LTIModel:
    """A linear time-invariant state-space model with an exact input delay.

    Parameters
    ----------
    A : (n_x, n_x) array
        State matrix (1/s continuous; dimensionless discrete).
    B : (n_x, n_u) array
    C : (n_y, n_x) array
    D : (n_y, n_u) array
        Input and output matrices, SI units of the channels (m, N, ...).
    dt : float
        0.0 for continuous time, else the sample time, s.
    delay_s : float
        Input delay on every input, s, exact (exp(-s delay_s)); >= 0.
    input_names, output_names, state_names : tuple of str
        Channel names; empty means ``u0, u1, ...``, ``y0, ...``, ``x0, ...``.

    All arrays are stored as read-only float copies. Invalid values raise a
    one-line :class:`~workbench.core.errors.InputError` naming the key.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float = 0.0
    delay_s: float = 0.0
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())
    state_names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        from workbench.io.formats import _names

        A, B, C, D = (_matrix(getattr(self, k), k) for k in "ABCD")
        n = A.shape[0]
        if A.shape != (n, n):
            raise InputError(f"{_SRC}: key 'A': expected a square matrix, got shape {A.shape}")
        if B.shape[0] != n:
            raise InputError(
                f"{_SRC}: key 'B': expected {n} rows to match A {A.shape}, got shape {B.shape}"
            )
        if C.shape[1] != n:
            raise InputError(
                f"{_SRC}: key 'C': expected {n} columns to match A {A.shape}, got shape {C.shape}"
            )
        if D.shape != (C.shape[0], B.shape[1]):
            raise InputError(
                f"{_SRC}: key 'D': expected shape {(C.shape[0], B.shape[1])} (n_y from C, n_u "
                f"from B), got {D.shape}"
            )
        dt = _nonneg_scalar(self.dt, "dt", "0.0 (continuous) or a sample time > 0 s")
        delay = _nonneg_scalar(self.delay_s, "delay_s", "a finite delay >= 0 s")
        for key, value in (("A", A), ("B", B), ("C", C), ("D", D)):
            object.__setattr__(self, key, readonly(value))
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "delay_s", delay)
        names = (
            ("input_names", B.shape[1], "u"),
            ("output_names", C.shape[0], "y"),
            ("state_names", n, "x"),
        )
        for key, count, default in names:
            object.__setattr__(self, key, _names(getattr(self, key), count, default, _SRC, key))

    # ------------------------------------------------------------ sizes
    @property
    def n_x(self) -> int:
        return self.A.shape[0]

    @property
    def n_u(self) -> int:
        return self.B.shape[1]

    @property
    def n_y(self) -> int:
        return self.C.shape[0]

    @property
    def is_discrete(self) -> bool:
        return self.dt > 0

    def replace(self, **changes) -> LTIModel:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def without_delay(self) -> LTIModel:
        """The rational part: the same model with ``delay_s = 0``."""
        return self if self.delay_s == 0 else replace(self, delay_s=0.0)

    # ------------------------------------------------- python-control
    @classmethod
    def from_statespace(
        cls,
        sys,
        *,
        delay_s: float = 0.0,
        input_names=None,
        output_names=None,
        state_names=None,
    ) -> LTIModel:
        """From a python-control ``StateSpace`` (its labels become the names by default).

        ``dt = None`` or ``0`` in python-control means continuous; ``dt = True``
        (unspecified sample time) is taken as 1 s, as :func:`workbench.core.lti.as_matrices` does.
        """
        from workbench.core.lti import as_matrices

        A, B, C, D, dt = as_matrices(sys)

        def labels(given, attr):
            if given is not None:
                return tuple(given)
            return tuple(getattr(sys, attr, None) or ())

        return cls(
            A,
            B,
            C,
            D,
            dt=dt,
            delay_s=delay_s,
            input_names=labels(input_names, "input_labels"),
            output_names=labels(output_names, "output_labels"),
            state_names=labels(state_names, "state_labels"),
        )

    def to_statespace(self, *, pade_order: int | None = None):
        """A python-control ``StateSpace``.

        Parameters
        ----------
        pade_order : int, optional
            How to realize a delay as states: a continuous model gets a Pade
            approximation of this order on every input (``pade_order * n_u``
            more states, placed after the model's own); a discrete model gets
            ``delay_s / dt`` exact shift states per input (the delay must then
            be a whole number of samples; the order is not used). Without it a
            model with a delay is refused: a ``StateSpace`` cannot hold the
            delay, and dropping it silently is what this type exists to stop.
            Use :meth:`without_delay` for the rational part on purpose.

        Raises
        ------
        InputError
            A delay and no ``pade_order``; ``pade_order < 1``; a fractional
            delay on a discrete model.
        """
        import control

        if self.delay_s == 0:
            return control.ss(
                self.A,
                self.B,
                self.C,
                self.D,
                self.dt,
                inputs=list(self.input_names),
                outputs=list(self.output_names),
                states=list(self.state_names),
            )
        if pade_order is None:
            raise InputError(
                f"model: has an input delay of {self.delay_s:g} s that a StateSpace cannot hold: "
                "give pade_order=N to realize it as states, or use without_delay() for the "
                "rational part"
            )
        if int(pade_order) != pade_order or pade_order < 1:
            raise InputError(f"pade_order: expected an integer >= 1, got {pade_order!r}")
        delay = _delay_states(self.delay_s, int(pade_order), self.dt)
        n_u, n_d = self.n_u, delay.A.shape[0]
        Ad, Bd, Cd, Dd = (np.kron(np.eye(n_u), M) for M in (delay.A, delay.B, delay.C, delay.D))
        # u -> delay -> v -> model: x' = A x + B (Cd xd + Dd u), y = C x + D (Cd xd + Dd u)
        n = self.n_x
        A = np.block([[self.A, self.B @ Cd], [np.zeros((n_u * n_d, n)), Ad]])
        B = np.vstack([self.B @ Dd, Bd])
        C = np.hstack([self.C, self.D @ Cd])
        D = self.D @ Dd
        states = list(self.state_names) + [
            f"delay_{name}_{k}" for name in self.input_names for k in range(n_d)
        ]
        return control.ss(
            A,
            B,
            C,
            D,
            self.dt,
            inputs=list(self.input_names),
            outputs=list(self.output_names),
            states=states,
        )

    # -------------------------------------------------------------- files
    @classmethod
    def read(cls, path: str | os.PathLike) -> LTIModel:
        """Read a spec model file (with its ``delay_s`` key, if any)."""
        from workbench.io.formats import read_model

        return read_model(path)

    def write(self, path: str | os.PathLike) -> None:
        """Write a spec model file atomically; the delay goes exact into key ``delay_s``."""
        from workbench.io.formats import save_model

        save_model(path, self)

    # ---------------------------------------------------------- analysis
    def frf(self, freq_hz) -> np.ndarray:
        """Frequency response with the delay, shape (n_f, n_y, n_u), at ``freq_hz`` (Hz)."""
        from workbench.core.lti import frf

        return frf(self, freq_hz)  # lti.frf applies the model's own delay

    def poles(self) -> np.ndarray:
        """Eigenvalues of A: rad/s for a continuous model, z-plane for a discrete one."""
        return np.linalg.eigvals(self.A) if self.n_x else np.zeros(0, complex)

    def pole_summary(self, *, rigid_tol: float = 1e-6) -> dict:
        """See :func:`pole_summary`."""
        return pole_summary(self, rigid_tol=rigid_tol)

    def dc_gain(self) -> np.ndarray | None:
        """See :func:`dc_gain`."""
        return dc_gain(self)


def as_model(obj) -> LTIModel:
    """An :class:`LTIModel` from an ``LTIModel``, a python-control ``StateSpace`` or a path.

    A ``StateSpace`` has no delay (0 s); a model file keeps its ``delay_s``.
    """
    if isinstance(obj, LTIModel):
        return obj
    if isinstance(obj, str | os.PathLike):
        return LTIModel.read(obj)
    if all(hasattr(obj, k) for k in ("A", "B", "C", "D", "dt")):
        return LTIModel.from_statespace(obj)
    raise InputError(
        f"model: expected an LTIModel, a python-control StateSpace or a model file path, "
        f"got {type(obj).__name__}"
    )


# ----------------------------------------------------------------- delay states
def pade_delay(delay_s: float, order: int):
    """Pade approximation of exp(-s delay_s) as a SISO ``control.StateSpace`` (order states)."""
    import control

    num, den = control.pade(delay_s, order)
    return control.ss(control.tf(num, den))


def _delay_states(delay_s: float, order: int, dt: float):
    """SISO realization of the delay: Pade (continuous) or a shift register (discrete)."""
    import control

    if dt == 0:
        return pade_delay(delay_s, order)
    m = int(round(delay_s / dt))
    if abs(m * dt - delay_s) > 1e-9 * dt:
        raise InputError(
            f"model: a discrete model's delay of {delay_s:g} s is not a whole number of samples "
            f"(dt = {dt:g} s), so no shift states realize it"
        )
    A = np.eye(m, k=-1)  # x[k+1] = [u; x_0; ...; x_{m-2}], output the oldest
    B = np.eye(m, 1)
    C = np.eye(1, m, m - 1)
    return control.ss(A, B, C, np.zeros((1, 1)), dt)


def pade_order(delay_s: float, f_max_hz: float, *, max_phase_error_deg: float = 1.0) -> int:
    """Smallest Pade order (<= 10) whose phase error stays below the limit up to ``f_max_hz``."""
    import control

    if delay_s <= 0:
        return 0
    w = 2 * np.pi * np.linspace(f_max_hz / 50, f_max_hz, 50)
    for n in range(1, 11):
        num, den = control.pade(delay_s, n)
        h = np.polyval(num, 1j * w) / np.polyval(den, 1j * w)
        err = np.degrees(np.abs(np.angle(h * np.exp(1j * w * delay_s))))
        if err.max() < max_phase_error_deg:
            return n
    return 10


def with_pade(sys, delay_s: float, order: int):
    """``sys`` (continuous ``StateSpace``) with a Pade delay of ``order`` states on every input."""
    if order == 0 or delay_s <= 0:
        return sys
    return LTIModel.from_statespace(sys, delay_s=delay_s).to_statespace(pade_order=order)


# ------------------------------------------------------------------- summaries
def pole_summary(model, *, rigid_tol: float = 1e-6) -> dict:
    """Poles of a model in continuous-time terms.

    Parameters
    ----------
    model : LTIModel or control.StateSpace
        Continuous or discrete model (discrete poles are mapped by s = ln(z) / dt).
    rigid_tol : float
        A pole with |s| below ``rigid_tol * max(1, max |s|)`` rad/s counts as a
        rigid-body (integrating) pole.

    Returns
    -------
    dict
        ``n_rigid_body_poles``; ``flexible_modes``: list of ``{"freq_hz",
        "damping"}`` for complex pairs (natural frequency |s| / 2 pi, damping
        -Re(s) / |s|), sorted by frequency; ``real_poles_hz``: |s| / 2 pi of
        the other real poles; ``n_unstable``.
    """
    m = as_model(model)
    A, dt = m.A, m.dt
    if A.shape[0] == 0:
        return {"n_rigid_body_poles": 0, "flexible_modes": [], "real_poles_hz": [], "n_unstable": 0}
    lam = m.poles().astype(complex)
    s = np.log(lam + 0j) / dt if dt > 0 else lam
    s = np.where(np.isfinite(s), s, -np.inf)  # z = 0 poles: infinitely fast
    scale = max(1.0, float(np.max(np.abs(s[np.isfinite(s)]), initial=1.0)))
    # a defective (Jordan) zero pole splits numerically into a pair of size
    # ~sqrt(eps * ||A||); the tolerance covers that too
    tol = max(rigid_tol * scale, 10 * np.sqrt(np.finfo(float).eps * np.linalg.norm(A, 1)))
    if dt > 0:
        tol = max(rigid_tol * scale, 10 * np.sqrt(np.finfo(float).eps) / dt)
    rigid = np.abs(s) < tol
    complex_pair = (~rigid) & (s.imag > tol)
    real = (~rigid) & (np.abs(s.imag) <= tol)
    modes = [
        {"freq_hz": float(abs(p) / (2 * np.pi)), "damping": float(-p.real / abs(p))}
        for p in sorted(s[complex_pair], key=abs)
    ]
    return {
        "n_rigid_body_poles": int(rigid.sum()),
        "flexible_modes": modes,
        "real_poles_hz": sorted(float(abs(p) / (2 * np.pi)) for p in s[real] if np.isfinite(p)),
        "n_unstable": int(np.sum((~rigid) & (s.real > tol))),
    }


def dc_gain(model, *, poles: dict | None = None) -> np.ndarray | None:
    """Static gain (n_y, n_u), or None when the model integrates (rigid-body poles).

    The delay does not change the static gain.
    """
    m = as_model(model)
    poles = pole_summary(m) if poles is None else poles
    if poles["n_rigid_body_poles"]:
        return None
    n = m.n_x
    M = (np.eye(n) - m.A) if m.dt > 0 else -m.A
    try:
        X = np.linalg.solve(M, m.B)
    except np.linalg.LinAlgError:
        return None
    return m.C @ X + m.D
