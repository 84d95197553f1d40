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
exactly (zero-order hold) and the port force is held (explicit, first order
in the substep): :func:`workbench.sim.substep_zoh`, the propagation the plants
use too; this module supplies the port law (with its friction clamp).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from workbench import sim
from workbench.core import lti
from workbench.core.errors import InputError

__all__ = [
    "PortNonlinearity",
    "simulate_nonlinear",
    "fit_friction",
    "fit_port_element",
    "ElementFit",
    "ELEMENTS",
]


@dataclass(frozen=True)
class PortNonlinearity:
    """Nonlinearities at the input ports.

    Parameters
    ----------
    friction_force : (n_u,) array
        Coulomb friction level per port, N (N m for torques); 0 = none.
    friction_velocity : float
        Velocity scale v0 of the smooth Coulomb law, m/s.
    cubic_stiffness : (n_u,) array
        Hardening spring k3 per port, N/m^3; 0 = none.
    saturation : (n_u,) array
        Symmetric saturation of each input, N; inf = none.
    substeps : int
        Substeps per sample.
    """

    friction_force: np.ndarray
    friction_velocity: float = 1e-3
    cubic_stiffness: np.ndarray | None = None
    saturation: np.ndarray | None = None
    substeps: int = 8
    notes: tuple[str, ...] = field(default=())


def _ports(sys):
    A, B, C, D, dt = lti.as_matrices(sys)
    if dt:
        raise InputError("nonlinear simulation: expected a continuous model (dt = 0)")
    if C.shape[0] != B.shape[1]:
        raise InputError(
            f"nonlinear simulation: expected a square model (ports collocated with the inputs), "
            f"got {C.shape[0]} outputs and {B.shape[1]} inputs"
        )
    return A, B, C, D


def simulate_nonlinear(
    sys, u: np.ndarray, fs: float, nl: PortNonlinearity, *, delay_s: float = 0.0
) -> np.ndarray:
    """Response to the recorded input ``u`` (N, n_u), from rest; (N, n_y) outputs.

    ``sys`` is a continuous square model (``StateSpace`` or ``LTIModel``); an
    ``LTIModel``'s own delay is applied and ``delay_s`` (s) adds to it, as in
    :func:`workbench.sim.simulate_zoh`; the total is rounded to whole samples.
    Without any nonlinearity this equals :func:`workbench.core.sim.simulate_zoh`
    for integer-sample delays.
    """
    A, B, C, D = _ports(sys)
    delay_s = float(delay_s) + float(getattr(sys, "delay_s", 0.0))  # the model's delay travels
    n = A.shape[0]
    # the held input enters at the ports like the port forces: one force input
    # f = u[k-m] - friction - k3 p^3 through B (no separate delayed-input path)
    no_input = np.zeros((n, 0))
    prop = sim.substep_zoh(A, no_input, B, 1.0 / fs, nl.substeps)
    Bd = prop.Gp
    m = int(round(delay_s * fs))
    u = np.asarray(u, float)
    N, n_u = u.shape
    ud = sim.delayed(u, m)
    if nl.saturation is not None:
        sat = np.broadcast_to(np.asarray(nl.saturation, float), (n_u,))
        ud = np.clip(ud, -sat, sat)
    Fc = np.broadcast_to(np.asarray(nl.friction_force, float), (n_u,))
    k3 = (
        np.zeros(n_u)
        if nl.cubic_stiffness is None
        else np.broadcast_to(np.asarray(nl.cubic_stiffness, float), (n_u,))
    )
    CA = C @ A
    v0 = nl.friction_velocity
    # velocity change of each port per unit force held over one substep: friction is
    # limited to the force that stops the port within the substep, so the explicit
    # scheme cannot make friction reverse the motion (stable for any F_c and v0)
    mobility = np.maximum(np.abs(np.diag(CA @ Bd)), 1e-300)
    empty = np.zeros(0)
    x = np.zeros(n)
    y = np.empty((N, C.shape[0]))
    for k in range(N):
        y[k] = C @ x + D @ ud[k]

        def force(x, uk=ud[k]):
            v = CA @ x
            friction = np.minimum(Fc * np.abs(np.tanh(v / v0)), np.abs(v) / mobility)
            return uk - np.sign(v) * friction - k3 * (C @ x) ** 3

        x = prop.advance(x, empty, empty, force)
    return y


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
        ``cubic_stiffness`` (N/m^3 per port), or ``saturation`` (N per input; inf = none).
    nonlinearity : PortNonlinearity
        The element as a simulation model.
    error_before, error_after : float
        Spec time-domain error of the linear model and of the nonlinear simulation model.
    candidates : dict
        Every element tried: its error predicted by the regression (``{element: error}``).
    """

    element: str
    ports: tuple[int, ...]
    parameters: dict
    nonlinearity: PortNonlinearity
    error_before: float
    error_after: float
    candidates: dict


def fit_port_element(
    sys, u: np.ndarray, y: np.ndarray, fs: float, *, substeps: int = 4
) -> ElementFit:
    """Which port nonlinearity explains the record: Coulomb friction, a cubic spring or saturation.

    Parameters
    ----------
    sys : LTIModel or control.StateSpace
        The linear model (continuous, square: output j measures the displacement where
        input j pushes); an LTIModel's delay is part of it.
    u, y : (N, n_u), (N, n_y) arrays
        Recorded input and output.
    fs : float
        Sampling frequency, Hz.
    substeps : int
        Substeps per sample of the final nonlinear simulation.

    Notes
    -----
    Friction and the cubic spring are forces at the ports that depend on the port
    motion, ``-F_j tanh(v_j / v0)`` and ``-k_j p_j^3``: with the motion taken from the
    measured output, the output they add is linear in ``F_j`` / ``k_j`` (the linear
    model driven by the signal at port j), so each is a least-squares regression of
    the linear model's residual (equation error in the nonlinearity, output error in
    the dynamics). Saturation is scanned over levels of |u| (the linear model driven
    by the clipped input). The best element is then simulated with
    :func:`simulate_nonlinear` and its error is the one reported.
    """
    from workbench.core.model import as_model

    lin = as_model(sys)
    _ports(lin)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    n_u = u.shape[1]
    y_lin = sim.simulate_zoh(lin, u, fs)
    before = lti.relative_error_time(y, y_lin)
    e = y - y_lin
    port = lin.without_delay()  # port forces act directly, not through the input delay
    v = np.gradient(y, 1.0 / fs, axis=0)
    v0 = 1e-3 * float(np.sqrt(np.mean(v**2))) or 1e-12
    signals = {"coulomb_friction": np.tanh(v / v0), "cubic_stiffness": y**3}
    trials: list[tuple[str, PortNonlinearity, dict]] = []
    for name, phi in signals.items():
        # regressor j: the output of a unit force law at port j, with the minus sign of a
        # resisting force
        X = np.stack(
            [-sim.simulate_zoh(port, np.eye(n_u)[j] * phi[:, [j]], fs).ravel() for j in range(n_u)],
            -1,
        )
        for common in (False, True):  # one level per port, or one level for all
            Xc = X.sum(axis=1, keepdims=True) if common else X
            scale = np.linalg.norm(Xc, axis=0)
            ok = scale > 0
            c = np.zeros(Xc.shape[1])
            if ok.any():
                c[ok] = np.linalg.lstsq(Xc[:, ok] / scale[ok], e.ravel(), rcond=None)[0]
                c[ok] /= scale[ok]
            # a friction level or a hardening spring is >= 0
            c = np.broadcast_to(np.maximum(c, 0.0), (n_u,)).copy()
            if not c.max() > 0:
                continue
            c[c < 0.05 * c.max()] = 0.0
            if name == "coulomb_friction":
                nl = PortNonlinearity(friction_force=c, friction_velocity=v0, substeps=substeps)
                params = {"friction_force": [float(x) for x in c], "friction_velocity": v0}
            else:
                nl = PortNonlinearity(
                    friction_force=np.zeros(n_u), cubic_stiffness=c, substeps=substeps
                )
                params = {"cubic_stiffness": [float(x) for x in c]}
            trials.append((name, nl, params))
    # saturation: the linear response to the clipped input, over levels of |u|
    amp = np.abs(u)
    best_sat, best_err = None, np.inf
    for q in (0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999):
        level = np.quantile(amp, q, axis=0)
        err = lti.relative_error_time(y, sim.simulate_zoh(lin, np.clip(u, -level, level), fs))
        if err < best_err:
            best_sat, best_err = level, err
    scored = [
        (
            float(best_err),
            "saturation",
            PortNonlinearity(friction_force=np.zeros(n_u), saturation=best_sat, substeps=1),
            {"saturation": [float(x) for x in best_sat]},
        )
    ]
    # friction and the spring: judged by the nonlinear simulation itself (the regression's
    # motion is the measured one; a from-rest simulation of a rigid body is far more
    # sensitive), so what is reported is what the simulation model reproduces
    for name, nl, params in trials:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging trial scores inf
            y_nl = simulate_nonlinear(lin, u, fs, nl)
        err = lti.relative_error_time(y, y_nl) if np.all(np.isfinite(y_nl)) else np.inf
        scored.append((float(err), name, nl, params))
    after, element, nl, params = min(scored, key=lambda t: t[0])
    preds: dict[str, float] = {}
    for err, name, _, _ in scored:
        preds[name] = min(preds.get(name, np.inf), err)
    vals = np.asarray(next(iter(params.values())), float)
    if element == "saturation":
        ports = tuple(int(j) for j in np.flatnonzero(np.isfinite(vals)))
    else:
        ports = tuple(int(j) for j in np.flatnonzero(vals > 0))
    before = float(before)
    return ElementFit(
        element=element,
        ports=ports,
        parameters=params,
        nonlinearity=nl,
        error_before=before,
        error_after=float(after),
        candidates=preds,
    )
