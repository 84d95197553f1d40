"""Linear MPC on a discrete state-space model, solved with casadi's QP interface.

``x+ = A x + B u``, horizon N, cost ``sum x'Qx + u'Ru + x_N' P x_N`` (P defaults
to the DARE solution, so the unconstrained MPC equals the infinite-horizon
LQR), bounds ``u_min <= u <= u_max`` (actuator force limits, N) and
``y_min <= Cz x <= y_max`` (position windows, m) on x_1..x_N.
The QP is condensed (U only) and built ONCE: H and the constraint matrix are
constant, the gradient is ``F x0``; the solver (qpOASES) is warm-started from
the previous solution shifted by one step.  Solve time per call is recorded.

:class:`MPCController` wraps it as a :class:`controllers.protocol.Controller`
(e = r - y -> u) with the Kalman observer of :mod:`controllers.modal_sf` on
the same discrete modal design model; :func:`design_mpc` builds one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi
import numpy as np
import scipy.linalg

from workbench.core.errors import InputError


class LinearMPC:
    """Condensed linear MPC; ``solve(x0) -> u0`` (shape (m,)), state-feedback form."""

    def __init__(
        self, A, B, Q, R, N, P=None, u_min=None, u_max=None, Cz=None, y_min=None, y_max=None
    ):
        A, B = np.atleast_2d(np.asarray(A, float)), np.atleast_2d(np.asarray(B, float))
        n, m = B.shape
        if A.shape != (n, n):
            raise InputError(f"MPC: A must be ({n}, {n}) to match B {B.shape}, got {A.shape}")
        Q, R = np.atleast_2d(np.asarray(Q, float)), np.atleast_2d(np.asarray(R, float))
        if Q.shape != (n, n) or R.shape != (m, m):
            raise InputError(
                f"MPC: Q must be ({n}, {n}) and R ({m}, {m}), got {Q.shape} and {R.shape}"
            )
        if int(N) < 1:
            raise InputError(f"MPC: horizon N must be >= 1, got {N}")
        N = int(N)
        P = scipy.linalg.solve_discrete_are(A, B, Q, R) if P is None else np.asarray(P, float)
        self.n, self.m, self.N, self.A, self.B, self.P = n, m, N, A, B, P
        # X = Phi x0 + Gam U, X = [x_1; ...; x_N]
        Phi = np.vstack([np.linalg.matrix_power(A, k + 1) for k in range(N)])
        Gam = np.zeros((N * n, N * m))
        for i in range(N):
            for j in range(i + 1):
                Gam[i * n : (i + 1) * n, j * m : (j + 1) * m] = np.linalg.matrix_power(A, i - j) @ B
        Qb = scipy.linalg.block_diag(*([Q] * (N - 1) + [P]))
        Rb = scipy.linalg.block_diag(*([R] * N))
        self._H = 2 * (Gam.T @ Qb @ Gam + Rb)
        self._H = 0.5 * (self._H + self._H.T)
        self._F = 2 * Gam.T @ Qb @ Phi  # gradient g = F x0
        lb = np.full(N * m, -np.inf) if u_min is None else np.tile(np.broadcast_to(u_min, (m,)), N)
        ub = np.full(N * m, np.inf) if u_max is None else np.tile(np.broadcast_to(u_max, (m,)), N)
        if np.any(lb > ub):
            raise InputError(f"MPC: infeasible force limits u_min {u_min} > u_max {u_max}")
        self._lbx, self._ubx = lb, ub
        if Cz is not None:
            Cz = np.atleast_2d(np.asarray(Cz, float))
            if Cz.shape[1] != n:
                raise InputError(f"MPC: Cz must have {n} columns, got shape {Cz.shape}")
            p = Cz.shape[0]
            ylo = np.full(p, -np.inf) if y_min is None else np.broadcast_to(y_min, (p,))
            yhi = np.full(p, np.inf) if y_max is None else np.broadcast_to(y_max, (p,))
            if np.any(ylo > yhi):
                raise InputError(f"MPC: infeasible position window y_min {y_min} > y_max {y_max}")
            Czb = scipy.linalg.block_diag(*([Cz] * N))
            self._Ac, self._CzPhi = Czb @ Gam, Czb @ Phi
            self._lba, self._uba = np.tile(ylo, N), np.tile(yhi, N)
        else:
            self._Ac = np.zeros((0, N * m))
            self._CzPhi = np.zeros((0, n))
            self._lba = self._uba = np.zeros(0)
        self._solver = casadi.conic(
            "mpc",
            "qpoases",
            {"h": casadi.DM(self._H).sparsity(), "a": casadi.DM(self._Ac).sparsity()},
            {"printLevel": "none", "error_on_fail": False},
        )
        self._warm = np.zeros(N * m)
        self.solve_times: list[float] = []

    def solve(self, x0, warm_start: bool = True) -> np.ndarray:
        """First move u_0 (shape (m,)) for state x0 (shape (n,)); records the solve time (s)."""
        U, dt_s, _ok = self.solve_from(x0, self._warm if warm_start else None)
        self.solve_times.append(dt_s)
        self._warm = self.shift(U)
        return U[: self.m]

    def solve_from(self, x0, warm=None) -> tuple[np.ndarray, float, bool]:
        """The whole move sequence U (N m,) for x0, without touching this object.

        ``warm`` (N m,) starts the solver (None: zeros). Returns (U, solve time
        in s, success): success False when qpOASES did not converge (e.g. a
        position window the state cannot reach any more); U is then its last iterate.
        """
        x0 = np.asarray(x0, float).ravel()
        if x0.shape != (self.n,):
            raise InputError(f"MPC: x0 must have {self.n} entries, got {x0.size}")
        off = self._CzPhi @ x0
        t0 = time.perf_counter()
        sol = self._solver(
            h=self._H,
            g=self._F @ x0,
            a=self._Ac,
            lba=self._lba - off,
            uba=self._uba - off,
            lbx=self._lbx,
            ubx=self._ubx,
            x0=np.zeros(self.N * self.m) if warm is None else warm,
        )
        dt_s = time.perf_counter() - t0
        ok = bool(self._solver.stats().get("success", True))
        return np.asarray(sol["x"]).ravel(), dt_s, ok

    def shift(self, U) -> np.ndarray:
        """The warm start for the next sample: U shifted by one move, the last repeated."""
        U = np.asarray(U, float)
        return np.concatenate([U[self.m :], U[-self.m :]])

    @property
    def report(self) -> dict:
        """Solve time per step (s): mean, max, count."""
        t = np.asarray(self.solve_times)
        return {
            "mean_s": float(t.mean()) if t.size else 0.0,
            "max_s": float(t.max()) if t.size else 0.0,
            "n": int(t.size),
        }


# ------------------------------------------------------------------ MPC as a Controller
class SolveLog:
    """Solve time per step of an MPC run, s; the one mutable part of an MPCController.

    A record, not control state: the control law never reads it. ``init()``
    of the controller starts a new log (one run of the loop).
    """

    def __init__(self):
        self.times_s: list[float] = []
        self.failures = 0

    def summary(self) -> dict:
        """mean_s, max_s, n (steps) and failures (QP solves that did not converge)."""
        t = np.asarray(self.times_s)
        return {
            "mean_s": float(t.mean()) if t.size else 0.0,
            "max_s": float(t.max()) if t.size else 0.0,
            "n": int(t.size),
            "failures": int(self.failures),
        }


@dataclass(frozen=True)
class MPCState:
    """Explicit MPC controller state.

    xi : (n,) observer estimate of the design-model state (plant, delay line, integrators).
    u : (n_u,) the move for this sample, computed at the previous step (strictly proper).
    warm : (N n_u,) the shifted move sequence, the next solve's start.
    """

    xi: np.ndarray
    u: np.ndarray
    warm: np.ndarray


class MPCController:
    """Constrained MPC on the discrete modal design model, with a Kalman observer: a Controller.

    The observer is the predictor of :func:`controllers.modal_sf.observer_controller`
    (same design model, same gain L, delay line known exactly, integral
    states on the rigid-body coordinates), fed with ``y_hat = -e`` so the
    reference enters through ``e = r - y``; the feedback ``u = -K xi`` is
    replaced by the first move of :class:`LinearMPC` on ``(Phi, Gamma)``::

        u[k]    = MPC(xi[k])            (solved at the end of step k-1: strictly proper)
        xi[k+1] = Ao xi[k] + Bu u[k] + Be e[k]

    With no active constraint and the DARE terminal cost, ``MPC(xi) = -K_lqr xi``
    exactly, so the controller equals ``observer_controller(dm, K_lqr, L)``.

    Constraints: ``u_min <= u <= u_max`` (actuator force limits, input units)
    hold exactly; ``y_min <= y - r <= y_max`` (position windows about the
    reference; with r = 0 the absolute position) is imposed on the predicted
    outputs of the estimated state over the horizon, so it holds on the true
    outputs only up to the estimation error, and the prediction assumes r
    constant: a moving reference or a disturbance can make the QP infeasible
    (counted in ``solve_times()["failures"]``, the solver's last iterate used).

    Not linear (``linear = False``): ``statespace()`` refuses; the simulator
    steps it sample by sample (``workbench.sim.closed_loop``).
    """

    linear = False

    def __init__(self, dm, L, mpc: LinearMPC):
        L = np.asarray(L, float)
        n, n_p, n_i = dm.n, dm.n_p, dm.n_i
        n_y, n_u = dm.C.shape[0], dm.Gamma.shape[1]
        if L.shape != (n_p, n_y):
            raise InputError(f"L: expected shape {(n_p, n_y)}, got {L.shape}")
        if (mpc.n, mpc.m) != (n, n_u):
            raise InputError(
                f"mpc: expected a LinearMPC on the design model ({n} states, {n_u} inputs), "
                f"got {mpc.n} states and {mpc.m} inputs"
            )
        k1 = n - n_i
        Lf = np.zeros((k1, n_y))
        Lf[:n_p] = L  # the delay line gets no correction: it is known exactly
        Pp, Gp, Cp, Dp = dm.plant
        Ao = np.zeros((n, n))
        Ao[:k1, :k1] = Pp - Lf @ Cp
        Ao[k1:, k1:] = np.eye(n_i)
        Bu = np.zeros((n, n_u))
        Bu[:k1] = Gp - Lf @ Dp
        Be = np.vstack([-Lf, dm.dt * dm.P_r])
        for a in (Ao, Bu, Be):
            a.setflags(write=False)
        self.dm, self.L, self.mpc = dm, L, mpc
        self._Ao, self._Bu, self._Be = Ao, Bu, Be
        self.input_names = tuple(dm.modal.output_names)
        self.output_names = tuple(dm.modal.input_names)
        self.delay_samples = dm.delay_samples
        self.log = SolveLog()

    @property
    def n_u(self) -> int:
        return self.mpc.m

    @property
    def n_y(self) -> int:
        return self.dm.C.shape[0]

    @property
    def fs(self) -> float:
        return self.dm.fs

    def statespace(self):
        """Refused: a constrained MPC is not a linear system."""
        raise InputError(
            "MPCController: no state-space form (constrained MPC is nonlinear); simulate it "
            "with workbench.sim.closed_loop (it steps the controller)"
        )

    def init(self) -> MPCState:
        """State at rest (xi = 0, u = 0); starts a new solve-time log."""
        self.log = SolveLog()
        z = np.zeros(self.mpc.N * self.mpc.m)
        return MPCState(xi=np.zeros(self.dm.n), u=np.zeros(self.n_u), warm=z)

    def output(self, state: MPCState) -> np.ndarray:
        """u[k], known before e[k] (solved at the previous step)."""
        return state.u

    def step(self, state: MPCState, e) -> tuple[np.ndarray, MPCState]:
        """u[k] (n_u,) and the next state from e[k] = r[k] - y[k] (n_y,); one QP per call."""
        e = np.asarray(e, float)
        if e.shape != (self.n_y,):
            raise InputError(f"e: expected shape ({self.n_y},), got {e.shape}")
        u = state.u
        xi = self._Ao @ state.xi + self._Bu @ u + self._Be @ e
        U, dt_s, ok = self.mpc.solve_from(xi, state.warm)
        self.log.times_s.append(dt_s)
        self.log.failures += not ok
        return u, MPCState(xi=xi, u=U[: self.n_u].copy(), warm=self.mpc.shift(U))

    def solve_times(self) -> dict:
        """Solve time per step of the last run: mean_s, max_s, n, failures."""
        return self.log.summary()


def design_mpc(
    model,
    fs: float,
    *,
    loop_delay_samples: int = 0,
    horizon: int = 20,
    Q=None,
    R=None,
    u_min=None,
    u_max=None,
    y_min=None,
    y_max=None,
    process=1.0,
    sensor=1.0,
    weights: dict | None = None,
) -> MPCController:
    """MPC controller on the modal design model of ``model`` (see :class:`MPCController`).

    Parameters
    ----------
    model : ModalModel, control.StateSpace or LTIModel
        Plant u -> y; :func:`controllers.modal_sf.design_model` builds the
        discrete design model (delay as shift states, integrators on the rigid
        DOFs, the minimality check).
    fs : float
        Controller rate, Hz.
    loop_delay_samples : int
        Computation delay of the loop, samples (the simulator applies it).
    horizon : int
        Prediction horizon N, samples.
    Q, R : arrays (n, n), (n_u, n_u), optional
        State and input weights (default ``modal_weights(dm, **weights)`` and I).
    u_min, u_max : float or (n_u,) array, optional
        Actuator force limits, input units (N).
    y_min, y_max : float or (n_y,) array, optional
        Position window on y - r, output units (m).
    process, sensor : float or array
        Kalman noise levels (:func:`controllers.modal_sf.kalman_gain`).
    """
    from controllers import modal_sf

    dm = modal_sf.design_model(model, fs, loop_delay_samples=loop_delay_samples)
    Q = modal_sf.modal_weights(dm, **(weights or {})) if Q is None else np.asarray(Q, float)
    R = np.eye(dm.Gamma.shape[1]) if R is None else np.atleast_2d(np.asarray(R, float))
    L = modal_sf.kalman_gain(dm, process=process, sensor=sensor)
    window = y_min is not None or y_max is not None
    mpc = LinearMPC(
        dm.Phi, dm.Gamma, Q, R, horizon, u_min=u_min, u_max=u_max,
        Cz=dm.C if window else None, y_min=y_min, y_max=y_max,
    )  # fmt: skip
    return MPCController(dm, L, mpc)
