"""Sampled simulation of a :class:`~plants.modal.LinearChain`: fast linear path and nonlinear path.

Linear path: exact zero-order-hold discretization with the (fractional) input
delay (:func:`workbench.sim.c2d_zoh`), then the recursion
x[k+1] = Ad x[k] + B0 u[k-m] + B1 u[k-m-1] is run block by block: Ad is block
lower triangular (actuator lags, then 2 x 2 mode blocks, then sensor lags), so
every block is a first- or second-order recursion driven by the blocks before
it, which :func:`scipy.signal.lfilter` runs in compiled code. The result equals
the plain state recursion to rounding (tested), at a fraction of its cost.

Nonlinear path (friction, cubic spring, saturation): a per-sample loop, compiled
(:mod:`workbench._port_kernel`, the one implementation of the port-force substep,
shared with the diagnosis' simulation models), with ``substeps`` substeps of
:func:`workbench.sim.substep_zoh` per sample: the linear part propagated exactly,
the input switching at the fractional delay, the port force varying linearly
over the substep from its start value to its end value (trapezoidal, second
order), the friction's end value implicit (a safeguarded Newton step on a convex
merit). This module only supplies the port-force law and the substep count.

The smooth Coulomb friction F = -F_c tanh(v / v0) is stiff: where the port sticks
it is a damper of F_c / v0 (N s/m). Substeps (``Effects.substeps``; None = auto):
the smallest count n with

    h F_c mobility / v0 <= 1 / 64,   h = 1 / (fs n)  (s),

for every port, mobility = (Cv Bp)_jj (1/kg: the port's driving-point velocity
per unit force and second, the velocity one newton held over one substep gives
it is h times this), clamped to 32..128 (:data:`MIN_FRICTION_SUBSTEPS`,
:data:`MAX_SUBSTEPS`: weak friction needs substeps to resolve the law's transitions
rather than its stiffness); without friction 8 (:data:`MIN_SUBSTEPS`; the cubic spring
of the plants is not stiff: 8 trapezoidal substeps are converged, measured on the
stage's test level, 6e-6 of the record's noise from 32). At the clamp (the wafer stage
with v0 = 1 um/s) the ratio is above 1/64: the implicit trapezoid stays stable and
accurate there (tested against 4x the substeps).

The block recursion of the linear path is kept here rather than in
``workbench.sim`` because it needs the chain's block-triangular layout; the
generic :func:`workbench.sim.dlsim` gives the same output (tested).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.signal

from workbench import sim

from .modal import LinearChain

__all__ = ["DiscreteChain"]

#: fewest and most substeps per sample of the automatic count
MIN_SUBSTEPS, MAX_SUBSTEPS = 8, 128
#: fewest with friction: the stiffness rule alone gives weak friction too few substeps to resolve
#: the smooth law's transitions (casegen's subtle beam friction: 9 substeps, 0.29 of the record's
#: noise from the converged response; 32: 0.015)
MIN_FRICTION_SUBSTEPS = 32
#: the automatic count keeps h F_c mobility / v0 at most this (dimensionless)
FRICTION_STEP_RATIO = 1.0 / 64

#: Modes whose drive is formed at once in the fast linear path (bounds memory to N x 2 x this).
_CHUNK_MODES = 24


@dataclass(frozen=True)
class DiscreteChain:
    """A linear chain sampled at ``fs`` behind a ZOH, with an input delay and port nonlinearities.

    Parameters
    ----------
    chain : LinearChain
        Continuous linear dynamics; its ``effects`` also give the nonlinear
        port forces, the saturation and the number of substeps.
    fs : float
        Sampling frequency, Hz.
    delay_s : float
        Input delay, s.
    """

    chain: LinearChain
    fs: float
    delay_s: float = 0.0

    @cached_property
    def zoh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(Ad, B0, B1, m) of :func:`workbench.sim.c2d_zoh`."""
        mats = self.chain.matrices
        return sim.c2d_zoh(mats["A"], mats["B"], 1.0 / self.fs, delay_s=self.delay_s)

    # -- nonlinear port model ------------------------------------------------------------
    @cached_property
    def _nl(self) -> dict[str, np.ndarray]:
        e = self.chain.effects
        n_u = self.chain.n_u
        zero = np.zeros(n_u)

        def vec(v):
            return (
                zero.copy() if v is None else np.broadcast_to(np.asarray(v, float), (n_u,)).copy()
            )

        sat = np.full(n_u, np.inf) if e.saturation is None else vec(e.saturation)
        return {
            "fc": vec(e.friction_force),
            "k3": vec(e.cubic_stiffness),
            "sat": sat,
            "v0": np.array(e.friction_velocity),
        }

    @property
    def nonlinear(self) -> bool:
        """True when a port force (friction, cubic spring) needs the substep loop.

        Saturation alone is memoryless at the input: the fast linear path runs
        on the saturated input.
        """
        nl = self._nl
        return bool(np.any(nl["fc"] > 0) or np.any(nl["k3"] > 0))

    @property
    def saturation(self) -> np.ndarray:
        """Symmetric saturation of each delayed input, (n_u,), N (inf = none)."""
        return self._nl["sat"].copy()

    def saturate(self, u: np.ndarray) -> np.ndarray:
        sat = self._nl["sat"]
        return np.clip(u, -sat, sat) if np.any(np.isfinite(sat)) else u

    @cached_property
    def substeps(self) -> int:
        """Substeps per sample of the nonlinear path: ``Effects.substeps``, or when None the
        automatic count of the module docstring (8 without friction)."""
        given = self.chain.effects.substeps
        if given is not None:
            return int(given)
        fc = self._nl["fc"]
        if not np.any(fc > 0):
            return MIN_SUBSTEPS
        mats = self.chain.matrices
        mobility = np.abs(np.diag(mats["Cv"] @ mats["Bp"]))  # 1/kg
        # h F_c mobility / v0 <= ratio  <=>  n >= F_c mobility / (v0 fs ratio)
        need = np.max(fc * mobility) / (float(self._nl["v0"]) * self.fs * FRICTION_STEP_RATIO)
        return int(np.clip(np.ceil(need * (1 - 1e-12)), MIN_FRICTION_SUBSTEPS, MAX_SUBSTEPS))

    @cached_property
    def substep(self) -> sim.SubstepZoh:
        """Per-substep propagation (:func:`workbench.sim.substep_zoh`) with the port forces."""
        mats = self.chain.matrices
        return sim.substep_zoh(
            mats["A"],
            mats["B"],
            mats["Bp"],
            1.0 / self.fs,
            self.substeps,
            delay_s=self.delay_s,
        )

    @cached_property
    def port_law(self) -> sim.PortLaw:
        """Friction and cubic spring at the ports (:class:`workbench.sim.PortLaw`)."""
        nl = self._nl
        mats = self.chain.matrices
        return sim.PortLaw(
            Cv=mats["Cv"],
            Cp=mats["Cp"],
            friction_force=nl["fc"],
            friction_velocity=float(nl["v0"]),
            cubic_stiffness=nl["k3"],
        )

    def port_force(self, x: np.ndarray) -> np.ndarray:
        """Friction and cubic-spring force at the ports, (n_u,) N, for state x (n_x,)."""
        return self.port_law.force(x)

    def advance_nonlinear(
        self,
        x: np.ndarray,
        u_new: np.ndarray,
        u_old: np.ndarray,
        *,
        engine: str = "compiled",
    ) -> np.ndarray:
        """State after one sample; ``u_new`` = u[k-m], ``u_old`` = u[k-m-1], both saturated.

        ``engine="python"``: the NumPy reference of the compiled substep loop.
        """
        if engine == "compiled":
            return self._stepper(x, u_new, u_old)
        return self.substep.advance(x, u_new, u_old, self.port_law, engine=engine)

    @cached_property
    def _stepper(self):
        return self.substep.stepper(self.port_law)

    # -- simulation ----------------------------------------------------------------------
    def simulate(self, u: np.ndarray) -> np.ndarray:
        """Noise-free output (N, n_y) from rest for input u (N, n_u), y[k] at k / fs."""
        if self.nonlinear:
            return self._simulate_nonlinear(u)
        return self._simulate_linear(self.saturate(u))

    def _simulate_nonlinear(self, u: np.ndarray, *, engine: str = "compiled") -> np.ndarray:
        mats = self.chain.matrices
        m = self.substep.m
        us = self.saturate(u)
        um, um1 = sim.delayed(us, m), sim.delayed(us, m + 1)
        if engine == "compiled":
            return self.substep.simulate(self.port_law, um, um1, mats["C"], mats["D"])[0]
        x = np.zeros(mats["C"].shape[1])
        X = np.zeros((u.shape[0], x.size))
        for k in range(u.shape[0]):
            X[k] = x
            x = self.advance_nonlinear(x, um[k], um1[k], engine=engine)
        return X @ mats["C"].T + um @ mats["D"].T

    def _simulate_linear(self, u: np.ndarray) -> np.ndarray:
        Ad, B0, B1, m = self.zoh
        mats = self.chain.matrices
        C, D = mats["C"], mats["D"]
        n_a, n_m2, n_s = self.chain.layout[2]
        N = u.shape[0]
        um, um1 = sim.delayed(u, m), sim.delayed(u, m + 1)
        has_b1 = bool(np.any(B1))

        def drive(rows):
            d = um @ B0[rows].T
            if has_b1:
                d += um1 @ B1[rows].T
            return d

        y = um @ D.T if np.any(D) else np.zeros((N, C.shape[0]))
        # group 1: actuator lags, scalar recursions
        g1 = np.arange(n_a)
        X1 = np.zeros((N, n_a))
        if n_a:
            d1 = drive(g1)
            for i in range(n_a):
                X1[:, i] = scipy.signal.lfilter([0.0, 1.0], [1.0, -Ad[i, i]], d1[:, i])
            y += X1 @ C[:, g1].T
        g3 = np.arange(n_a + n_m2, n_a + n_m2 + n_s)
        acc3 = drive(g3) + X1 @ Ad[np.ix_(g3, g1)].T if n_s else None
        # group 2: 2 x 2 blocks, one per mode, in chunks to bound the memory
        n_modes = n_m2 // 2
        for start in range(0, n_modes, _CHUNK_MODES):
            k = np.arange(start, min(start + _CHUNK_MODES, n_modes))
            q, v = n_a + 2 * k, n_a + 2 * k + 1
            rows = np.concatenate([q, v])
            W = drive(rows)
            if n_a:
                W += X1 @ Ad[np.ix_(rows, g1)].T
            Wq, Wv = W[:, : k.size], W[:, k.size :]
            F11, F12, F21, F22 = Ad[q, q], Ad[q, v], Ad[v, q], Ad[v, v]
            # (zI - F)^-1 = adj(zI - F) / det(zI - F), written in z^-1
            Vq = np.zeros((N, k.size))
            Vv = np.zeros((N, k.size))
            Vq[1:] = Wq[:-1]
            Vq[2:] += -F22 * Wq[:-2] + F12 * Wv[:-2]
            Vv[1:] = Wv[:-1]
            Vv[2:] += -F11 * Wv[:-2] + F21 * Wq[:-2]
            Xq = np.empty_like(Vq)
            Xv = np.empty_like(Vv)
            for i in range(k.size):
                den = [1.0, -(F11[i] + F22[i]), F11[i] * F22[i] - F12[i] * F21[i]]
                Xi = scipy.signal.lfilter(
                    [1.0], den, np.stack([Vq[:, i], Vv[:, i]], axis=1), axis=0
                )
                Xq[:, i], Xv[:, i] = Xi[:, 0], Xi[:, 1]
            y += Xq @ C[:, q].T
            if np.any(C[:, v]):
                y += Xv @ C[:, v].T
            if n_s:
                acc3 += Xq @ Ad[np.ix_(g3, q)].T + Xv @ Ad[np.ix_(g3, v)].T
        # group 3: sensor lags, scalar recursions driven by everything before
        for i, r in enumerate(g3):
            x3 = scipy.signal.lfilter([0.0, 1.0], [1.0, -Ad[r, r]], acc3[:, i])
            y += np.outer(x3, C[:, r])
        return y
