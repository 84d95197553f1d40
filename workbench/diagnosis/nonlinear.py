"""Nonlinear simulation models: a linear model plus port nonlinearities.

Linear models cannot hold friction, a hardening spring or a saturating
amplifier, so ``augment --effect nonlinearity`` adds them to the *simulation
model* used for time-domain comparison instead. The nonlinearities act at
the plant's inputs, on ports collocated with them (a square model whose
output j measures the displacement where input j pushes, as in DOF
coordinates of a stage):

    u_applied = sat(u[k - m]) - F_c tanh(v / v0) - k3 p^3,   p = C x,  v = C A x

with p the port displacement (the collocated output) and v its velocity.
Over each of ``substeps`` substeps per sample the linear part is propagated
exactly (zero-order hold) and the port force varies linearly from its start to
its end value (trapezoidal, the friction's end value implicit):
:func:`workbench.sim.substep_zoh` and its compiled loop, the propagation the
plants use too; this module supplies the port law.

A square model whose sensors see some modes with other shapes than the actuators drive
them (a stage's flexible modes in DOF coordinates: residue ``c_k b_k^T`` with ``c_k !=
b_k``) has its outputs as ports only for the collocated modes (symmetric positive
semi-definite residue): :func:`square_ports` gives the others the port residue ``g_k v_k
v_k^T`` (``v_k`` their input direction), one gain ``g_k = |b_k|^2`` each, which
:func:`fit_port_element` fits with the element (:class:`SquarePorts`).

A model that is not square has no output at most ports. With one sensor i
collocated with actuator j (methods.md section 4, the extended modal model),
the residue row of that sensor fixes each mode's mass-normalized shape at
every actuator: ``R_k = phi_k(sensors) phi_k(actuators)^T`` and ``phi_k(s_i) =
phi_k(a_j)`` give ``phi_k(a) phi_k(a)^T = R_k[i, :]^T R_k[i, :] / R_k[i, j]``, the
port-displacement residue of mode k. :func:`with_ports` appends these port
displacements to the model's outputs (``port_outputs`` of
:func:`simulate_nonlinear` and :func:`fit_port_element`);
:func:`collocated_pairs` lists the pairs a model allows (every mode's
driving-point residue positive, as a collocated pair's is).

A hardening spring may sit on a mode instead of a port (a modal Duffing: the geometric
stiffening of a beam's bending mode): the force ``-k3 q^3`` on the mode's modal displacement
``q`` enters the mode's own equation. :class:`ModalPort` gives that port in the model's
companion realization (the element's own ``port_forces`` / ``port_displacements`` in
:class:`PortNonlinearity`, the same substep propagation and kernel), and
:func:`fit_port_element` fits the spring there; it needs no sensor at an input.

Friction may act on a square model's rigid-body motion instead of at its inputs (a
bearing's friction on a stage's rigid bodies, which drives no flexible mode, where a force
at the inputs drives them through B): :class:`RigidPorts` gives those ports (the rigid
modes' rows of B and columns of C, one port per input), and :func:`fit_port_element` fits
friction there; the diagnosis lets the record choose between the two. On free rigid bodies
(decoupled double integrators, :func:`_coulomb_ports`) that friction is the hard Coulomb law
(``friction_velocity`` 0), simulated event by event: each port's stops, holds and reversals
in closed form over each held sample (:func:`_coulomb_record`), the other states' linear ZOH
response beside it; no substeps, exact. The smooth law there, and a mode's spring, are
substepped likewise on the states the element moves and those that drive them only
(:func:`_port_states`: a mode's two states and the actuator lags, of a beam's 44), the
others' linear response added.

A saturation of the inputs needs no port: the applied force ``clip(u_j, -l_j, l_j)`` does
not depend on the motion, so any linear model driven by the clipped recorded input is its
simulation model (:func:`fit_saturation`, on a model with no port to locate).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal

from workbench import sim
from workbench.core import lti
from workbench.core.errors import InputError

__all__ = [
    "PortNonlinearity",
    "simulate_nonlinear",
    "collocated_pairs",
    "with_ports",
    "square_ports",
    "SquarePorts",
    "ModalPort",
    "RigidPorts",
    "fit_friction",
    "fit_port_element",
    "fit_saturation",
    "ElementFit",
    "ELEMENTS",
    "first_order_errors",
]


@dataclass(frozen=True)
class PortNonlinearity:
    """Nonlinearities at the input ports.

    Parameters
    ----------
    friction_force : (n_u,) array
        Coulomb friction level per port, N (N m for torques); 0 = none.
    friction_velocity : float
        Velocity scale v0 of the smooth Coulomb law, m/s. 0: the hard law, ``-F_c sign(v)``
        sticking while the other forces stay within ``F_c``, simulated event-exact (no
        substeps); only on the element's own ports, when they are free, decoupled double
        integrators (:func:`_coulomb_ports`: :class:`RigidPorts` of free rigid bodies), and
        alone (no cubic spring).
    cubic_stiffness : (n_u,) array
        Hardening spring k3 per port, N/m^3; 0 = none.
    saturation : (n_u,) array
        Symmetric saturation of each input, N; inf = none.
    substeps : int
        Substeps per sample.
    port_forces, port_displacements : (n, n_p) and (n_p, n) arrays, optional
        Ports that are not the inputs: where each port force enters the model's state
        (n states, n_p ports) and the port displacement it acts on, for the model the
        element sits on in its own realization (:class:`ModalPort`: one mode's
        coordinate, the modal Duffing). The levels are then per port (n_p,), in that
        port's units (modal force per modal displacement cubed for a mode). None: the
        ports are the inputs (forces through B, displacements from the collocated outputs).
    """

    friction_force: np.ndarray
    friction_velocity: float = 1e-3
    cubic_stiffness: np.ndarray | None = None
    saturation: np.ndarray | None = None
    substeps: int = 8
    notes: tuple[str, ...] = field(default=())
    port_forces: np.ndarray | None = None
    port_displacements: np.ndarray | None = None


def _ports(sys, port_outputs=None):
    """(A, B, C, D, Cp, measured): the measured outputs' C, D, the ports' Cp and their indices."""
    A, B, C, D, dt = lti.as_matrices(sys)
    if dt:
        raise InputError("nonlinear simulation: expected a continuous model (dt = 0)")
    n_y, n_u = C.shape[0], B.shape[1]
    if port_outputs is None:
        if n_y != n_u:
            raise InputError(
                "nonlinear simulation: expected a square model (ports collocated with the "
                f"inputs), got {n_y} outputs and {n_u} inputs; a model with a collocated "
                "sensor gets its ports from with_ports"
            )
        return A, B, C, D, C, np.arange(n_y)
    ports = np.asarray(port_outputs, int).ravel()
    if ports.size != n_u or np.any((ports < 0) | (ports >= n_y)) or np.unique(ports).size != n_u:
        raise InputError(
            f"nonlinear simulation: expected port_outputs, {n_u} distinct outputs of the "
            f"{n_y}, one per input, got {ports.tolist()}"
        )
    measured = np.setdiff1d(np.arange(n_y), ports)
    return A, B, C[measured], D[measured], C[ports], measured


def collocated_pairs(model, *, max_pairs: int = 3) -> list[tuple[int, int]]:
    """(sensor, actuator) pairs that may be collocated: every mode's driving-point residue > 0.

    A displacement sensor at a force actuator sees every mode with the residue
    ``phi_k(a)^2 > 0`` (a collocated transfer function alternates poles and zeros); a
    sensor elsewhere sees some mode with the opposite sign (a node between them). The
    test is necessary, not sufficient (two close points pass it too): the pairs are
    hypotheses, ranked by their smallest relative driving-point residue, at most
    ``max_pairs``. Real poles are no structural modes and are not tested.

    Parameters
    ----------
    model : workbench.modal.model.ModalModel
    """
    R = [m.numerator()[0] for m in model.modes if m.kind != "real"]
    if not R:
        return []
    R = np.array(R)  # (n_m, n_y, n_u)
    scale = np.maximum(np.abs(R).reshape(len(R), -1).max(axis=1), 1e-300)
    margin = (R / scale[:, None, None]).min(axis=0)
    pairs = [(int(i), int(j)) for i, j in np.argwhere(margin > 1e-9)]
    pairs.sort(key=lambda p: -margin[p])
    return pairs[:max_pairs]


def with_ports(model, pair: tuple[int, int]):
    """The modal model with the port displacements of its inputs appended to its outputs.

    Parameters
    ----------
    model : workbench.modal.model.ModalModel
    pair : (int, int)
        Sensor (output) i collocated with actuator (input) j.

    Returns
    -------
    ModalModel or None
        ``n_y + n_u`` outputs, the last ``n_u`` the port displacements (mode k
        contributes ``R_k[i, :]^T R_k[i, :] / R_k[i, j]``, the mass-normalized
        ``phi_k(a) phi_k(a)^T``; a mode with no positive driving-point residue, whose
        shape at the ports the pair cannot fix, none). Outside the mechanics: no
        feedthrough, no sensor lag or output coupling on the ports (input lags and
        coupling act on the port forces as on the inputs). None when a rigid-body
        cluster holds several rigid modes (their shapes are not fixed by one row).
    """
    i, j = pair
    n_u = model.n_u
    rows = []
    for m in model.modes:
        N0, N1 = m.numerator()
        row = N0[i]
        r = row[j]
        P = np.zeros((n_u, n_u))
        if m.kind != "real" and r > 1e-9 * max(np.abs(N0).max(), 1e-300):
            if m.kind == "rigid":
                sv = np.linalg.svd(np.vstack([N0, N1]), compute_uv=False)
                if sv.size > 1 and sv[1] > 1e-9 * sv[0]:
                    return None
            P = np.outer(row, row) / r
        c_port = m.b * (m.c[i] / m.b[j]) if m.b[j] != 0 else np.zeros(n_u)
        rows.append((c_port, P, np.zeros((n_u, n_u))))
    return _append_ports(model, rows)


def _append_ports(model, rows):
    """``model`` with its n_u port displacements appended to its outputs.

    ``rows``: per mode ``(c_port (n_u,), P0 (n_u, n_u), P1 (n_u, n_u))``, the port rows of
    its modal output vector and of its numerator ``N1 s + N0``. Outside the mechanics: no
    feedthrough, no sensor lag or output coupling on the ports (input lags and coupling act
    on the port forces as on the inputs).
    """
    from dataclasses import replace

    import scipy.linalg

    n_u = model.n_u
    modes = []
    for m, (c_port, P0, P1) in zip(model.modes, rows, strict=True):
        N0, N1 = m.numerator()
        modes.append(
            replace(
                m,
                c=np.concatenate([m.c, c_port]),
                N0=np.vstack([N0, P0]),
                N1=np.vstack([N1, P1]),
            )
        )
    tau_out = None if model.tau_out is None else np.concatenate([model.tau_out, np.zeros(n_u)])
    T_out = None if model.T_out is None else scipy.linalg.block_diag(model.T_out, np.eye(n_u))
    names = tuple(model.output_names) + tuple(f"port {name}" for name in model.input_names)
    return replace(
        model,
        modes=tuple(modes),
        D=np.vstack([model.D, np.zeros((n_u, n_u))]),
        transform=None,
        output_names=names,
        tau_out=tau_out,
        T_out=T_out,
    )


def _collocated(m) -> bool:
    """Whether mode ``m`` of a square model is seen at the input ports: its residue is
    symmetric positive semi-definite, ``phi(a) phi(a)^T`` (a rigid body in DOF coordinates).
    A mode whose sensor shape differs from its actuator shape (``c != b``) is not."""
    N0, _ = m.numerator()
    scale = max(float(np.abs(N0).max()), 1e-300)
    if np.abs(N0 - N0.T).max() > 1e-6 * scale:
        return False
    return bool(np.linalg.eigvalsh(0.5 * (N0 + N0.T)).min() >= -1e-9 * scale)


@dataclass(frozen=True)
class SquarePorts:
    """The port model of a square model whose outputs are not all collocated with its inputs.

    Output j of a square model (DOF coordinates of a stage) measures the port of input j
    for the modes it sees as the actuators drive them (collocated: symmetric positive
    semi-definite residue, the rigid bodies); a flexible mode that the sensors see with
    another shape (``c_k != b_k``) has the port residue ``b_k b_k^T``, which its residue
    ``c_k b_k^T`` fixes only up to a gain: ``g_k v_k v_k^T`` with ``v_k`` its input
    direction (in general ``g_k (N0^T N0)^(1/2) / |N0|_2``), ``g_k = |b_k|^2 >= 0``
    (m/N) one unknown per such mode, fitted on the record with the element
    (:func:`fit_port_element`). Taking the outputs as the ports (``Cp = C``) instead puts
    the sensors' shapes in the port velocity: a non-collocated path through which a steep
    friction law drives those modes.

    Attributes
    ----------
    model : ModalModel
        The square linear model.
    modes : tuple of int
        Indices (into ``model.modes``) of the non-collocated modes, one gain each.
    unit : (n_g,) array
        ``|N0_k|_2 = |c_k| |b_k|`` per such mode, m/N: the gain if sensor and actuator
        shapes had the same size (the scale the gains are searched on).
    """

    model: Any
    modes: tuple[int, ...]
    unit: np.ndarray

    @property
    def port_outputs(self) -> list[int]:
        """The port displacements' output indices in :meth:`system` (the last n_u)."""
        return list(range(self.model.n_y, self.model.n_y + self.model.n_u))

    def freq_hz(self) -> list[float]:
        """The non-collocated modes' frequencies, Hz (one per gain)."""
        return [float(self.model.modes[k].freq_hz) for k in self.modes]

    def system(self, gains):
        """The LTIModel with the ports appended (``port_outputs``), gains (n_g,) m/N >= 0."""
        gains = np.broadcast_to(np.asarray(gains, float), (len(self.modes),))
        n_u = self.model.n_u
        zero = np.zeros((n_u, n_u))
        rows = []
        for k, m in enumerate(self.model.modes):
            N0, N1 = m.numerator()
            if m.kind == "real":  # a lag, no structural mode: not at the ports
                rows.append((np.zeros(n_u), zero, zero))
            elif k not in self.modes:
                rows.append((m.c, N0, N1))
            else:
                # (N0^T N0)^(1/2) = V S V^T: g_k v v^T for a rank-one residue
                _, sv, Vt = np.linalg.svd(N0)
                P = gains[self.modes.index(k)] / max(sv[0], 1e-300) * (Vt.T * sv) @ Vt
                bb = float(m.b @ m.b)
                rows.append((P @ m.b / bb if bb > 0 else np.zeros(n_u), P, zero))
        return _append_ports(self.model, rows).to_lti()

    def port_map_derivative(self) -> np.ndarray:
        """dCp / dg_k, (n_g, n_u, n) m per state per m/N: how the port displacements' rows of
        :meth:`system`'s C move with each gain (nothing else in it depends on them). The rows
        are linear in the gains (each mode's port residue is ``g_k`` times a fixed shape), so
        the difference over one unit of each gain is the derivative, exactly."""
        ports = self.port_outputs
        base = np.asarray(self.system(self.unit).C, float)[ports]
        out = []
        for k, unit in enumerate(self.unit):
            g = self.unit.copy()
            g[k] += unit
            out.append((np.asarray(self.system(g).C, float)[ports] - base) / unit)
        return np.stack(out) if out else np.zeros((0,) + base.shape)


def square_ports(model) -> SquarePorts | None:
    """The port model of a square ModalModel, or None when every mode is collocated (then
    the outputs are the ports, ``Cp = C``, as :func:`simulate_nonlinear` takes by default)."""
    if model.n_y != model.n_u:
        raise InputError(
            f"square_ports: expected a square model, got {model.n_y} outputs and {model.n_u} inputs"
        )
    modes = tuple(k for k, m in enumerate(model.modes) if m.kind != "real" and not _collocated(m))
    if not modes:
        return None
    unit = np.array([np.linalg.norm(model.modes[k].numerator()[0], 2) for k in modes])
    return SquarePorts(model=model, modes=modes, unit=unit)


@dataclass(frozen=True)
class ModalPort:
    """A port on one flexible mode's coordinate: where a modal cubic spring (a modal Duffing,
    the geometric stiffening of a beam's mode) acts.

    The force ``-k3 q^3`` on the mode's modal displacement ``q`` enters the mode's own
    equation, ``q'' + 2 z w q' + w^2 q = b^T u - k3 q^3``, not any input: a model that is
    not square, with no output at the inputs, has this port all the same. ``q`` is the
    coordinate of :meth:`ModalModel.to_statespace`'s companion form (``b``, ``c`` of the
    mode as the model holds them), so ``k3`` (modal force per modal displacement cubed)
    absorbs the mode's normalization. :func:`fit_port_element` fits the spring on it.

    Attributes
    ----------
    model : ModalModel
        The linear model the spring sits on.
    mode : int
        Index into ``model.modes`` of a flexible mode realized by one 2-state block (an
        ideal mode or a rank-one residue).
    """

    model: Any
    mode: int

    def __post_init__(self):
        modes = self.model.modes
        if not 0 <= self.mode < len(modes) or modes[self.mode].kind != "flexible":
            raise InputError(
                f"ModalPort: expected the index of a flexible mode of the model, got {self.mode}"
            )
        if self.maps is None:
            raise InputError(
                f"ModalPort: mode {self.mode} has no single coordinate (its residue has rank > 1 "
                "or a velocity term)"
            )

    @property
    def freq_hz(self) -> float:
        """The mode's natural frequency, Hz."""
        return float(self.model.modes[self.mode].freq_hz)

    @functools.cached_property
    def _ideal(self):
        """The model with the mode in its ideal form (``N0 = c b^T``, ``N1 = 0``), or None.

        A mode kept with its exact numerator is realized in (Re, Im) coordinates in which the
        input enters both states: neither is the modal displacement. When that numerator is
        the ideal one to :data:`IDEAL_TOL` (rank one, no velocity term: a structural mode of
        a mechanical model), the ideal form is the same transfer function and its first state
        is ``q``; otherwise the mode has no single coordinate (None)."""
        from dataclasses import replace

        m = self.model.modes[self.mode]
        if m.N0 is not None or m.N1 is not None:
            N0, N1 = m.numerator()
            scale = max(float(np.linalg.norm(N0, 2)), 1e-300)
            off_rank = float(np.linalg.norm(N0 - np.outer(m.c, m.b), 2))
            if off_rank > IDEAL_TOL * scale or m.omega * np.linalg.norm(N1, 2) > IDEAL_TOL * scale:
                return None
        ideal = replace(m, N0=None, N1=None)
        modes = self.model.modes
        return replace(self.model, modes=modes[: self.mode] + (ideal,) + modes[self.mode + 1 :])

    @functools.cached_property
    def lti(self):
        """The model's companion-form realization (LTIModel, with its delay), the mode ideal."""
        return self._ideal.to_lti()

    @functools.cached_property
    def maps(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(Bp (n, 1), Cp (1, n)) in :attr:`lti`'s states: the mode's velocity row, where its
        force enters, and its displacement; None when the mode has no single coordinate."""
        m = self._ideal
        if m is None:
            return None
        A = np.asarray(self.lti.A, float)
        # the ideal companion block [[0, 1], [-w^2, -2 z w]]: displacement off, velocity off + 1
        off = _mode_blocks_at(m, A)[self.mode][0]
        Bp = np.zeros((A.shape[0], 1))
        Bp[off + 1, 0] = 1.0
        Cp = np.zeros((1, A.shape[0]))
        Cp[0, off] = 1.0
        return Bp, Cp


@dataclass(frozen=True)
class RigidPorts:
    """Ports on the rigid-body motion of a square model: where friction at a bearing acts.

    Friction where a body slides on its bearing resists the body's rigid motion: its force
    enters the rigid-body modes' equations only, against their velocity, and drives no
    flexible mode (a stage's guide or air-bearing friction on its six rigid degrees of
    freedom). Friction at the inputs (:func:`fit_port_element` on the square model itself)
    instead pushes through the actuators, into the flexible modes as well. Both are
    hypotheses; the record decides by the error each leaves.

    In a square model in DOF coordinates the rigid-body part of the output is the DOF
    displacement of the rigid motion, ``C_r x_r``, and the force at DOF j enters the rigid
    modes as the input does, ``B_r``: the ports are the inputs' (one level per input, ``n_p =
    n_u``), with the flexible modes' rows of ``B`` and columns of ``C`` left out. A rigid mode
    held as a residue block of rank > 1 (the six rigid bodies of a stage as one) is the same:
    its states are all rigid.

    Attributes
    ----------
    model : ModalModel
        The square linear model, with at least one rigid mode.
    """

    model: Any

    def __post_init__(self):
        if self.model.n_y != self.model.n_u:
            raise InputError(
                f"RigidPorts: expected a square model, got {self.model.n_y} outputs and "
                f"{self.model.n_u} inputs"
            )
        if not any(m.kind == "rigid" for m in self.model.modes):
            raise InputError("RigidPorts: the model has no rigid mode")
        if self.model.tau_out is not None and np.any(self.model.tau_out):
            raise InputError(
                "RigidPorts: a model with sensor lags has no rigid displacement output"
            )

    @functools.cached_property
    def lti(self):
        """The model's companion-form realization (LTIModel, with its delay)."""
        return self.model.to_lti()

    @functools.cached_property
    def maps(self) -> tuple[np.ndarray, np.ndarray]:
        """(Bp (n, n_u), Cp (n_u, n)) in :attr:`lti`'s states: the rigid modes' input rows
        (where a port force enters them) and their output columns (the rigid displacement)."""
        A = np.asarray(self.lti.A, float)
        n, n_u = A.shape[0], self.model.n_u
        Bp, Cp = np.zeros((n, n_u)), np.zeros((n_u, n))
        for mode, (off, (Ab, Bb, Cb)) in zip(self.model.modes, _mode_blocks_at(self.model, A)):
            if mode.kind == "rigid":
                k = Ab.shape[0]
                Bp[off : off + k] = Bb
                Cp[:, off : off + k] = Cb
        return Bp, Cp


def _mode_blocks_at(model, A: np.ndarray) -> list[tuple[int, tuple]]:
    """Each mode's first state in ``model.to_lti()``'s realization (state matrix ``A``) and its
    companion blocks ``(Ab, Bb, Cb)``: after the actuator lags' states (lagged inputs only,
    as ``wrap_outer`` puts them), the modes' blocks in order, each checked against ``A``."""
    from workbench.modal.model import _mode_blocks

    tau_in = model.tau_in
    off = int(np.count_nonzero(tau_in)) if tau_in is not None else 0
    out = []
    for mode in model.modes:
        blocks = _mode_blocks(mode, "companion")
        k = blocks[0].shape[0]
        if not np.array_equal(A[off : off + k, off : off + k], blocks[0]):
            raise AssertionError("a mode's block is not where the realization has it")
        out.append((off, blocks))
        off += k
    return out


#: a spring on a mode's coordinate (:class:`ModalPort`) is scanned over levels within
#: MODAL_SPAN either way of MODAL_CENTER times ``w^2 / q_rms^2`` (the levels that change the
#: mode's stiffness at the rms motion by 0.1 % to 10^4 times: a strong spring holds the mode's
#: resonant motion to a fraction of its linear rms, where its force is what a much smaller one
#: is at the linear motion), on a grid of ratio MODAL_STEP
MODAL_CENTER, MODAL_SPAN, MODAL_STEP = 10.0**0.5, 10.0**3.5, 10.0**0.25
#: ... and from its level regressed on the mode's measured coordinate (:func:`_measured_mode`),
#: refined within MEASURED_SPAN either way on a grid of ratio MEASURED_STEP: near a hardening
#: mode's jumps the error is rough in the level at a fraction of a per cent (an indepgen beam
#: record, a spring 30 % of its mode's stiffness at the rms motion: 1.1, 2.1 and 8.8x the noise
#: at 0.75, 0.8 and 1.05 % above the regressed level), far below the scan's grid above
MEASURED_SPAN, MEASURED_STEP = 1.04, 1.0025
#: a mode's exact numerator is its ideal one (:class:`ModalPort`) within this share of its size
IDEAL_TOL = 1e-6


def simulate_nonlinear(
    sys,
    u: np.ndarray,
    fs: float,
    nl: PortNonlinearity,
    *,
    delay_s: float = 0.0,
    port_outputs=None,
) -> np.ndarray:
    """Response to the recorded input ``u`` (N, n_u), from rest; (N, n_y) outputs.

    ``sys`` is a continuous square model (``StateSpace`` or ``LTIModel``); an
    ``LTIModel``'s own delay is applied and ``delay_s`` (s) adds to it, as in
    :func:`workbench.sim.simulate_zoh`; the total is rounded to whole samples.
    Without any nonlinearity this equals :func:`workbench.core.sim.simulate_zoh`
    for integer-sample delays. ``port_outputs``: the outputs of ``sys`` that are the
    port displacements, one per input (a model from :func:`with_ports`); they are
    left out of the returned outputs. Default: output j is the port of input j.
    """
    return _simulate(sys, u, fs, nl, delay_s, port_outputs)[0]


#: a port map is a free double integrator's (:func:`_coulomb_ports`) within this share of its size
COULOMB_TOL = 1e-9


def _coulomb_ports(A, B, Bp, Cp):
    """The element's own ports as free, decoupled double integrators, for the event-exact hard
    Coulomb law (``friction_velocity`` 0): ``(acc (n_p, n_u), w (n_p,), out (n_r, 2 n_p), r
    (n,) bool)`` or None when they are not.

    The ports' states ``r`` (those ``Bp`` drives or ``Cp`` reads) must be closed under ``A``
    (nothing else drives them, they drive nothing else: the friction moves no other state) and
    nilpotent (``A_rr^2 = 0``: free rigid bodies, no spring, no damping), with ``x_r`` one to
    one with the ports' displacements and velocities ``(p, v) = (Cp x, Cp A x)`` (``out`` maps
    them back, ``x_r = out (p, v)``). Then ``p' = v`` and ``v' = acc u + w f``: each port's
    acceleration is its input's ``acc u`` plus its own force's ``w_j f_j`` only (``Cp A Bp``
    diagonal, > 0; ``Cp B`` and ``Cp Bp`` zero, the forces act on the accelerations). A
    stage's rigid bodies in DOF coordinates (:class:`RigidPorts`) are; lagged inputs or a
    suspension are not."""
    A, B, Bp, Cp = (np.asarray(M, float) for M in (A, B, Bp, Cp))
    r = np.any(Bp != 0, axis=1) | np.any(Cp != 0, axis=0)
    n_p = Cp.shape[0]
    if int(r.sum()) != 2 * n_p:
        return None
    size = max(np.abs(A).max(), 1e-300)
    Arr = A[np.ix_(r, r)]
    if np.abs(A[np.ix_(r, ~r)]).max(initial=0.0) > COULOMB_TOL * size:
        return None
    if np.abs(A[np.ix_(~r, r)]).max(initial=0.0) > COULOMB_TOL * size:
        return None
    if np.abs(Arr @ Arr).max() > COULOMB_TOL * size**2:
        return None
    CpA = Cp @ A
    T = np.vstack([Cp[:, r], CpA[:, r]])
    if np.linalg.cond(T) > 1e10:
        return None
    W = CpA @ Bp
    w = np.diag(W).copy()
    scale = max(np.abs(W).max(), 1e-300)
    if np.any(w <= 0) or np.abs(W - np.diag(w)).max() > COULOMB_TOL * scale:
        return None
    lead = max(np.abs(Cp).max() * max(np.abs(B).max(), np.abs(Bp).max()), 1e-300)
    if max(np.abs(Cp @ B).max(), np.abs(Cp @ Bp).max()) > COULOMB_TOL * lead:
        return None
    return CpA @ B, w, np.linalg.inv(T), r


@numba.njit(cache=True)
def _coulomb_sample(p, v, a, f, dt):  # pragma: no cover - compiled
    """(p, v) after one sample ``dt`` of a free unit-mass port from (p, v): ``v' = a - f
    sign(v)`` (``a`` held), sticking at ``v = 0`` while ``|a| <= f``."""
    t = dt
    while t > 0.0:  # at most two phases: slide to a stop, then stick or slide on
        if v == 0.0:
            if abs(a) <= f:
                break  # stuck for the rest of the sample
            g = a - f if a > 0 else a + f
            p += 0.5 * g * t * t
            v = g * t
            break
        g = a - f if v > 0 else a + f
        if g * v >= 0.0 or -v / g >= t:  # no stop within the sample
            p += v * t + 0.5 * g * t * t
            v += g * t
            break
        ts = -v / g
        p += 0.5 * v * ts  # (v ts + g ts^2 / 2, g ts = -v)
        v = 0.0
        t -= ts
    return p, v


@numba.njit(cache=True)
def _coulomb_record(acc, wF, dt, P, V):  # pragma: no cover - compiled
    """Event-exact hard Coulomb motion of free unit-mass ports from rest: ``p' = v``, ``v' =
    acc[k] - wF sign(v)`` over sample k (acc held), sticking at ``v = 0`` while ``|acc| <= wF``
    (static = sliding level). Writes each sample's start state into ``P``, ``V`` (N, n_p)."""
    N, n_p = acc.shape
    for j in range(n_p):
        p, v, f = 0.0, 0.0, wF[j]
        for k in range(N):
            P[k, j] = p
            V[k, j] = v
            p, v = _coulomb_sample(p, v, acc[k, j], f, dt)


@numba.njit(cache=True)
def _coulomb_port_sums(acc, wF, dt, a, b):  # pragma: no cover - compiled
    """For each level ``wF[t]`` of one port (``acc`` (N,) its input's acceleration): the
    sums over its record from rest of ``a p + b v``, ``p^2``, ``p v``, ``v^2`` (T, 4), (p, v)
    each sample's start state as :func:`_coulomb_record` writes it."""
    out = np.zeros((wF.shape[0], 4))
    for t in range(wF.shape[0]):
        p, v, f = 0.0, 0.0, wF[t]
        s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0
        for k in range(acc.shape[0]):
            s0 += a[k] * p + b[k] * v
            s1 += p * p
            s2 += p * v
            s3 += v * v
            p, v = _coulomb_sample(p, v, acc[k], f, dt)
        out[t, 0], out[t, 1], out[t, 2], out[t, 3] = s0, s1, s2, s3
    return out


def _simulate_coulomb(A, B, C, D, Bp, Cp, ud, fs, friction_force):
    """(y, p) of the hard Coulomb law on ports :func:`_coulomb_ports` accepts, from rest: the
    ports' event-exact motion (:func:`_coulomb_record`) plus the other states' linear ZOH
    response, which the friction does not move. ``ud`` (N, n_u): the delayed, held input."""
    ports = _coulomb_ports(A, B, Bp, Cp)
    if ports is None:
        raise InputError(
            "nonlinear simulation: a hard Coulomb law (friction_velocity 0) needs ports that "
            "are free, decoupled double integrators (RigidPorts of free rigid bodies)"
        )
    acc_map, w, out, r = ports
    N, n_p = ud.shape[0], Cp.shape[0]
    acc = np.ascontiguousarray(ud @ acc_map.T)
    wF = np.ascontiguousarray(w * np.broadcast_to(np.asarray(friction_force, float), (n_p,)))
    P, V = np.empty((N, n_p)), np.empty((N, n_p))
    _coulomb_record(acc, wF, 1.0 / fs, P, V)
    C_rest = np.array(C, float)
    C_rest[:, r] = 0.0  # the ports' states: their exact motion below
    y = (
        _linear_rest(A, B, C_rest, D, ud, fs)
        + np.hstack([P, V]) @ (np.asarray(C, float)[:, r] @ out).T
    )
    return y, P


def coulomb_port_profile(sys, u, y, fs, Bp, Cp, levels, j: int):
    """``errors(trial)``: the relative errors (spec 1a, whole record) of the hard Coulomb law
    on free rigid ports (:func:`_coulomb_ports`) with port ``j``'s level set to each of
    ``trial`` (levels, any shape; 0 for none), the others held at ``levels``.

    Each port's event-exact motion depends on its own level only (the ports are decoupled
    double integrators), so the record is simulated once, here, and port ``j``'s own motion
    is replaced per trial, its squared error summed alongside (:func:`_coulomb_port_sums`):
    about 0.04 ms a trial on a 10,000-sample 6x6 record, where a whole simulation takes 2
    ms. ``sys``: the continuous linear model (its delay is applied)."""
    A, B, C, D, _ = lti.as_matrices(sys)
    u = np.asarray(u, float)
    ud = sim.delayed(u, int(round(float(getattr(sys, "delay_s", 0.0)) * fs)))
    acc_map, w, out, r = _coulomb_ports(A, B, Bp, Cp)
    M = np.asarray(C, float)[:, r] @ out  # (n_y, 2 n_p): the ports' (p, v) to the output
    n_p, N = Cp.shape[0], ud.shape[0]
    acc_j = np.ascontiguousarray(ud @ acc_map[j])
    levels = np.broadcast_to(np.asarray(levels, float), (n_p,))
    y_full = _simulate_coulomb(A, B, C, D, Bp, Cp, ud, fs, levels)[0]
    P, V = np.empty((N, 1)), np.empty((N, 1))
    _coulomb_record(acc_j[:, None], np.array([w[j] * levels[j]]), 1.0 / fs, P, V)
    m_p, m_v = M[:, j], M[:, n_p + j]
    rest = np.asarray(y, float) - y_full + P * m_p + V * m_v  # the residual without port j
    # |rest - p m_p' - v m_v'|^2 expanded: sums over the samples a trial, not an (N, n_y)
    # residual (what is left is many times the rounding of |rest|^2: a fit at the noise)
    a, b = rest @ m_p, rest @ m_v
    pp, pv, vv = m_p @ m_p, m_p @ m_v, m_v @ m_v
    base, scale = float(np.sum(rest**2)), float(np.linalg.norm(y))

    def errors(trial) -> np.ndarray:
        trial = np.asarray(trial, float)
        levels_w = np.ascontiguousarray(w[j] * trial.ravel())
        sums = _coulomb_port_sums(acc_j, levels_w, 1.0 / fs, a, b)
        e2 = base - 2 * sums[:, 0] + pp * sums[:, 1] + 2 * pv * sums[:, 2] + vv * sums[:, 3]
        return (np.sqrt(np.maximum(e2, 0.0)) / scale).reshape(trial.shape)

    return errors


def _simulate(sys, u, fs, nl, delay_s=0.0, port_outputs=None, sens=None):
    """(y, p): :func:`simulate_nonlinear`'s measured outputs and the port displacements; with
    ``sens`` (:class:`workbench.sim.PortSensitivity`, its port velocity map's derivative
    ``Cv`` as ``dCp A``) also dy / dtheta, (N, n_y, n_th). Ports of the element's own
    (``nl.port_forces``, e.g. a mode's coordinate) instead of the inputs: every output is
    measured, the forces enter through ``nl.port_forces``."""
    if nl.port_forces is None:
        A, B, C, D, Cp, _ = _ports(sys, port_outputs)
        Bp = B  # the held input enters at the ports like the port forces
    else:
        if port_outputs is not None:
            raise InputError("nonlinear simulation: an element on its own ports takes no outputs")
        A, B, C, D, dt = lti.as_matrices(sys)
        if dt:
            raise InputError("nonlinear simulation: expected a continuous model (dt = 0)")
        Bp = np.asarray(nl.port_forces, float)
        Cp = np.asarray(nl.port_displacements, float)
        if Bp.ndim != 2 or Bp.shape[0] != A.shape[0] or Cp.shape != Bp.shape[::-1]:
            raise InputError(
                f"nonlinear simulation: expected port_forces ({A.shape[0]}, n_p) and "
                f"port_displacements (n_p, {A.shape[0]}), got {Bp.shape} and {Cp.shape}"
            )
    delay_s = float(delay_s) + float(getattr(sys, "delay_s", 0.0))  # the model's delay travels
    m = int(round(delay_s * fs))
    u = np.asarray(u, float)
    n_u = u.shape[1]
    ud = sim.delayed(u, m)
    if nl.saturation is not None:
        sat = np.broadcast_to(np.asarray(nl.saturation, float), (n_u,))
        ud = np.clip(ud, -sat, sat)
    if nl.friction_velocity == 0:  # hard Coulomb: event-exact, no substeps
        if nl.port_forces is None or sens is not None or np.any(nl.cubic_stiffness or 0.0):
            raise InputError(
                "nonlinear simulation: a hard Coulomb law (friction_velocity 0) acts on its "
                "own ports (port_forces), alone, without sensitivities"
            )
        return _simulate_coulomb(A, B, C, D, Bp, Cp, ud, fs, nl.friction_force)
    law = dict(
        friction_force=nl.friction_force,
        friction_velocity=nl.friction_velocity,
        cubic_stiffness=0.0 if nl.cubic_stiffness is None else nl.cubic_stiffness,
    )
    on = _port_states(A, Bp, Cp) if nl.port_forces is not None else None
    if on is None or on.all():
        # the held input with a whole-sample delay, the port forces directly
        prop = sim.substep_zoh(A, B, Bp, 1.0 / fs, nl.substeps)
        # the port velocity Cp A x (a displacement output has no feedthrough of force); the
        # compiled substep loop of the plants (trapezoidal port force, implicit friction)
        return prop.simulate(sim.PortLaw(Cv=Cp @ A, Cp=Cp, **law), ud, ud, C, D, sens=sens)
    # the element's own ports move only the states ``on`` (the others neither drive them nor
    # are driven by them): those substepped with the element, the others' linear response
    # (one ZOH step a sample) added, as :func:`_simulate_coulomb` adds it
    A_on = A[np.ix_(on, on)]
    prop = sim.substep_zoh(A_on, B[on], Bp[on], 1.0 / fs, nl.substeps)
    Cp_on = Cp[:, on]
    no_d = np.zeros_like(D)
    out = prop.simulate(
        sim.PortLaw(Cv=Cp_on @ A_on, Cp=Cp_on, **law), ud, ud, C[:, on], no_d, sens=sens
    )
    C_rest = np.array(C, float)
    C_rest[:, on] = 0.0
    return (_linear_rest(A, B, C_rest, D, ud, fs) + out[0],) + tuple(out[1:])


#: linear responses :func:`_linear_rest` keeps (a scan of an element's level simulates the
#: same model and input each time; the response is the same)
_REST_CACHE: dict = {}
_REST_CACHE_SIZE = 4


def _linear_rest(A, B, C_rest, D, ud, fs) -> np.ndarray:
    """(N, n_y) ZOH response ``C_rest x + D ud`` of ``x' = A x + B ud`` from rest, one exact
    step a sample: the states an element does not move (:func:`_port_states`). Kept for the
    next call with the same matrices and input (the latest _REST_CACHE_SIZE, by digest: a
    44-state beam's response takes ~6 ms, the spring's substeps on its mode ~1 ms)."""
    import hashlib

    h = hashlib.blake2b(digest_size=16)
    for M in (A, B, C_rest, D, ud):
        M = np.ascontiguousarray(M, dtype=float)
        h.update(repr(M.shape).encode())
        h.update(M.tobytes())
    h.update(repr(float(fs)).encode())
    key = h.digest()
    y = _REST_CACHE.pop(key, None)
    if y is None:
        Ad, B0, _, _ = sim.c2d_zoh(A, B, 1.0 / fs)
        y = sim.dlsim(Ad, B0, C_rest, D, ud)
        y.flags.writeable = False  # shared by the calls that ask for it again
    _REST_CACHE[key] = y  # the latest used last
    while len(_REST_CACHE) > _REST_CACHE_SIZE:
        _REST_CACHE.pop(next(iter(_REST_CACHE)))
    return y


def _port_states(A: np.ndarray, Bp: np.ndarray, Cp: np.ndarray) -> np.ndarray:
    """(n,) bool: the states an element on its own ports (force map ``Bp`` (n, n_p), port
    displacement ``Cp`` (n_p, n)) moves or reads, and every state that drives them: those the
    port forces enter and those they reach through ``A``, the ports' own states, then all that
    feed any of these through ``A`` (exact zeros of the realization: a mode's companion block,
    the actuator lags that drive it). The other states' response is the linear model's."""
    A = np.asarray(A, float)
    link = A != 0
    on = np.any(np.asarray(Bp) != 0, axis=1)
    while True:  # downstream: driven by a state on
        grown = on | np.any(link[:, on], axis=1)
        if (grown == on).all():
            break
        on = grown
    on = on | np.any(np.asarray(Cp) != 0, axis=0)
    while True:  # upstream: driving a state on
        grown = on | np.any(link[on, :], axis=0)
        if (grown == on).all():
            break
        on = grown
    return on


def fit_friction(
    sys,
    u: np.ndarray,
    y: np.ndarray,
    fs: float,
    *,
    friction_velocity: float | None = None,
    per_port: bool = False,
    substeps: int = 4,
    max_nfev: int = 40,
) -> tuple[PortNonlinearity, float, float]:
    """Fit Coulomb friction levels so that the simulation reproduces ``y``.

    Parameters
    ----------
    sys : workbench.core.model.LTIModel or control.StateSpace
        Continuous, square model (ports collocated with the inputs); an
        ``LTIModel``'s input delay is part of it (a ``StateSpace`` has none).
    u, y : (N, n_u), (N, n_y) arrays
        Recorded input and output (time data of spec 1a).
    friction_velocity : float, optional
        v0 of the smooth Coulomb law, m/s; default 1e-3 of the rms port velocity
        seen in ``y``.
    per_port : bool
        One level per input (else one level, N, for all).

    Returns
    -------
    (PortNonlinearity, error_before, error_after)
        The spec's time-domain relative error without and with the friction.
    """
    from workbench.core.model import as_model

    sys = as_model(sys)
    _ports(sys)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    if friction_velocity is None:  # Coulomb-like: far below the measured port velocities
        friction_velocity = 1e-3 * float(np.sqrt(np.mean((np.diff(y, axis=0) * fs) ** 2)))
    n_u = u.shape[1]

    def model(theta):
        level = np.exp(theta) * (np.ones(n_u) if per_port else np.ones(1))
        nl = PortNonlinearity(
            friction_force=level, friction_velocity=friction_velocity, substeps=substeps
        )
        return nl, simulate_nonlinear(sys, u, fs, nl)

    def residual(theta):
        return (model(theta)[1] - y).ravel() / np.linalg.norm(y)

    before = lti.relative_error_time(y, sim.simulate_zoh(sys, u, fs))
    # coarse grid on the common level, 1 mN .. 10 N, then least squares
    grid = np.log(np.logspace(-3, 1, 9))
    costs = [np.sum(residual(np.full(1, g)) ** 2) for g in grid]
    theta0 = np.full(n_u if per_port else 1, grid[int(np.argmin(costs))])
    sol = scipy.optimize.least_squares(residual, theta0, max_nfev=max_nfev, x_scale=1.0)
    nl, y_fit = model(sol.x)
    return nl, before, lti.relative_error_time(y, y_fit)


#: the port elements :func:`fit_port_element` tries
ELEMENTS = ("coulomb_friction", "cubic_stiffness", "saturation")
#: regressions of an element on the motion its own simulation model gives (estimated ports)
MOTION_ITERATIONS = 4
#: Gauss-Newton steps on the levels through the simulation model itself (estimated ports)
REFINE_ITERATIONS = 2
#: ... on a friction's levels and its velocity scale v0 (which may have to move several-fold
#: from its estimate, at most e^0.5 per step)
VELOCITY_ITERATIONS = 6
#: the final simulation's substeps are doubled until doubling moves the output by less than this
#: fraction of the misfit left: a coarse simulation adds an error of its own (the trapezoidal
#: port force is second order in the substep), largest where friction switches sign
CONVERGED = 0.25
#: ... up to this many substeps per sample
MAX_SUBSTEPS = 64
#: friction on the rigid-body motion (:class:`RigidPorts`) of bodies that are not free (the hard
#: law's event-exact simulation needs free ones, :func:`_coulomb_ports`) is the smooth law,
#: fitted at this many substeps and converged up to RIGID_MAX_SUBSTEPS (an indepgen stage
#: record at its true levels, v0 1e-8 m/s: 6.5 / 2.5 / 1.06x the noise at 16 / 64 / 256
#: substeps; 0.7 s a simulation at 256, where the event-exact one takes 3 ms)
RIGID_SUBSTEPS, RIGID_MAX_SUBSTEPS = 32, 256
#: ... its v0 estimated as this share of the rms port velocity (1e-3 at the inputs' ports): a
#: bearing's Coulomb friction is hard, and the rigid bodies' simulation resolves it (the
#: regression's law, free bodies' too)
RIGID_VELOCITY = 1e-4
#: ... its levels regressed at this high-pass corner too (a fraction of fs; :data:`HIGH_PASS`)
RIGID_HIGH_PASS = 1e-3
#: ... its levels started port by port within RIGID_SPAN either way, in RIGID_SWEEPS sweeps
RIGID_SPAN, RIGID_SWEEPS = 4.0, 1
#: ... and a free rigid port the regression left without friction (its level < 0, or adding
#: less than 5 % of the largest port's share) profiled (PROFILE_STEP) within RIGID_REVIVE_SPAN
#: either way of the other ports' level per unit of drive (the rms force the input applies at
#: the port; their median), and kept if that fits better than none: the
#: regression of a small level is unreliable in sign as well as size (an indepgen stage
#: record, friction subtle: a rotation's level regressed at -2.4x its truth at one high-pass
#: corner, another rotation's at -1.1x at the other), and a port dropped there was dropped for
#: good (the level fit 3.7x the floor without it, 1.00x from any level of it within 40x of the
#: truth)
RIGID_REVIVE_SPAN = 100.0
#: free rigid bodies' levels (the hard law) are then profiled port by port on the whole record
#: (:func:`coulomb_port_profile`) over a grid of this ratio within RIGID_REVIVE_SPAN either
#: way, refined to PROFILE_XATOL in the log, in at most PROFILE_SWEEPS sweeps: the error is
#: below the stuck body's plateau only within a few per cent of a level (an indepgen stage
#: record, friction clear: a rotation 0.98 / 1.02x its truth 45 / 33x the floor, the body held
#: by a level 10x its truth 95x, 0.5x 2100x), and a scan of a few per cent or a start several
#: times off (the regression put the two tilts 10x and 53x high) ends on that plateau
PROFILE_STEP, PROFILE_XATOL, PROFILE_SWEEPS = 10.0**0.005, 1e-3, 3
#: ... the sweeps after the first within this factor either way of each port's level (the
#: ports' motions are independent: what moves a port's best level there is only the others'
#: share of the outputs it shows on)
PROFILE_LOCAL = 1.2
#: rounds of (converge the substeps, refit the levels there)
CONVERGE_ROUNDS = 3
#: ... not run when the levels fitted at the first count leave more than this many times the
#: error the caller needs (``give_up_above``): converging lowers a fit's error by a few times
#: (an indepgen stage record at its true levels: 6.5 / 2.5 / 1.06x the noise at 16 / 64 / 256
#: substeps), not by tens (an indep3 shaft record with a suspension: friction on its rigid
#: body 1.16 at 32 substeps where 0.02 was needed, 75 of the fit's 77 s converging it)
COARSE_MARGIN = 10.0
#: friction's Gauss-Newton uses the exact Jacobian while a step lowers the squared error by at
#: least this share of what the Jacobian's linear model predicts (the trust-region ratio test)
MODEL_TRUST = 0.25
#: the friction's v0 is fitted within this factor either way of its estimate (1e-3 of the rms
#: port velocity): far below it the law is a step the substeps cannot resolve, far above it a
#: viscous damper (a linear effect); a free v0 may run off to either on a poor start
VELOCITY_RANGE = 100.0
#: the port gains of a square model's non-collocated modes (:class:`SquarePorts`) start from
#: the best of this grid (a common factor on each mode's |N0_k|_2, the gain if the sensor and
#: actuator shapes had the same size), at the element's regressed levels
GAIN_GRID = np.logspace(-3.0, 1.0, 9)
#: ... and are fitted within [GAIN_RANGE[0], GAIN_RANGE[1]] x |N0_k|_2
GAIN_RANGE = (1e-4, 10.0)
#: ... and their joint Gauss-Newton stops when a step lowers the error by less than this fraction
GAIN_STOP = 1e-3
#: with them, the regressed levels are first scaled by the common factor, within this factor
#: either way, whose simulation fits best (a grid of this ratio, then a 1-D search)
LEVEL_SPAN, LEVEL_STEP = 10.0, 10.0**0.1
#: Gauss-Newton steps on the levels, v0 and the gains (it stops earlier on GAIN_STOP)
GAIN_ITERATIONS = 10
#: friction's Gauss-Newton through the simulation runs on the record's first fractions, each
#: from the shorter one's levels (continuation, as for saturation): from rest, a level error
#: drifts the rigid bodies more the longer the record, the misfit over the whole record is rough
#: in the levels (Gauss-Newton from 3-50 % off stalled at 4.8x the noise on an indepgen stage
#: record), over its first sixteenth nearly quadratic (0.2 % off the true levels there, 1.8x)
FRICTION_HORIZONS = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0)
#: the port gains' grid and the levels' common scale are judged on the record's first fraction
START_HORIZON = 1 / 8
#: the friction levels are regressed on the residual and the regressors high-passed at this
#: fraction of the sampling frequency, order HIGH_PASS_ORDER: a from-rest record of a rigid
#: body integrates any error of the law's regressor twice (the sign of a noisy velocity near
#: reversals, sticking), a drift that dominates the residual's low frequencies and biased the
#: levels of an indepgen stage record 2-30x low (some negative); high-passed, 1-5 % off on its
#: translations
HIGH_PASS = 0.01
HIGH_PASS_ORDER = 4
#: residual evaluations of each of the saturation levels' least-squares fits (a level a port)
SATURATION_NFEV = 60
#: ... fitted on the record's first fractions, each from the shorter one's levels
SATURATION_HORIZONS = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1)
#: shares of the samples clipped that the saturation levels are first scanned over (a common
#: quantile of |u| for all inputs), down to one sample an input: a slight clipping of a closed
#: loop's command (a few peaks a period) leaves a drift far above the noise in a from-rest
#: simulation of a rigid body, which a level clipping 0.1 % of the samples misses by far
SATURATION_SHARES = (0.5, 0.3, 0.2, 0.1, 0.05, 0.02, 0.01, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4)
#: ... then each input's level between two of its this many largest |u| (clipping a few peaks),
#: in this many sweeps over the inputs
SATURATION_PEAKS, SATURATION_SWEEPS = 12, 2
#: an input the levels' least squares leaves unclipped is profiled over the levels clipping up
#: to this share of its samples (the generator's clear saturation clips 10 %)
SATURATION_PROFILE = 0.1


@dataclass(frozen=True)
class ElementFit:
    """A port nonlinearity fitted to a record (:func:`fit_port_element`).

    Attributes
    ----------
    element : str
        One of :data:`ELEMENTS`.
    ports : tuple of int
        Inputs (collocated ports) where the element acts, 0-based.
    parameters : dict
        ``friction_force`` (N per port) and ``friction_velocity`` (m/s), or
        ``cubic_stiffness`` (N/m^3 per port), each with the ``substeps`` per sample of its
        simulation; or ``saturation`` (N per input; inf = none). On a
        :class:`SquarePorts` model also ``port_gains`` (m/N, the fitted ``|b_k|^2`` per
        non-collocated mode) and ``port_gain_freq_hz`` (those modes' frequencies, Hz).
    nonlinearity : PortNonlinearity
        The element as a simulation model.
    error_before, error_after : float
        Spec time-domain error of the linear model and of the nonlinear simulation model.
    candidates : dict
        Every element tried: its error predicted by the regression (``{element: error}``).
    level : float
        The share of the record's power that the element adds to the linear model's
        response to the recorded input, ``||y_element - y_linear||^2 / ||y||^2`` (both
        simulated from rest, at most 1): the spec's nonlinearity ``level``, "the share of
        output power not explained by a linear model", with the linear model the one the
        element sits on. On a rigid body it includes the drift the clipped or resisted force
        integrates to, and may reach 1.
    output : (N, n_y) array or None
        Friction or a spring: the nonlinear simulation model's outputs (the measured ones) that
        ``error_after`` is the error of, the fit's own run (read-only), for a caller that needs
        them again (a simulation at 64 substeps takes ~0.5 s on a stage record). None for
        saturation.
    """

    element: str
    ports: tuple[int, ...]
    parameters: dict
    nonlinearity: PortNonlinearity
    error_before: float
    error_after: float
    candidates: dict
    level: float = float("nan")
    output: np.ndarray | None = field(default=None, repr=False, compare=False)


def _saturation_scan(lin, meas, u, y, fs):
    """(levels (n_u,), error): the best common quantile of |u| as every input's level (N), the
    linear model ``lin``'s outputs ``meas`` driven by the clipped input against ``y``."""
    amp = np.abs(u)
    best_sat, best_err = None, np.inf
    for share in SATURATION_SHARES:
        if share * amp.shape[0] < 1.0:
            break  # less than a sample clipped
        level = np.quantile(amp, 1.0 - share, axis=0)
        y_sat = sim.simulate_zoh(lin, np.clip(u, -level, level), fs)[:, meas]
        err = lti.relative_error_time(y, y_sat)
        if err < best_err:
            best_sat, best_err = level, err
    return best_sat, float(best_err)


def _refine_saturation(lin, meas, u, y, fs, level, err):
    """(levels, error): one saturation level per input by least squares through the linear
    simulation of the clipped input, from the common quantile's levels. The quantile grid
    gives every input the same share of clipped samples; a closed loop's inputs differ (its
    controller's command is not the recorded input's scaled copy), and a from-rest
    simulation of a rigid body integrates a level error twice (an indepgen stage record:
    6026x the floor at the best quantile, 0.1 % off the true levels 270x). Over the whole
    record that makes the misfit rough in the levels (local minima 0.5 % apart: a fit on
    it stalled at 528x), over its start it is nearly quadratic: the levels are fitted on
    growing first parts of the record (SATURATION_HORIZONS), each from the shorter one's
    (continuation; 1.00x there). The output is linear in the clipped input, so the
    Jacobian is exact: d clip(u_j, l_j) / d ln l_j = l_j sign(u_j) where |u_j| > l_j,
    simulated per input."""
    amp = np.abs(u)
    active = np.flatnonzero(np.isfinite(level) & (level > 0))
    if active.size == 0:
        return level, err
    norm = np.linalg.norm(y)
    top = amp.max(axis=0)[active]

    def levels(theta):
        out = np.array(level, float)
        out[active] = np.exp(theta)
        return out

    def resid(theta, n):
        lv = levels(theta)
        y_n = sim.simulate_zoh(lin, np.clip(u[:n], -lv, lv), fs)[:, meas]
        return (y_n - y[:n]).ravel() / norm

    def jac(theta, n):
        lv = levels(theta)
        cols = []
        for j in active:
            d = np.zeros_like(u[:n])
            over = amp[:n, j] > lv[j]
            d[over, j] = np.sign(u[:n][over, j]) * lv[j]
            cols.append(sim.simulate_zoh(lin, d, fs)[:, meas].ravel() / norm)
        return np.stack(cols, -1)

    # a level above an input's largest |u| clips nothing there: the box ends at it
    lo = np.log(np.maximum(np.quantile(amp, 0.05, axis=0)[active], 1e-300))
    hi = np.log(np.maximum(top, 1e-300))
    if not np.all(lo < hi):
        return level, err
    theta = np.clip(np.log(level[active]), lo, hi)
    for frac in SATURATION_HORIZONS:
        n = max(int(frac * u.shape[0]), 1)
        theta = scipy.optimize.least_squares(
            resid,
            theta,
            jac=jac,
            bounds=(lo, hi),
            method="trf",
            max_nfev=SATURATION_NFEV,
            args=(n,),
        ).x
    lv = levels(theta)
    e_new = lti.relative_error_time(y, sim.simulate_zoh(lin, np.clip(u, -lv, lv), fs)[:, meas])
    return (lv, float(e_new)) if e_new < err else (level, err)


def _scan_peaks(
    lin,
    meas,
    u,
    y,
    fs,
    level,
    err,
    *,
    sweeps: int = SATURATION_SWEEPS,
    peaks: int = SATURATION_PEAKS,
):
    """(levels, error): each input's level in turn (the others held; ``sweeps`` sweeps,
    SATURATION_SWEEPS by default) at the best level clipping at most ``peaks`` of its
    samples (:func:`_level_profile`, exact); kept where it lowers the error. A slight
    clipping (a few peaks of a closed loop's command) makes the error steep in the level
    (a from-rest simulation of a rigid body: 0.1 % off the level, 50x the noise) with a
    kink at every peak: the least squares of :func:`_refine_saturation` stays between the
    peaks it starts between, which the common quantile's level may not be."""
    level = np.array(level, float)
    for _ in range(sweeps):
        for j in range(u.shape[1]):
            if np.unique(np.abs(u[:, j])).size < 2:
                continue
            x, e = _level_profile(lin, meas, u, y, fs, level, j, peaks)
            if e < err:
                level[j], err = x, e
    return level, err


def _level_profile(lin, meas, u, y, fs, level, j: int, k_max: int):
    """(level_j, error): input ``j``'s saturation level that fits best over every level
    clipping at most ``k_max`` of its samples, the other inputs' ``level`` held; exact.

    Between two consecutive amplitudes of input j the clipped samples are the same and
    their excess over the level changes linearly with it: the output changes by the level's
    change times the response ``T`` to the clipped samples' signs, so the residual is linear
    and the error squared quadratic in the level there, its minimum over the piece in closed
    form. Going down the amplitudes, each new clipped sample adds its shifted pulse response
    to ``T`` (the simulation from rest is linear and shift-invariant). The error is rough in
    the level (a from-rest rigid body: a valley 0.3 % wide, 25x the noise either side of it),
    which no local search crosses: an indepgen closed-loop stage record whose least squares
    left one input unclipped at 6.8x the noise floor reaches the floor from this level."""
    amp = np.abs(u[:, j])
    n = u.shape[0]
    order = np.argsort(-amp, kind="stable")[: min(k_max, n - 1) + 1]
    pulse = np.zeros_like(u)
    pulse[0, j] = 1.0
    h = sim.simulate_zoh(lin, pulse, fs)[:, meas]
    free = np.array(level, float)
    free[j] = np.inf
    rho = y - sim.simulate_zoh(lin, np.clip(u, -free, free), fs)[:, meas]  # nothing clipped on j
    T = np.zeros_like(rho)
    # flat views: the products below as dot products, no temporaries (the loop runs once per
    # clipped sample, up to a tenth of the record)
    rho_f, T_f = rho.ravel(), T.ravel()
    best_sq, best_level = float(rho_f @ rho_f), float(amp[order[0]])
    for i, k in enumerate(order[:-1]):
        T[k:] += np.sign(u[k, j]) * h[: n - k]  # the samples down to amplitude amp[k] clip
        a, b = amp[k], amp[order[i + 1]]
        if a <= b:
            continue  # a tie: the next sample joins at the same level
        # rho(a - t) = rho(a) + t T over 0 <= t <= a - b
        tt, rt = float(T_f @ T_f), float(rho_f @ T_f)
        t = min(max(-rt / tt, 0.0), a - b) if tt > 0 else 0.0
        sq = float(rho_f @ rho_f) + 2 * t * rt + t * t * tt
        if sq < best_sq:
            best_sq, best_level = sq, float(a - t)
        rho += (a - b) * T
    return best_level, float(np.sqrt(max(best_sq, 0.0)) / np.linalg.norm(y))


def saturation_first_order(lin, meas, u, y, fs, period: int | None = None) -> float:
    """The error a saturation of the inputs reaches at a first look (the screen of
    :func:`first_order_errors`): the quantile scan, then one sweep of :func:`_scan_peaks`
    over each input's largest peaks. The scan alone gives every input the same share of
    clipped samples; a slight clipping of an open-loop record of a free body (each input's
    top peak or two, by 0.1-1 %) drifts far above the noise, and no common quantile comes
    near it (an indepgen free-free beam: 0.0515 at the scan's best, the model's own error;
    0.021 after one sweep, 0.125 s; the fit 0.0143, the noise floor).

    ``period`` (samples): a periodic record repeats each peak once a period, so the sweep
    takes SATURATION_PEAKS peaks of every period (an indepgen beam record of ten periods,
    its inputs clipped at their two largest peaks, 20 samples each: the sweep over 12
    samples left the model's own error, 3.35x the floor, and the screen kept the fit out;
    over 120, 1.15x; the fit 1.00x)."""
    level, err = _saturation_scan(lin, meas, u, y, fs)
    if level is None:  # fewer samples than any share clips
        return err
    repeats = max(1, u.shape[0] // period) if period else 1
    peaks = SATURATION_PEAKS * repeats
    return _scan_peaks(lin, meas, u, y, fs, level, err, sweeps=1, peaks=peaks)[1]


def _fit_saturation_levels(lin, meas, u, y, fs, *, refine=True):
    """(levels (n_u,) N, error): the saturation of the inputs that explains ``y`` best, the
    linear model ``lin`` (outputs ``meas`` measured) driven by the clipped recorded input:
    the quantile scan, then (``refine``) the levels per input between the largest peaks and
    through the simulation. Least squares, peaks, least squares again: the peak scan lowers
    the whole record's error one input at a time and, from the quantile's levels, may do so
    by leaving unclipped an input that is clipped (an indepgen stage record, 10 % of the
    samples clipped on every input: least squares from there end at 412x the noise floor),
    while from the least squares' levels it moves only the inputs whose level sits between
    the wrong peaks (a slight clipping of the same generator: 9.6x after the first least
    squares, 1.00x after the second; the strong one 1.00x after the first)."""
    level, err = _saturation_scan(lin, meas, u, y, fs)
    if refine:
        level, err = _refine_saturation(lin, meas, u, y, fs, level, err)
        level, err = _scan_peaks(lin, meas, u, y, fs, level, err)
        level, err = _refine_saturation(lin, meas, u, y, fs, level, err)
        # an input's level may sit in a valley beside the right one (the least squares left
        # it unclipped, at its largest |u|, the box's end; or clipping: an indepgen stage
        # record, 7-11 % of each input's samples clipped, five levels right to 1e-8 and the
        # sixth 34 % high, 88x the noise floor): each input's exact profile over the levels
        # clipping up to SATURATION_PROFILE of its samples (0.1 s an input on a 10 000-sample
        # stage record; there 1.00x), then the least squares again
        k_max = max(int(SATURATION_PROFILE * u.shape[0]), SATURATION_PEAKS)
        moved = False
        for j in np.flatnonzero(np.isfinite(level)):
            x, e = _level_profile(lin, meas, u, y, fs, level, j, k_max)
            if e < err:
                level[j], err, moved = x, e, True
        if moved:
            level, err = _refine_saturation(lin, meas, u, y, fs, level, err)
    return level, err


#: runs of a simulation model that :func:`fit_port_element` keeps for reuse (the latest; a
#: stage record's run is about 0.6 MB)
SIMULATION_CACHE = 8


def _between_neighbours(cost, grid: np.ndarray, errs: list, i: int, xatol: float):
    """(x, cost) of a 1-D scan's best: the grid's point ``i`` (its cost ``errs[i]``) or a
    bounded search between its neighbours on ``grid`` (clipped to its ends), the lower."""
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    sol = scipy.optimize.minimize_scalar(
        cost, bounds=(lo, hi), method="bounded", options={"xatol": xatol}
    )
    return (float(sol.x), float(sol.fun)) if sol.fun < errs[i] else (grid[i], errs[i])


def _run_key(nl: PortNonlinearity, g) -> tuple:
    """What a simulation run of :func:`fit_port_element` depends on besides the record: the
    element's every field and the port gains ``g`` (None or (n_g,) m/N), as bytes."""

    def raw(a):
        return None if a is None else (np.shape(a), np.asarray(a, float).tobytes())

    return (
        raw(nl.friction_force),
        float(nl.friction_velocity),
        raw(nl.cubic_stiffness),
        raw(nl.saturation),
        int(nl.substeps),
        raw(nl.port_forces),
        raw(nl.port_displacements),
        raw(g),
    )


class _RunCache:
    """The latest ``size`` simulation runs (outputs y (N, n_y), ports p (N, n_p), read-only),
    each under its :func:`_run_key`; a run serves any request over as many samples or fewer
    (its first rows: a run from rest is causal)."""

    def __init__(self, size: int):
        self.size = size
        self.runs: dict = {}

    def get(self, key, n: int):
        """(y[:n], p[:n]) of a kept run of ``key`` over at least ``n`` samples, or None."""
        hit = self.runs.get(key)
        if hit is None or hit[0].shape[0] < n:
            return None
        self.runs[key] = self.runs.pop(key)  # the latest used last
        return hit[0][:n], hit[1][:n]

    def put(self, key, y: np.ndarray, p: np.ndarray) -> None:
        """Keep (y, p) under ``key`` unless a run as long is kept; the oldest dropped."""
        old = self.runs.pop(key, None)
        if old is not None and old[0].shape[0] >= y.shape[0]:
            y, p = old
        y, p = np.asarray(y), np.asarray(p)
        y.flags.writeable = False  # shared with the callers: none may write into it
        p.flags.writeable = False
        self.runs[key] = (y, p)
        while len(self.runs) > self.size:
            self.runs.pop(next(iter(self.runs)))


def fit_port_element(
    sys,
    u: np.ndarray,
    y: np.ndarray,
    fs: float,
    *,
    substeps: int = 4,
    port_outputs=None,
    motion: np.ndarray | None = None,
    refine: bool = True,
    give_up_above: float | None = None,
    saturation: ElementFit | None = None,
) -> ElementFit:
    """Which port nonlinearity explains the record: Coulomb friction, a cubic spring or saturation.

    Parameters
    ----------
    sys : LTIModel, control.StateSpace, SquarePorts or ModalPort
        The linear model (continuous, square: output j measures the displacement where
        input j pushes; or with its port displacements as extra outputs, ``port_outputs``);
        an LTIModel's delay is part of it. A :class:`SquarePorts` (:func:`square_ports`):
        a square model some of whose modes are not collocated; their port gains are
        fitted with the element (``parameters["port_gains"]``, m/N per mode, and
        ``parameters["port_gain_freq_hz"]``, the modes' frequencies). A
        :class:`ModalPort`: one port on a mode's coordinate, every output measured; only
        the cubic spring is tried there (a modal Duffing: ``parameters["cubic_stiffness"]``
        one k3 in modal units, ``"mode"`` the mode's index in the model, ``"mode_freq_hz"``
        its frequency); ``ports`` of the result is empty (no input is the port). A
        :class:`RigidPorts`: friction on the rigid bodies' motion only (one level per input,
        ``parameters["on"] == "rigid_modes"``), started from the regression at two high-pass
        corners scaled by a common factor; on free rigid bodies the hard law, simulated
        event-exact (``friction_velocity`` 0, ``substeps`` 1), each port's level profiled on
        the whole record (PROFILE_STEP within RIGID_REVIVE_SPAN; a port the regression left
        without friction from the others' level per unit of drive) and refined by
        Gauss-Newton through that simulation; else, scaled port by port, the smooth law at
        RIGID_SUBSTEPS .. RIGID_MAX_SUBSTEPS.
    u, y : (N, n_u), (N, n_y) arrays
        Recorded input and output.
    fs : float
        Sampling frequency, Hz.
    substeps : int
        Substeps per sample of the simulations that fit the levels. The reported model
        (with ``refine``) is simulated with as many substeps as its output needs to
        converge (doubled while doubling moves the output by more than
        :data:`CONVERGED` of the misfit, up to :data:`MAX_SUBSTEPS`), its levels refitted
        there; ``parameters["substeps"]`` says how many.
    port_outputs : sequence of int, optional
        The outputs of ``sys`` that are the port displacements (:func:`with_ports`); the
        others are the measured ones, ``y``.
    motion : (N, n_u) array, optional
        Port displacements to regress on. Default: the measured output (square model),
        else the linear model's simulated ports (a linear model closer to the record,
        e.g. one with the linear effects a diagnosis found, gives a better estimate).
    refine : bool
        With estimated ports: refine the levels by Gauss-Newton through the simulation
        model (a few simulations more; False to compare hypotheses cheaply).
    give_up_above : float, optional
        The error the element must go below to be of use (a caller's). When the levels
        fitted at ``substeps`` leave more than :data:`COARSE_MARGIN` times it, the
        simulation's substeps are not converged (each finer count refits the levels
        through hundreds of simulations) and the coarse fit is returned
        (``parameters["substeps"]`` says at which count).
    saturation : ElementFit, optional
        A saturation of the inputs already fitted on this linear model
        (:func:`fit_saturation`: it needs no port, so it is the same on every hypothesis of
        where the ports are): taken as the saturation candidate, not fitted again.

    Notes
    -----
    Friction and the cubic spring are forces at the ports that depend on the port
    motion, ``-F_j tanh(v_j / v0)`` and ``-k_j p_j^3``: with the motion taken from the
    measured output (or its estimate, ``motion``), the output they add is linear in
    ``F_j`` / ``k_j`` (the linear model driven by the signal at port j), so each is a
    least-squares regression of the linear model's residual (equation error in the
    nonlinearity, output error in the dynamics). Saturation is scanned over levels of
    |u| (the linear model driven by the clipped input). The best element is then
    simulated with :func:`simulate_nonlinear` and its error is the one reported.
    When the port motion is not measured (``port_outputs``, no ``motion`` given, or an
    estimate), the regression is repeated on the motion that the element's own simulation
    model gives (at the true level that is the true motion: a consistent fixed point), and
    the levels are then refined on the simulation model's output error (``refine``).
    """

    from workbench.core.model import as_model

    family = sys if isinstance(sys, SquarePorts) else None
    modal = sys if isinstance(sys, ModalPort) else None
    rigid = sys if isinstance(sys, RigidPorts) else None
    if (family is not None or modal is not None or rigid is not None) and port_outputs is not None:
        raise InputError(f"fit_port_element: a {type(sys).__name__} sets its own ports")
    if family is not None:
        port_outputs = family.port_outputs
        # any gains: the measured outputs (and the regressors below) do not depend on them
        lin = as_model(family.system(family.unit))
    elif modal is not None:
        lin = as_model(modal.lti)
    elif rigid is not None:
        lin = as_model(rigid.lti)
    else:
        lin = as_model(sys)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    n_u = u.shape[1]
    if modal is not None or rigid is not None:
        meas = np.arange(lin.C.shape[0])  # every output measured, the ports the element's
        Bp, Cp = (modal or rigid).maps
    else:
        _, _, _, _, _, meas = _ports(lin, port_outputs)
    n_p = n_u if modal is None else 1  # ports: the inputs', or the mode's coordinate
    max_substeps = MAX_SUBSTEPS
    # friction on free rigid bodies: the hard Coulomb law, its stick-slip events exact (no
    # substeps, :func:`_coulomb_record`); the smooth law needed 256 substeps at its v0 to come
    # within 1.06x the noise of an indepgen stage record (the generator's law is the hard one)
    hard = rigid is not None and _coulomb_ports(*lti.as_matrices(lin)[:2], Bp, Cp) is not None
    if hard:
        substeps = max_substeps = 1
    elif rigid is not None:  # a simulation of the rigid bodies alone: cheap, and steep in the
        # substeps at the small v0 of hard Coulomb friction (RIGID_SUBSTEPS)
        substeps, max_substeps = max(substeps, RIGID_SUBSTEPS), RIGID_MAX_SUBSTEPS
    y_all = sim.simulate_zoh(lin, u, fs)
    y_lin = y_all[:, meas]
    before = lti.relative_error_time(y, y_lin)
    port, measured_ports, motion, _, v0 = _port_motion(
        lin,
        u,
        y,
        y_all,
        fs,
        (Bp, Cp) if modal is not None or rigid is not None else None,
        n_p=n_p,
        modal=modal,
        rigid=rigid,
        family=family,
        port_outputs=port_outputs,
        motion=motion,
    )
    log_v_bounds = np.log(v0) + np.log(VELOCITY_RANGE) * np.array([-1.0, 1.0])
    drive = None
    if rigid is not None:  # the rms force the input applies at each rigid port (its units):
        # the port's acceleration from the input over its acceleration per unit port force
        A_l, B_l = lti.as_matrices(lin)[:2]
        mobility = np.diag(Cp @ A_l @ Bp)
        acc = u @ (Cp @ A_l @ B_l).T
        with np.errstate(divide="ignore", invalid="ignore"):
            drive = np.where(mobility > 0, np.sqrt(np.mean(acc**2, axis=0)) / mobility, 0.0)
    log_g_bounds = None
    if family is not None:
        log_g_bounds = np.log(family.unit)[None, :] + np.log(GAIN_RANGE)[:, None]  # (2, n_g)

    def system(g):
        """The linear model the simulation runs: with its port gains ``g`` (SquarePorts)."""
        return lin if g is None else system_with(np.asarray(g, float).tobytes())

    @functools.lru_cache(maxsize=SIMULATION_CACHE)
    def system_with(g_bytes):
        """:func:`system` of the gains given as bytes (a scan asks for the same gains again;
        building the model takes about 2 ms)."""
        return as_model(family.system(np.frombuffer(g_bytes)))

    @functools.cache
    def port_map_derivative():
        """dCp / dg_k of the port gains (SquarePorts), (n_g, n_u, n)."""
        return family.port_map_derivative()

    def law(name, p):
        if name == "coulomb_friction":
            return np.tanh(np.gradient(p, 1.0 / fs, axis=0) / v0)
        return p**3

    def regress(name, common, p, high_pass=HIGH_PASS):
        """Levels (n_p,) >= 0 of element ``name`` by least squares, the motion ``p`` given;
        friction's on the residual and the regressors high-passed (:data:`HIGH_PASS`; causal,
        both start from rest): its law's errors, not its level, dominate their low frequencies."""
        phi = law(name, p)
        # regressor j: the output of a unit force law at port j, with the minus sign of a
        # resisting force
        X = np.stack(
            [
                -sim.simulate_zoh(port, np.eye(n_p)[j] * phi[:, [j]], fs)[:, meas]
                for j in range(n_p)
            ],
            -1,
        )  # (N, n_meas, n_p)
        r = y - y_lin
        if name == "coulomb_friction":
            sos = scipy.signal.butter(HIGH_PASS_ORDER, high_pass * fs, "high", fs=fs, output="sos")
            X = scipy.signal.sosfilt(sos, X, axis=0)
            r = scipy.signal.sosfilt(sos, r, axis=0)
        X = X.reshape(-1, n_p)
        Xc = X.sum(axis=1, keepdims=True) if common else X
        scale = np.linalg.norm(Xc, axis=0)
        ok = scale > 0
        c = np.zeros(Xc.shape[1])
        if ok.any():
            c[ok] = np.linalg.lstsq(Xc[:, ok] / scale[ok], r.ravel(), rcond=None)[0]
            c[ok] /= scale[ok]
        # a friction level or a hardening spring is >= 0; a port whose element adds less than
        # 5 % of the largest port's share of the output is none. Friction's compared by what
        # they add, not by level: N and N m at ports of different inertia (an indepgen stage's
        # rotations, 1-2 % of its translations' levels, drift 60x its noise without theirs).
        # The spring's by level, as before (the rule by share is not validated on its cases)
        c = np.maximum(c, 0.0)
        share = c * scale if name == "coulomb_friction" else c
        c[share < 0.05 * share.max()] = 0.0
        return np.broadcast_to(c, (n_p,)).copy()

    def make_element(name, c, n_sub=substeps, v=None, g=None):
        """(PortNonlinearity, parameters); ``g``: the port gains (SquarePorts), reported."""
        gains = {}
        if g is not None:
            gains = {
                "port_gains": [float(x) for x in g],
                "port_gain_freq_hz": family.freq_hz(),
            }
        if name == "coulomb_friction":
            v = (0.0 if hard else v0) if v is None else float(v)
            own = {}
            if rigid is not None:  # on the rigid-body motion, not through B
                own = {"port_forces": Bp, "port_displacements": Cp}
                gains = {"on": "rigid_modes"}
            nl = PortNonlinearity(friction_force=c, friction_velocity=v, substeps=n_sub, **own)
            params = {"friction_force": [float(x) for x in c], "friction_velocity": v}
            return nl, params | {"substeps": n_sub} | gains
        if modal is not None:
            nl = PortNonlinearity(
                friction_force=np.zeros(n_p),
                cubic_stiffness=c,
                substeps=n_sub,
                port_forces=Bp,
                port_displacements=Cp,
            )
            where = {"mode": modal.mode, "mode_freq_hz": modal.freq_hz}
            return nl, {"cubic_stiffness": [float(x) for x in c], "substeps": n_sub} | where
        nl = PortNonlinearity(friction_force=np.zeros(n_u), cubic_stiffness=c, substeps=n_sub)
        return nl, {"cubic_stiffness": [float(x) for x in c], "substeps": n_sub} | gains

    def gains_of(params):
        g = params.get("port_gains")
        return None if g is None else np.asarray(g, float)

    runs = _RunCache(SIMULATION_CACHE)

    def run(nl, g, n, sens):
        """``_simulate``'s (y, p[, dy]) of the record's first ``n`` samples (None: all), the
        (y, p) of a run of the same model over at least as many samples reused: the fit
        simulates a model again (a scan's best point, a converged count's own output, a
        trial the Jacobian's run repeats), and a run from rest over a record's first part
        is the first part of the run over a longer one (the same arithmetic, sample by sample)."""
        n_run = u.shape[0] if n is None else min(n, u.shape[0])
        key = _run_key(nl, g)
        if sens is None:
            hit = runs.get(key, n_run)
            if hit is not None:
                return hit
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging trial scores inf
            out = _simulate(system(g), u[:n_run], fs, nl, 0.0, port_outputs, sens=sens)
        runs.put(key, out[0], out[1])
        return out

    def simulated(nl, g=None, *, residual=False, output=False, n=None, sens=None):
        """(error, simulated port motion) of the nonlinear simulation model with port gains
        ``g`` (SquarePorts; None otherwise), or its residual, or its output; the residual
        over the record's first ``n`` samples if given (relative to their norm). With ``sens``
        (:class:`workbench.sim.PortSensitivity`; the residual only) the residual's exact
        Jacobian (N n_y, n_th) in place of the port motion."""
        out = run(nl, g, n, sens)
        y_nl, p_nl = out[:2]
        if not np.all(np.isfinite(y_nl)):
            return np.inf, None
        if residual:
            scale = np.linalg.norm(y[:n])
            if sens is not None:
                return (y_nl - y[:n]).ravel() / scale, out[2].reshape(y_nl.size, -1) / scale
            return (y_nl - y[:n]).ravel() / scale, p_nl
        if output:
            return y_nl, p_nl
        return float(lti.relative_error_time(y, y_nl)), p_nl

    def rms(r):
        """The relative error of a residual (inf for a diverged simulation's)."""
        return float(np.sqrt(r @ r)) if np.all(np.isfinite(r)) else np.inf

    # friction's starts of the gains and of the levels' scale are judged on the record's first
    # part (START_HORIZON): a level's misfit grows with the drift it causes, and is smoother
    # there (the spring's on the whole record, as before: not validated on its cases)
    def start_n(name):
        return max(int(START_HORIZON * u.shape[0]), 2) if name == "coulomb_friction" else None

    def converged_substeps(name, c, n_sub, v=None, g=None):
        """Substeps, from ``n_sub`` up, at which the element's simulation is converged."""
        if hard and name == "coulomb_friction":
            return n_sub  # event-exact: no substeps to converge
        y_n = simulated(make_element(name, c, n_sub, v)[0], g, output=True)[0]
        while n_sub < max_substeps and np.all(np.isfinite(y_n)):
            y_2n = simulated(make_element(name, c, 2 * n_sub, v)[0], g, output=True)[0]
            if not np.all(np.isfinite(y_2n)):
                break
            n_sub *= 2
            change = np.linalg.norm(y_2n - y_n) / np.linalg.norm(y)
            misfit = lti.relative_error_time(y, y_2n)
            y_n = y_2n
            if change <= CONVERGED * misfit:
                break
        return n_sub

    def refine_levels(name, c, n_sub=substeps, v=None, g=None, *, free_gains=True):
        """Gauss-Newton on the log levels of the active ports, through the simulation model;
        for friction on log v0 too (the smooth law's velocity scale: the estimate above only
        sets its order, and its shape near sticking is what is left of the misfit), within
        VELOCITY_RANGE of its estimate; with port gains ``g`` (SquarePorts) on their logs too,
        within GAIN_RANGE (the levels and the gains are coupled: the gains set how far the
        sticking ports hold the non-collocated modes, fitted alone at fixed levels they are
        biased; ``free_gains=False`` holds them). Steps leaving the bounds are cut back to
        them (projected). Friction's on the record's growing first parts
        (:data:`FRICTION_HORIZONS`), each from the shorter one's; the candidates are those
        of the whole record. The hard law (free rigid bodies) has no v0 and no sensitivities:
        its levels only, by forward differences."""
        active = np.flatnonzero(c > 0)
        if active.size == 0:  # no element to refine
            return []
        friction = name == "coulomb_friction"
        n_lvl = active.size
        smooth = friction and not hard  # the hard law has no v0 and no sensitivities
        n_v = int(smooth)
        fit_g = g is not None and free_gains
        out = []

        def unpack(theta):
            levels = np.zeros(n_p)
            levels[active] = np.exp(theta[:n_lvl])
            vel = float(np.exp(theta[n_lvl])) if smooth else None
            gains = np.exp(theta[n_lvl + n_v :]) if fit_g else g
            return levels, vel, gains

        def resid(theta, n=None):
            levels, vel, gains = unpack(theta)
            nl = make_element(name, levels, n_sub, vel)[0]
            return simulated(nl, gains, residual=True, n=n)[0]

        def resid_jac(theta, n):
            """(residual, its Jacobian in theta): friction's exact, from the sensitivities
            the simulation computes alongside (the derivative of the simulation as computed),
            at about 2-3 simulations' cost for the stage's 9 parameters where finite
            differences take 10; the spring's None (finite differences below)."""
            if not smooth:
                return resid(theta, n), None
            levels, vel, gains = unpack(theta)
            n_th = theta.size
            dFc = np.zeros((n_th, n_u))
            dFc[np.arange(n_lvl), active] = levels[active]  # d F_c / d log F_c
            dlv = np.zeros(n_th)
            dlv[n_lvl] = 1.0
            dCv = None
            if fit_g:  # d Cv / d log g_k = g_k dCp/dg_k A (the port velocity is Cp A x)
                A = np.asarray(system(gains).A, float)
                dCv = np.zeros((n_th, n_u, A.shape[0]))
                dCv[n_lvl + n_v :] = gains[:, None, None] * (port_map_derivative() @ A)
            sens = sim.PortSensitivity(friction_force=dFc, log_velocity=dlv, Cv=dCv)
            nl = make_element(name, levels, n_sub, vel)[0]
            r, J = simulated(nl, gains, residual=True, n=n, sens=sens)
            return r, (J if np.all(np.isfinite(r)) else None)

        def gauss_newton_step(J, r0):
            """(step, whole): the Gauss-Newton step, cut back to move no parameter by more than
            0.5 (a trust region on the logs), and whether it was not cut."""
            step = np.linalg.lstsq(J, -r0, rcond=None)[0]
            cut = min(1.0, 0.5 / max(np.max(np.abs(step)), 1e-300))
            return step * cut, cut == 1.0

        def fd_jacobian(theta, r0, n):
            """Forward differences of the residual (None when a step diverges)."""
            J = np.empty((r0.size, theta.size))
            for k in range(theta.size):
                r = resid(theta + h * np.eye(theta.size)[k], n)
                if not np.all(np.isfinite(r)):
                    return None
                J[:, k] = (r - r0) / h
            return J

        theta = np.log(c[active])
        lo, hi = np.full(n_lvl, -np.inf), np.full(n_lvl, np.inf)
        if smooth:
            theta = np.append(theta, np.log(v0 if v is None else v))
            lo, hi = np.append(lo, log_v_bounds[0]), np.append(hi, log_v_bounds[1])
        if fit_g:
            theta = np.append(theta, np.log(np.maximum(g, 1e-300)))
            lo, hi = np.append(lo, log_g_bounds[0]), np.append(hi, log_g_bounds[1])
        theta = np.clip(theta, lo, hi)
        h = 0.02
        n_iter = VELOCITY_ITERATIONS if friction else REFINE_ITERATIONS
        n_iter = GAIN_ITERATIONS if fit_g else n_iter
        horizons = FRICTION_HORIZONS if friction else (1.0,)
        # friction's Jacobian is exact (the sensitivities) where Gauss-Newton takes whole steps
        # with it (no parameter moved by more than the trust region, 0.5 in the logs) and its
        # linear model predicts the error's fall over them (a share MODEL_TRUST of it): near
        # the optimum, where it is the better slope. Elsewhere forward differences over h, the
        # path as before, until their step is whole again. Far from the optimum, near
        # stick-slip switches, the record is steep in the parameters on scales far below the
        # steps: the exact derivative holds only near the point, and the step it extrapolates
        # is cut back to nothing (on an indepgen stage record with hard Coulomb friction it
        # asked for 100x in a port gain and stalled at 32x the floor, where differences over
        # h reach 4x)
        exact = smooth
        for frac in horizons:
            n = max(int(frac * u.shape[0]), 2)
            r0, J = resid_jac(theta, n) if exact else (resid(theta, n), None)
            if not np.all(np.isfinite(r0)):
                return out
            for _ in range(n_iter):
                if J is None:
                    if exact:  # the accepted trial's, which was run without it
                        r0, J = resid_jac(theta, n)
                    else:
                        J = fd_jacobian(theta, r0, n)
                    if J is None:
                        return out
                cost0 = float(r0 @ r0)
                step, whole = gauss_newton_step(J, r0)
                accepted = False
                if exact:
                    fall, model_fall = -np.inf, 0.0
                    if whole:
                        trial = np.clip(theta + step, lo, hi)
                        model = r0 + J @ (trial - theta)
                        # the trial's run carries the sensitivities where an accepted trial
                        # is followed by another step (which needs its Jacobian: the same
                        # outputs, one run instead of two); not on a step that ends the loop
                        final = np.max(np.abs(step)) < 0.005 or _ == n_iter - 1
                        if final:
                            r, J_trial = resid(trial, n), None
                        else:
                            r, J_trial = resid_jac(trial, n)
                        fall = cost0 - float(r @ r) if np.all(np.isfinite(r)) else -np.inf
                        model_fall = cost0 - float(model @ model)
                    if fall > 0 and fall >= MODEL_TRUST * model_fall:
                        theta, r0, J, accepted = trial, r, J_trial, True
                    else:
                        exact = False
                        J = fd_jacobian(theta, r0, n)
                        if J is None:
                            return out
                        step, whole = gauss_newton_step(J, r0)
                if smooth and not exact and whole:
                    exact = True  # near the optimum (a whole step): the exact slope next
                if not accepted:
                    for shrink in (1.0, 0.5):
                        trial = np.clip(theta + shrink * step, lo, hi)
                        r = resid(trial, n)
                        if np.all(np.isfinite(r)) and float(r @ r) < cost0:
                            theta, r0, J = trial, r, None
                            break
                    else:
                        break
                if frac == 1.0:  # the whole record's error: a candidate
                    levels, vel, gains = unpack(theta)
                    nl, params = make_element(name, levels, n_sub, vel, gains)
                    out.append((float(np.sqrt(r0 @ r0)), name, nl, params))
                if fit_g and float(r0 @ r0) > (1.0 - 2 * GAIN_STOP) * cost0:
                    break  # the error fell by less than GAIN_STOP: each step costs n + 1 runs
                if np.max(np.abs(step)) < 0.005:
                    break
        return out

    def start_gains(name, c, n_sub=substeps, v=None):
        """The port gains (SquarePorts; else None) the simulation of element ``name`` at the
        levels ``c`` fits best on GAIN_GRID: the gains' start (the error is far from
        quadratic in them: a gain too small leaves a non-collocated mode undamped by the
        sticking ports, one too large locks it)."""
        if family is None:
            return None
        nl = make_element(name, c, n_sub, v)[0]
        n = start_n(name)
        errs = [rms(simulated(nl, s * family.unit, residual=True, n=n)[0]) for s in GAIN_GRID]
        return GAIN_GRID[int(np.argmin(errs))] * family.unit

    def scale_levels(name, c, n_sub, v, g, span, ratio=LEVEL_STEP):
        """The levels ``c`` times the common factor (within ``span`` either way) whose
        simulation fits best: the best of a grid of ratio LEVEL_STEP, then a bounded 1-D
        search between its neighbours. The regressed levels may be far off (an equation
        error on the sampled motion, regressed on a linear model's residual that a rigid
        body's drift dominates), the error is sharp in their scale (a from-rest simulation
        of rigid bodies integrates a level error twice: on the stage 25 % off is ~10x the
        error at the right scale) and a Gauss-Newton step through a stick-slip simulation
        moves them by a few per cent at a time."""

        def cost(log_s):
            nl = make_element(name, np.exp(log_s) * c, n_sub, v)[0]
            return rms(simulated(nl, g, residual=True, n=start_n(name))[0])

        step = np.log(ratio)
        grid = np.arange(-np.log(span), np.log(span) + 0.5 * step, step)
        errs = [cost(x) for x in grid]
        i = int(np.argmin(errs))
        sol = scipy.optimize.minimize_scalar(
            cost,
            bounds=(grid[i] - step, grid[i] + step),
            method="bounded",
            # to a tenth of a fine grid's step (its valleys are that narrow), else 0.5 %
            options={"xatol": min(0.005, 0.1 * step)},
        )
        return np.exp(sol.x if sol.fun < errs[i] else grid[i]) * c

    def scale_each(name, c, n_sub, span):
        """The levels ``c`` each scaled within ``span`` either way, port by port (the best of
        a grid of ratio sqrt(LEVEL_STEP) on its log, then a bounded 1-D search between its
        neighbours, the others held; RIGID_SWEEPS sweeps over the ports), on the record's
        first part (:func:`start_n`): the rigid ports' start. A rigid body's regressed level
        may be off by several-fold (the rotations' small levels, whose regressors the
        translations' drift swamps) and the error is sharp in each level; a common scale
        cannot fix the ports' ratios, Gauss-Newton from there stalls. The error has several
        minima in a level (an indepgen stage record: a rotation's regressed level 2.5x its
        truth, a bounded search over the whole span ended at 3.9x, a local minimum, and the
        fit at 29.7x the floor; the grid's best is the truth's, 1.00x)."""
        c = c.copy()
        step = 0.5 * np.log(LEVEL_STEP)
        grid = np.arange(-np.log(span), np.log(span) + 0.5 * step, step)
        for _ in range(RIGID_SWEEPS):
            for j in np.flatnonzero(c > 0):

                def cost(log_s, j=j):
                    trial = c.copy()
                    trial[j] *= np.exp(log_s)
                    nl = make_element(name, trial, n_sub)[0]
                    return rms(simulated(nl, None, residual=True, n=start_n(name))[0])

                errs = [cost(x) for x in grid]
                x, e = _between_neighbours(cost, grid, errs, int(np.argmin(errs)), 0.002)
                if e < cost(0.0):
                    c[j] *= np.exp(x)
        return c

    def start_with_gains(name, c, n_sub, g=None):
        """(levels, gains): the gains' grid (from ``g``'s levels if given), the levels' common
        scale at those gains (within LEVEL_SPAN at the regressed levels, LEVEL_STEP^2 after),
        the gains' grid again at the scaled levels; v0 its estimate."""
        span = LEVEL_SPAN if g is None else LEVEL_STEP**2
        g = start_gains(name, c, n_sub) if g is None else g
        c = scale_levels(name, c, n_sub, None, g, span)
        return c, start_gains(name, c, n_sub)

    def fit_with_gains(name, c, g):
        """The element ``name`` from its levels ``c`` and port gains ``g`` (a SquarePorts
        model; both from :func:`start_with_gains` at ``substeps``): per round at n
        substeps, the levels' common scale (:func:`scale_levels`) and the gains' grid
        (:func:`start_gains`) at v0's estimate, n raised to the coarser of the first two
        counts whose outputs agree (:func:`converged_substeps`, at most CONVERGE_ROUNDS
        rounds); then Gauss-Newton on the levels, v0 and the gains jointly there
        (:func:`refine_levels`; the converged rounds after it refit at finer counts if its
        smaller misfit asks for them). The error is steep in the levels (a from-rest
        simulation of rigid bodies integrates a level error twice: 10 % off is ~100x the
        noise on the stage) and flat in the gains until the levels are close; how far the
        sticking ports hold a non-collocated mode is what the gains set, which a coarse
        simulation misplaces. A list of (error, name, nl, params) like refine_levels."""
        n_sub, out = substeps, []
        for _ in range(CONVERGE_ROUNDS):
            n_new = converged_substeps(name, c, n_sub, None, g)
            if n_new <= 2 * n_sub:  # n_sub's output moved little on doubling: fit there
                break
            n_sub = n_new // 2
            c, g = start_with_gains(name, c, n_sub, g)
            nl, params = make_element(name, c, n_sub, None, g)
            out.append((simulated(nl, g)[0], name, nl, params))
        return out + refine_levels(name, c, n_sub, None, g)

    def profile(c):
        """The free rigid bodies' levels ``c`` (the hard law), port by port: each port with a
        drive set to the best of a grid of ratio PROFILE_STEP within RIGID_REVIVE_SPAN either
        way of its level (a port without one: of the other ports' level per unit of drive,
        their median) or to none, then a bounded 1-D search between its grid neighbours, the
        others held (:func:`coulomb_port_profile`: the whole record, exact, 0.04 ms a level);
        in sweeps until no port moves (the ports' motions are independent; their outputs may
        mix them), at most PROFILE_SWEEPS, the later ones within PROFILE_LOCAL."""
        c = c.copy()
        on = (c > 0) & (drive > 0)
        if not on.any():
            return c
        ratio = float(np.median(c[on] / drive[on]))
        step, span = np.log(PROFILE_STEP), np.log(RIGID_REVIVE_SPAN)
        for sweep in range(PROFILE_SWEEPS):
            moved = False
            if sweep:  # the others moved: each port from its level, only as far as they move it
                span = np.log(PROFILE_LOCAL)
            for j in np.flatnonzero(drive > 0):
                errors = coulomb_port_profile(lin, u, y, fs, Bp, Cp, c, j)
                now, none = errors([c[j], 0.0])
                center = np.log(c[j] if c[j] > 0 else ratio * drive[j])
                grid = center + np.arange(-span, span + 0.5 * step, step)
                errs = errors(np.exp(grid))
                i = int(np.argmin(errs))
                x, e = _between_neighbours(
                    lambda x, errors=errors: float(errors(np.exp(x))),
                    grid,
                    list(errs),
                    i,
                    PROFILE_XATOL,
                )
                if none <= e and none < now:
                    moved, c[j] = True, 0.0
                elif e < now and abs(x - np.log(max(c[j], 1e-300))) > PROFILE_XATOL:
                    moved, c[j] = True, np.exp(x)
            if not moved:
                break
        return c

    def rigid_start(name, c):
        """The rigid bodies' levels from the regression ``c`` (at :data:`HIGH_PASS`) or the
        regression at RIGID_HIGH_PASS: each scaled by its best common factor
        (:func:`scale_levels`) and then port by port (free bodies :func:`profile`, others
        :func:`scale_each`), the one whose
        simulation fits the whole record better kept. The regression of a rigid body's
        friction is exact in the dynamics (it drives no flexible mode) but its low
        frequencies carry the drift its law's errors integrate: which corner leaves the better
        start differs by record (the indepgen stage: 21x vs 1.3x the floor on one record; on
        another the first part of the record preferred the corner whose whole-record start
        was 27x where the other's was 5x, and the refinement stalled at 26x from it)."""
        starts = []
        for c_hp in (c, regress(name, False, motion, RIGID_HIGH_PASS)):
            if c_hp.max() > 0:
                c_hp = scale_levels(name, c_hp, substeps, None, None, LEVEL_SPAN)
                if hard:  # (whole-record simulations: cheap event-exact ones only)
                    c_hp = profile(c_hp)
                else:
                    c_hp = scale_each(name, c_hp, substeps, RIGID_SPAN)
                nl = make_element(name, c_hp, substeps)[0]
                starts.append((simulated(nl)[0], c_hp))
        return min(starts, key=lambda t: t[0])[1] if starts else c

    def modal_start():
        """The spring on the mode: its level's scale scanned through the simulation
        (:func:`scale_levels`) within MODAL_SPAN either way of MODAL_CENTER times the mode's
        unit ``w^2 / q_rms^2`` (the linear stiffness at the estimated motion's rms). The
        regressed level is no start there: a lightly damped mode's response moves with its
        frequency, far from linearly in k3 over the levels a record shows (an indepgen beam
        mode at 91 Hz, zeta 0.019, a spring 1 % of its stiffness: the regression gives half
        the level; 3 %, twice the noise, a twentieth)."""
        w = 2 * np.pi * modal.freq_hz
        unit = w**2 / max(float(np.mean(motion**2)), 1e-300)
        c = np.array([MODAL_CENTER * unit])
        with np.errstate(invalid="ignore"):  # a diverging trial scores inf in the 1-D search
            return scale_levels("cubic_stiffness", c, substeps, None, None, MODAL_SPAN, MODAL_STEP)

    # saturation: the linear response to the clipped input (it needs no port; not a mode's)
    scored = []
    if saturation is not None and modal is None and rigid is None:
        scored.append(
            (
                saturation.error_after,
                "saturation",
                saturation.nonlinearity,
                dict(saturation.parameters),
            )
        )
    elif modal is None and rigid is None:  # (the rigid ports' saturation is the inputs')
        best_sat, best_err = _fit_saturation_levels(lin, meas, u, y, fs, refine=refine)
        scored.append(
            (
                float(best_err),
                "saturation",
                PortNonlinearity(friction_force=np.zeros(n_u), saturation=best_sat, substeps=1),
                {"saturation": [float(x) for x in best_sat]},
            )
        )
    # friction and the spring: judged by the nonlinear simulation itself (the regression's
    # motion is the measured or estimated one; a from-rest simulation of a rigid body is far
    # more sensitive), so what is reported is what the simulation model reproduces
    best = None  # (error, name, common, levels, port motion, port gains)
    # on a mode's coordinate the spring only: friction acts where parts slide (the ports)
    names = ("coulomb_friction", "cubic_stiffness")
    names = ("cubic_stiffness",) if modal is not None else names
    # on the rigid bodies friction only (a spring on a rigid body is a suspension's, linear)
    names = ("coulomb_friction",) if rigid is not None else names
    if (
        modal is not None
        and (measured := _measured_mode(lin, (Bp, Cp), y - y_lin, motion)) is not None
    ):
        # the spring's level regressed on the mode's coordinate as measured (the linear model's
        # plus what the residual shows of it), an output-error regression where the scan's
        # unit is a guess (below); refined on a fine grid of the simulation's error. A mode
        # whose measured motion shows no hardening (a level <= 0) is not scanned either
        c = regress("cubic_stiffness", False, measured)
        if not c.max() > 0:
            names = ()
        else:
            if refine:
                c = scale_levels(
                    "cubic_stiffness", c, substeps, None, None, MEASURED_SPAN, MEASURED_STEP
                )
            nl, params = make_element("cubic_stiffness", c)
            err, p_nl = simulated(nl)
            scored.append((err, "cubic_stiffness", nl, params))
            if p_nl is not None:
                best = (err, "cubic_stiffness", False, c, p_nl, None)
    for name in names:
        per_port = None
        # one level per port, or one level for all (one port on a mode: one level)
        # (friction on the rigid bodies: a level per bearing, each body's own)
        for common in (False, True) if modal is None and rigid is None else (False,):
            c = regress(name, common, motion) if modal is None else modal_start()
            if rigid is not None:  # the rigid ports' start
                c = rigid_start(name, c)
            if not common:
                per_port = c
            elif family is not None and not c.max() > 0 and per_port.max() > 0:
                # the common level's regression failed (a linear residual that rigid-body
                # drift dominates): the mean of the per-port levels starts its scale search
                c = np.full(n_u, per_port[per_port > 0].mean())
            if not c.max() > 0:
                continue
            g = None
            if family is not None:  # the start the gains need (the levels' scale too: the
                # simulation is too steep in them to judge the element at the regressed ones)
                c, g = start_with_gains(name, c, substeps)
            nl, params = make_element(name, c, g=g)
            err, p_nl = simulated(nl, g)
            scored.append((err, name, nl, params))
            if p_nl is not None and (best is None or err < best[0]):
                best = (err, name, common, c, p_nl, g)
    if best is not None and not measured_ports:
        # the motion was an estimate (a linear model's ports): the element changes it. Regress
        # again on the motion the nonlinear simulation model itself gives, while the error falls
        # (at the true level the simulated motion is the true one: a consistent fixed point)
        err, name, common, c, p_nl, _ = best
        for _ in range(MOTION_ITERATIONS):
            c_new = regress(name, common, p_nl)
            if not c_new.max() > 0:
                break
            nl, params = make_element(name, c_new)
            err_new, p_new = simulated(nl)
            if not err_new < err:
                break
            scored.append((err_new, name, nl, params))
            step = np.max(np.abs(c_new - c)) / c.max()
            err, c, p_nl = err_new, c_new, p_new
            if step < 0.01:
                break
        # the regression is an equation error (sampled velocity, the force held per sample):
        # its fixed point is close to, not at, the simulation model's best levels
        if refine:
            scored += refine_levels(name, c)
    if best is not None and hard and refine:
        # the rigid bodies' levels through their event-exact simulation (no substeps to
        # converge below, where the smooth law's levels were refitted at each finer count)
        scored += refine_levels(best[1], best[3])
    if best is not None and family is not None and refine:
        # the port gains are fitted with the levels (the regression has no gains: its motion
        # is the measured one), on the converged simulation
        scored += fit_with_gains(best[1], best[3], best[5])
    if not scored:  # no spring regressed on the mode (none >= 0 lowers the residual)
        nl, params = make_element("cubic_stiffness", np.zeros(n_p))
        scored.append((float(before), "cubic_stiffness", nl, params))
    after, element, nl, params = min(scored, key=lambda t: t[0])
    if refine and element != "saturation":
        # the levels above are fitted on a simulation of ``substeps`` substeps; the reported
        # model is the converged one, its levels refitted there (near sticking, the error is
        # steep in the level: a level right for a coarse simulation is not right for the motion)
        # Converged is judged against the misfit left, which a level fitted on a coarse
        # simulation inflates: judged again after the levels are refitted at the finer count
        n_sub = params.get("substeps", substeps)
        hopeless = give_up_above is not None and after > COARSE_MARGIN * give_up_above
        # no element at all (no level regressed above zero): nothing to converge
        hopeless = hopeless or not np.any(np.asarray(next(iter(params.values())), float) > 0)
        for _ in range(0 if hopeless else CONVERGE_ROUNDS):
            levels = np.asarray(next(iter(params.values())), float)
            vel, g = params.get("friction_velocity"), gains_of(params)
            n_new = converged_substeps(element, levels, n_sub, vel, g)
            if n_new == n_sub:
                break
            n_sub = n_new
            # (own names: when the coarse simulation is kept below, so is its model)
            nl_n, params_n = make_element(element, levels, n_sub, vel, g)
            fine = [(simulated(nl_n, g)[0], element, nl_n, params_n)]
            fine += refine_levels(element, levels, n_sub, vel, g)
            best_fine = min(fine, key=lambda t: t[0])
            if not best_fine[0] <= after:
                # the record is explained better by the coarse simulation (a record made by
                # one, or a fine-step refit that did not converge): keep what explains it
                break
            after, element, nl, params = best_fine
    preds: dict[str, float] = {}
    for err, name, _, _ in scored:
        preds[name] = min(preds.get(name, np.inf), err)
    vals = np.asarray(next(iter(params.values())), float)
    if modal is not None:
        ports = ()  # no input is the port: ``parameters["mode"]`` says which mode
    elif element == "saturation":
        ports = tuple(int(j) for j in np.flatnonzero(np.isfinite(vals)))
    else:
        ports = tuple(int(j) for j in np.flatnonzero(vals > 0))
    if element == "saturation":
        y_el = sim.simulate_zoh(lin, np.clip(u, -vals, vals), fs)[:, meas]
    else:
        y_el = simulated(nl, gains_of(params), output=True)[0]
    return ElementFit(
        element=element,
        ports=ports,
        parameters=params,
        nonlinearity=nl,
        error_before=float(before),
        error_after=float(after),
        candidates=preds,
        level=_output_share(y_el, y_lin, y),
        output=None if element == "saturation" else y_el,
    )


def _output_share(y_element: np.ndarray, y_linear: np.ndarray, y: np.ndarray) -> float:
    """The share of the record's power that the element adds to the linear model's response
    to the recorded input, ``||y_element - y_linear||^2 / ||y||^2``, at most 1 (a from-rest
    simulation of a rigid body integrates a force difference twice and may exceed it)."""
    share = np.sum((y_element - y_linear) ** 2) / max(float(np.sum(y**2)), 1e-300)
    return float(min(share, 1.0)) if np.isfinite(share) else 1.0


def fit_saturation(sys, u: np.ndarray, y: np.ndarray, fs: float, *, refine: bool = True):
    """Saturation of the inputs alone: the linear model driven by the clipped recorded input.

    Unlike friction or a spring, an input saturation needs no port: the applied force is
    ``clip(u_j, -l_j, l_j)`` whatever the plant's motion, so any linear model (a model that
    is not square and has no sensor collocated with an input too) is its simulation model.
    The levels are scanned over quantiles of |u| and refined per input through the
    simulation (as in :func:`fit_port_element`).

    Parameters
    ----------
    sys : LTIModel or control.StateSpace
        The linear model (continuous; an LTIModel's delay is part of it), any n_y x n_u.
    u, y : (N, n_u), (N, n_y) arrays
        Recorded input (the command before the saturation) and output.
    fs : float
        Sampling frequency, Hz.
    refine : bool
        Refine the levels per input (else the best common quantile of |u|).

    Returns
    -------
    ElementFit
        ``element`` "saturation", ``parameters["saturation"]`` the level per input (N),
        ``ports`` every input; ``candidates`` holds saturation only.
    """
    from workbench.core.model import as_model

    lin = as_model(sys)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    meas = np.arange(y.shape[1])
    y_lin = sim.simulate_zoh(lin, u, fs)
    before = lti.relative_error_time(y, y_lin)
    levels, after = _fit_saturation_levels(lin, meas, u, y, fs, refine=refine)
    y_sat = sim.simulate_zoh(lin, np.clip(u, -levels, levels), fs)
    return ElementFit(
        element="saturation",
        ports=tuple(int(j) for j in np.flatnonzero(np.isfinite(levels))),
        parameters={"saturation": [float(x) for x in levels]},
        nonlinearity=PortNonlinearity(
            friction_force=np.zeros(u.shape[1]), saturation=levels, substeps=1
        ),
        error_before=float(before),
        error_after=float(after),
        candidates={"saturation": float(after)},
        level=_output_share(y_sat, y_lin, y),
    )


#: the smooth friction law's velocity scales the first-order screen tries, times the fit's
#: estimate (the fit moves v0 within VELOCITY_RANGE of it; below it the law is the sign's)
SCREEN_VELOCITIES = (1.0, 10.0, 100.0)


def first_order_errors(
    sys,
    u: np.ndarray,
    y: np.ndarray,
    fs: float,
    *,
    port_outputs=None,
    motion: np.ndarray | None = None,
    ports: bool = True,
    saturation: float | None = None,
    period: int | None = None,
) -> tuple[float, dict[str, float]]:
    """The linear model's error and, per element, the error the linear model plus the
    element's first-order signature reaches at best: what :func:`fit_port_element` could
    reach near level zero, at the cost of a few linear simulations (no nonlinear one).

    The arguments are :func:`fit_port_element`'s (the same port hypotheses: a square
    model, ``port_outputs``, :class:`SquarePorts` at unit gains, :class:`ModalPort`,
    :class:`RigidPorts`). At a small level an element adds to the linear model's output
    the linear model's response to its law of the port motion at each port (the regressors
    of the fit's regression): ``-F_j tanh(v_j / v0)`` (friction; at every v0 of
    SCREEN_VELOCITIES times the fit's estimate, jointly) and ``-k_j p_j^3`` (the cubic
    spring). The error reported is the residual's least-squares distance from their
    non-negative combinations (the levels are >= 0, as the fit's; the several v0 jointly,
    a lower bound of any one's), relative to ``||y||`` like the spec error. Saturation:
    :func:`saturation_first_order` (it depends on the linear model only: ``saturation``,
    its value from another hypothesis on the same model, is taken as given). The motion is
    the measured output (square model), ``motion``, or the linear model's simulated ports,
    as in the fit. ``ports=False``: no port is located (a model that is not square, no
    ``port_outputs``), saturation only, as :func:`fit_saturation` fits it.

    Returns ``(error, {element: error})``: the linear model's own error and the elements'
    for those the hypothesis has (the mode's port: the spring only; the rigid bodies':
    friction only).
    """

    from workbench.core.model import as_model

    family = sys if isinstance(sys, SquarePorts) else None
    modal = sys if isinstance(sys, ModalPort) else None
    rigid = sys if isinstance(sys, RigidPorts) else None
    if family is not None:
        port_outputs = family.port_outputs
        lin = as_model(family.system(family.unit))
    elif modal is not None or rigid is not None:
        lin = as_model((modal or rigid).lti)
    else:
        lin = as_model(sys)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    n_u = u.shape[1]
    norm = max(float(np.linalg.norm(y)), 1e-300)
    if not ports:
        meas = np.arange(lin.C.shape[0])
        err = float(np.linalg.norm(y - sim.simulate_zoh(lin, u, fs)) / norm)
        if saturation is None:
            saturation = saturation_first_order(lin, meas, u, y, fs, period)
        return err, {"saturation": saturation}
    if modal is not None or rigid is not None:
        meas = np.arange(lin.C.shape[0])
        Bp, Cp = (modal or rigid).maps
    else:
        _, _, _, _, _, meas = _ports(lin, port_outputs)
    n_p = n_u if modal is None else 1
    y_all = sim.simulate_zoh(lin, u, fs)
    r = y - y_all[:, meas]
    port, _, motion, vel, v0 = _port_motion(
        lin,
        u,
        y,
        y_all,
        fs,
        (Bp, Cp) if modal is not None or rigid is not None else None,
        n_p=n_p,
        modal=modal,
        rigid=rigid,
        family=family,
        port_outputs=port_outputs,
        motion=motion,
    )

    def projected(laws) -> float:
        """The residual's distance from the cone of the ports' responses to ``laws``
        (non-negative combinations: the element's levels are >= 0)."""
        cols = []
        for phi in laws:
            for j in range(n_p):
                if not np.any(phi[:, j]):
                    continue
                # the output of a unit force law at port j, resisting (minus sign)
                force = -np.eye(n_p)[j] * phi[:, [j]]
                cols.append(sim.simulate_zoh(port, force, fs)[:, meas].ravel())
        if not cols:
            return float(np.linalg.norm(r) / norm)
        X = np.stack(cols, -1)
        scale = np.linalg.norm(X, axis=0)
        X = X[:, scale > 0] / scale[scale > 0]
        if X.shape[1] == 0:
            return float(np.linalg.norm(r) / norm)
        # levels >= 0, as the fit's (a friction level, a hardening spring)
        return float(scipy.optimize.nnls(X, r.ravel())[1] / norm)

    out: dict[str, float] = {}
    if modal is None and rigid is None:
        if saturation is None:
            saturation = saturation_first_order(lin, meas, u, y, fs, period)
        out["saturation"] = saturation
    if modal is None:
        out["coulomb_friction"] = projected([np.tanh(vel / (s * v0)) for s in SCREEN_VELOCITIES])
    if rigid is None:
        out["cubic_stiffness"] = projected([motion**3])
    return float(np.linalg.norm(r) / norm), out


def _measured_mode(lin, maps, residual: np.ndarray, motion: np.ndarray) -> np.ndarray | None:
    """The mode's coordinate (N, 1) as the record shows it: the linear model's ``motion`` plus
    the part of the linear model's ``residual`` (N, n_y) its outputs carry, or None.

    A force on one mode's coordinate moves that mode's two states only (a modal block of
    :class:`ModalPort`'s realization), so the record's departure from the linear model, where
    the spring is all that is missing, is ``C_k dx_k``: ``dx_k`` by least squares over the
    outputs at each sample. With the mode's displacement measured, the spring's force is a
    regressor known from the record, and the level an output-error regression (the linear
    model's motion instead is far from the record's for a spring of a few per cent of the
    mode's stiffness, see :data:`MODAL_CENTER`). None where no output sees the mode.
    """
    Cp = maps[1]
    off = int(np.flatnonzero(Cp[0])[0])
    Cb = np.asarray(lin.C, float)[:, off : off + 2]
    if not np.any(Cb):
        return None
    dx = np.linalg.lstsq(Cb, residual.T, rcond=None)[0].T
    return motion + dx[:, [0]]


def _port_motion(lin, u, y, y_all, fs, maps, *, n_p, modal, rigid, family, port_outputs, motion):
    """What an element's regressors start from: ``(port, measured_ports, motion, vel, v0)``.

    ``port`` is the linear model whose inputs are the element's forces: without the input
    delay (port forces act directly), entering through ``maps``' ``Bp`` (the mode's or the
    rigid modes' velocity rows) where those are given. ``motion`` (N, n_p) is the ports'
    motion (m): the measured outputs of a square model (``measured_ports``), the given
    ``motion``, the mode's coordinate simulated through ``maps``' ``Cp``, or the linear
    model's simulated ports; ``vel`` its velocity (m/s) and ``v0`` the smooth friction
    law's velocity scale from it (m/s).
    """
    from dataclasses import replace

    n_u = u.shape[1]
    port = lin.without_delay()
    if maps is not None:
        port = replace(port, B=maps[0], D=np.zeros((lin.C.shape[0], n_p)), input_names=())
    # a square model's outputs are its ports' motion: exactly for the collocated modes and,
    # with non-collocated ones (SquarePorts), up to their share of the displacement (small
    # for modes far above the motion's band); the regression takes them as measured. A
    # mode's coordinate is never measured: the linear model's estimate, then its own
    measured_ports = (port_outputs is None or family is not None) and motion is None
    measured_ports = measured_ports and modal is None
    if motion is None and modal is not None:
        C_mode = maps[1]
        motion = sim.simulate_zoh(
            replace(lin, C=C_mode, D=np.zeros((1, n_u)), output_names=()), u, fs
        )
    elif motion is None:
        motion = y if measured_ports else y_all[:, np.asarray(port_outputs, int)]
    motion = np.asarray(motion, float)
    vel = np.gradient(motion, 1.0 / fs, axis=0)
    v_share = RIGID_VELOCITY if rigid is not None else 1e-3
    v0 = v_share * float(np.sqrt(np.mean(vel**2))) or 1e-12
    return port, measured_ports, motion, vel, v0
