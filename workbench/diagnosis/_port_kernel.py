"""Compiled inner loop of :func:`workbench.diagnosis.nonlinear.simulate_nonlinear`.

One pass over the N samples, ``n_sub`` substeps each, the same arithmetic as the
Python loop it replaces (:meth:`workbench.sim.SubstepZoh.advance` with the port law
of :mod:`workbench.diagnosis.nonlinear`)::

    y[k] = C x + D u[k],  p[k] = Cp x
    per substep:  v = CA x
                  f = u[k] - sign(v) min(F_c |tanh(v / v0)|, |v| / mobility) - k3 (Cp x)^3
                  x <- Phi x + Gp f

A fitted element is judged by simulating it many times (regressions, refinement,
several port hypotheses), which in Python costs about a second per beam record.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["port_loop"]


@numba.njit(cache=True)
def port_loop(Phi, Gp, C, D, Cp, CA, ud, Fc, k3, v0, mobility, n_sub, y, p):  # pragma: no cover
    n = Phi.shape[0]
    n_u = Gp.shape[1]
    n_y = C.shape[0]
    N = ud.shape[0]
    x = np.zeros(n)
    xn = np.zeros(n)
    f = np.zeros(n_u)
    for k in range(N):
        for i in range(n_y):
            acc = 0.0
            for m in range(n):
                acc += C[i, m] * x[m]
            for j in range(n_u):
                acc += D[i, j] * ud[k, j]
            y[k, i] = acc
        for j in range(n_u):
            acc = 0.0
            for m in range(n):
                acc += Cp[j, m] * x[m]
            p[k, j] = acc
        for _ in range(n_sub):
            for j in range(n_u):
                v = 0.0
                q = 0.0
                for m in range(n):
                    v += CA[j, m] * x[m]
                    q += Cp[j, m] * x[m]
                fr = min(Fc[j] * abs(np.tanh(v / v0)), abs(v) / mobility[j])
                s = 1.0 if v > 0 else (-1.0 if v < 0 else 0.0)
                f[j] = ud[k, j] - s * fr - k3[j] * q * q * q
            for i in range(n):
                acc = 0.0
                for m in range(n):
                    acc += Phi[i, m] * x[m]
                for j in range(n_u):
                    acc += Gp[i, j] * f[j]
                xn[i] = acc
            for i in range(n):
                x[i] = xn[i]
