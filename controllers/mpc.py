"""Linear MPC on a discrete state-space model, solved with casadi's QP interface.

``x+ = A x + B u``, horizon N, cost ``sum x'Qx + u'Ru + x_N' P x_N`` (P defaults
to the DARE solution, so the unconstrained MPC equals the infinite-horizon
LQR), bounds ``u_min <= u <= u_max`` (actuator force limits, N) and
``y_min <= Cz x <= y_max`` (position windows, m) on x_1..x_N.
The QP is condensed (U only) and built ONCE: H and the constraint matrix are
constant, the gradient is ``F x0``; the solver (qpOASES) is warm-started from
the previous solution shifted by one step.  Solve time per call is recorded.
"""

from __future__ import annotations

import time

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
            x0=self._warm if warm_start else np.zeros_like(self._warm),
        )
        self.solve_times.append(time.perf_counter() - t0)
        U = np.asarray(sol["x"]).ravel()
        # shift by one step for the next warm start
        self._warm = np.concatenate([U[self.m :], U[-self.m :]])
        return U[: self.m]

    @property
    def report(self) -> dict:
        """Solve time per step (s): mean, max, count."""
        t = np.asarray(self.solve_times)
        return {
            "mean_s": float(t.mean()) if t.size else 0.0,
            "max_s": float(t.max()) if t.size else 0.0,
            "n": int(t.size),
        }
