"""Modal mechanics and the linear signal chain of a plant, in state-space form.

A :class:`ModalSet` holds mass-normalized modes in the plant's input/output
coordinates; :func:`apply_modal_effects` turns a plant's nominal modes into the
true ones (suspension, frequency and damping errors, residual and extra modes);
:class:`LinearChain` assembles the continuous state space of the whole linear
chain (actuator lags, input crosstalk, modes, output crosstalk, sensor lags)
with the block structure that the fast simulator exploits.

State coordinates per mode k are (q_k, dq_k/dt)::

    d/dt [q; dq] = [[0, 1], [-w_k^2, -2 z_k w_k]] [q; dq] + [0; b_k^T] u,
    y = sum_k c_k q_k,

so a rigid-body mode (w = 0) is a double integrator with b = c = 1/sqrt(m).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from workbench.core.arrays import readonly
from workbench.core.errors import InputError

from .effects import Effects, as_channel_vector

__all__ = ["ModalSet", "apply_modal_effects", "LinearChain"]

KINDS = ("rigid", "flexible", "residual", "extra", "suspension")


@dataclass(frozen=True)
class ModalSet:
    """Mass-normalized modes expressed at the plant's inputs and outputs.

    Parameters
    ----------
    freq_hz : (n_m,) array
        Undamped natural frequencies, Hz (0 for a rigid-body mode).
    damping : (n_m,) array
        Modal damping ratios, -.
    b : (n_m, n_u) array
        Input participation: modal force of mode k per unit input j.
    c : (n_m, n_y) array
        Output participation: output i per unit modal displacement of mode k.
    kind : tuple of str, length n_m
        'rigid', 'suspension', 'flexible', 'residual' or 'extra'.
    """

    freq_hz: np.ndarray
    damping: np.ndarray
    b: np.ndarray
    c: np.ndarray
    kind: tuple[str, ...]

    def __post_init__(self):
        for name in ("freq_hz", "damping", "b", "c"):
            object.__setattr__(self, name, readonly(getattr(self, name), float))
        n = self.freq_hz.shape[0]
        if self.freq_hz.shape != (n,) or self.damping.shape != (n,):
            raise InputError(
                "ModalSet: freq_hz and damping must be (n_m,), "
                f"got {self.freq_hz.shape}, {self.damping.shape}"
            )
        if self.b.ndim != 2 or self.c.ndim != 2 or self.b.shape[0] != n or self.c.shape[0] != n:
            raise InputError(
                f"ModalSet: b must be (n_m, n_u) and c (n_m, n_y) with n_m = {n}, "
                f"got {self.b.shape} and {self.c.shape}"
            )
        kind = tuple(self.kind)
        if len(kind) != n or any(k not in KINDS for k in kind):
            raise InputError(f"ModalSet.kind: expected {n} entries from {KINDS}, got {kind!r}")
        object.__setattr__(self, "kind", kind)

    @property
    def n_modes(self) -> int:
        return self.freq_hz.shape[0]

    @property
    def n_u(self) -> int:
        return self.b.shape[1]

    @property
    def n_y(self) -> int:
        return self.c.shape[1]

    def select(self, mask) -> ModalSet:
        """The modes where ``mask`` (n_m,) is true."""
        mask = np.asarray(mask, bool)
        return ModalSet(
            self.freq_hz[mask],
            self.damping[mask],
            self.b[mask],
            self.c[mask],
            tuple(k for k, m in zip(self.kind, mask) if m),
        )

    def concat(self, other: ModalSet) -> ModalSet:
        """This set followed by ``other`` (same n_u, n_y)."""
        return ModalSet(
            np.concatenate([self.freq_hz, other.freq_hz]),
            np.concatenate([self.damping, other.damping]),
            np.vstack([self.b, other.b]),
            np.vstack([self.c, other.c]),
            self.kind + other.kind,
        )

    def to_modal(self, *, delay_s: float = 0.0, input_names=(), output_names=()):
        """These modes as the one modal type, :class:`workbench.modal.model.ModalModel`.

        A mode at 0 Hz is a rigid mode (double integrator); every other one,
        whatever its plant role ('suspension', 'flexible', 'residual', 'extra'),
        is a flexible mode with the same ``b_k``, ``c_k`` (the role is the
        plant's bookkeeping, not part of the dynamics). D = 0; modes ordered
        rigid first, then by frequency (stable). ``delay_s`` (s) and the names
        are passed through. The lags and crosstalk of the plant's chain are not
        modes and are not included.
        """
        from workbench.modal.model import ModalModel, Mode

        order = sorted(range(self.n_modes), key=lambda k: (self.freq_hz[k] > 0, self.freq_hz[k]))
        modes = tuple(
            Mode(
                kind="rigid" if self.freq_hz[k] == 0 else "flexible",
                freq_hz=self.freq_hz[k],
                damping=0.0 if self.freq_hz[k] == 0 else self.damping[k],
                b=self.b[k],
                c=self.c[k],
            )
            for k in order
        )
        return ModalModel(
            modes=modes,
            D=np.zeros((self.n_y, self.n_u)),
            input_names=tuple(input_names),
            output_names=tuple(output_names),
            delay_s=delay_s,
        )

    def frf(self, freq_hz) -> np.ndarray:
        """Sum over modes of c_k b_k^T / (s^2 + 2 z w s + w^2) at s = j 2 pi f, (n_f, n_y, n_u)."""
        s = 2j * np.pi * np.atleast_1d(np.asarray(freq_hz, float))
        w = 2 * np.pi * self.freq_hz
        h = 1.0 / (s[:, None] ** 2 + 2 * self.damping * w * s[:, None] + w**2)
        return np.einsum("ky,fk,ku->fyu", self.c, h, self.b)


def apply_modal_effects(
    nominal: ModalSet, residual: ModalSet | None, effects: Effects, *, n_u: int, n_y: int
) -> ModalSet:
    """The true modes of a plant: its nominal modes changed by ``effects``.

    Parameters
    ----------
    nominal : ModalSet
        Rigid-body and flexible modes of the nominal machine.
    residual : ModalSet or None
        The plant's structural modes above Nyquist (kind 'residual').
    effects : Effects
        Uses suspension_freq_hz/-damping, mode_freq_error, mode_damping_error,
        residual_max_hz and extra_modes.
    n_u, n_y : int
        Plant dimensions, to check the extra modes.

    Returns
    -------
    ModalSet
    """
    f = np.array(nominal.freq_hz)
    z = np.array(nominal.damping)
    kind = list(nominal.kind)
    rigid = np.array([k == "rigid" for k in kind])
    flex = np.array([k == "flexible" for k in kind])
    if effects.suspension_freq_hz is not None:
        if not rigid.any():
            raise InputError(
                "Effects.suspension_freq_hz: this plant has no rigid-body modes "
                "(its suspension is part of its own configuration); set it to None"
            )
        f[rigid] = as_channel_vector(
            effects.suspension_freq_hz, int(rigid.sum()), "Effects.suspension_freq_hz"
        )
        z[rigid] = effects.suspension_damping
        kind = ["suspension" if r else k for k, r in zip(kind, rigid)]
    if effects.mode_freq_error is not None:
        f[flex] *= 1.0 + as_channel_vector(
            effects.mode_freq_error, int(flex.sum()), "Effects.mode_freq_error"
        )
    if effects.mode_damping_error is not None:
        z[flex] *= 1.0 + as_channel_vector(
            effects.mode_damping_error, int(flex.sum()), "Effects.mode_damping_error"
        )
    out = ModalSet(f, z, nominal.b, nominal.c, tuple(kind))
    if effects.residual_max_hz > 0 and residual is not None and residual.n_modes:
        out = out.concat(residual.select(residual.freq_hz <= effects.residual_max_hz))
    for i, m in enumerate(effects.extra_modes):
        if len(m.b) != n_u or len(m.c) != n_y:
            raise InputError(
                f"Effects.extra_modes[{i}]: expected b of length {n_u} and c of length {n_y}, "
                f"got {len(m.b)} and {len(m.c)}"
            )
        extra = ModalSet([m.freq_hz], [m.damping], [m.b], [m.c], ("extra",))
        out = out.concat(extra)
    return out


def _cutoffs(value, n: int, name: str) -> np.ndarray:
    if value is None:
        return np.full(n, np.inf)
    return as_channel_vector(value, n, name)


@dataclass(frozen=True)
class LinearChain:
    """Continuous state space of a plant's linear chain, without the delay.

    Parameters
    ----------
    modes : ModalSet
        The true modes (:func:`apply_modal_effects`).
    effects : Effects
        Uses actuator_cutoff_hz, sensor_cutoff_hz, crosstalk_input, crosstalk_output.

    Notes
    -----
    States, in this order: one per input with a finite actuator cutoff (the
    lagged input), two per mode (q, dq/dt), one per output with a finite
    sensor cutoff. A is block lower triangular in these three groups, and the
    mode group is block diagonal (2 x 2), which the fast simulator uses.
    The nonlinear port forces f_p (n_u,) act on the modes like the inputs
    but behind the actuator lag and crosstalk (collocated with input j), and
    the port displacement is d_p = sum_k b_k q_k.
    """

    modes: ModalSet
    effects: Effects = field(default_factory=Effects)

    @property
    def n_u(self) -> int:
        return self.modes.n_u

    @property
    def n_y(self) -> int:
        return self.modes.n_y

    @cached_property
    def input_cutoff_hz(self) -> np.ndarray:
        return _cutoffs(self.effects.actuator_cutoff_hz, self.n_u, "Effects.actuator_cutoff_hz")

    @cached_property
    def output_cutoff_hz(self) -> np.ndarray:
        return _cutoffs(self.effects.sensor_cutoff_hz, self.n_y, "Effects.sensor_cutoff_hz")

    @cached_property
    def crosstalk_in(self) -> np.ndarray:
        X = self.effects.crosstalk_input
        if X is None:
            return np.eye(self.n_u)
        if X.shape != (self.n_u, self.n_u):
            raise InputError(
                f"Effects.crosstalk_input: expected ({self.n_u}, {self.n_u}), got {X.shape}"
            )
        return np.eye(self.n_u) + X

    @cached_property
    def crosstalk_out(self) -> np.ndarray:
        X = self.effects.crosstalk_output
        if X is None:
            return np.eye(self.n_y)
        if X.shape != (self.n_y, self.n_y):
            raise InputError(
                f"Effects.crosstalk_output: expected ({self.n_y}, {self.n_y}), got {X.shape}"
            )
        return np.eye(self.n_y) + X

    @cached_property
    def layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lagged inputs, lagged outputs, slice sizes): index arrays of the lagged channels."""
        lu = np.flatnonzero(np.isfinite(self.input_cutoff_hz))
        ly = np.flatnonzero(np.isfinite(self.output_cutoff_hz))
        return lu, ly, np.array([lu.size, 2 * self.modes.n_modes, ly.size])

    @cached_property
    def matrices(self) -> dict[str, np.ndarray]:
        """A, B, C, D, Bp (port force), Cp (port displacement), Cv (port velocity)."""
        m = self.modes
        lu, ly, sizes = self.layout
        n_a, n_m2, n_s = sizes
        n = n_a + n_m2 + n_s
        A = np.zeros((n, n))
        B = np.zeros((n, self.n_u))
        C = np.zeros((self.n_y, n))
        Bp = np.zeros((n, self.n_u))
        Cp = np.zeros((self.n_u, n))
        Cv = np.zeros((self.n_u, n))
        # actuator lag states
        wu = 2 * np.pi * self.input_cutoff_hz
        for i, j in enumerate(lu):
            A[i, i] = -wu[j]
            B[i, j] = wu[j]
        # the input the mechanics sees: u_act = S_u x + E_u u
        S_u = np.zeros((self.n_u, n))
        E_u = np.eye(self.n_u)
        for i, j in enumerate(lu):
            S_u[j, i] = 1.0
            E_u[j, j] = 0.0
        Xin = self.crosstalk_in
        w = 2 * np.pi * m.freq_hz
        for k in range(m.n_modes):
            q, v = n_a + 2 * k, n_a + 2 * k + 1
            A[q, v] = 1.0
            A[v, q] = -(w[k] ** 2)
            A[v, v] = -2 * m.damping[k] * w[k]
            bk = m.b[k] @ Xin
            A[v, :] += bk @ S_u
            B[v, :] += bk @ E_u
            Bp[v, :] = m.b[k]
            Cp[:, q] = m.b[k]
            Cv[:, v] = m.b[k]
        # mechanical output, then output crosstalk
        Cm = np.zeros((self.n_y, n))
        Cm[:, n_a : n_a + n_m2 : 2] = m.c.T
        Cm = self.crosstalk_out @ Cm
        wy = 2 * np.pi * self.output_cutoff_hz
        C[:] = Cm
        for i, j in enumerate(ly):
            r = n_a + n_m2 + i
            A[r, :] += wy[j] * Cm[j]
            A[r, r] -= wy[j]
            C[j, :] = 0.0
            C[j, r] = 1.0
        D = np.zeros((self.n_y, self.n_u))
        return {"A": A, "B": B, "C": C, "D": D, "Bp": Bp, "Cp": Cp, "Cv": Cv}

    @property
    def n_x(self) -> int:
        return self.matrices["A"].shape[0]

    def frf(self, freq_hz, *, delay_s: float = 0.0) -> np.ndarray:
        """Frequency response of the chain, (n_f, n_y, n_u), from the modal sum.

        Notes
        -----
        G(s) = L_y(s) (I + X_y) [sum_k c_k b_k^T / (s^2 + 2 z_k w_k s + w_k^2)]
        (I + X_u) L_u(s) exp(-s delay_s), with L(s) = diag(1 / (1 + s / w_c)).
        """
        f = np.atleast_1d(np.asarray(freq_hz, float))
        s = 2j * np.pi * f
        G = self.modes.frf(f)
        G = np.einsum("ij,fjk,kl->fil", self.crosstalk_out, G, self.crosstalk_in)
        Lu = 1.0 / (1.0 + s[:, None] / (2 * np.pi * self.input_cutoff_hz[None, :]))
        Ly = 1.0 / (1.0 + s[:, None] / (2 * np.pi * self.output_cutoff_hz[None, :]))
        G = Ly[:, :, None] * G * Lu[:, None, :]
        if delay_s:
            G = G * np.exp(-s * delay_s)[:, None, None]
        return G
