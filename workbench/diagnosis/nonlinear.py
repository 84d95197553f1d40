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

__all__ = ["PortNonlinearity", "simulate_nonlinear", "fit_friction"]


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
