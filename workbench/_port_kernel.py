"""Compiled substep loop of the port nonlinearities (:class:`workbench.sim.SubstepZoh`).

The one implementation of the port-force substep, used by the plants' nonlinear path
(``plants.sim``) and by the diagnosis' simulation models
(``workbench.diagnosis.nonlinear``). Per substep j of length h (the linear part exact,
the port force f(t) varying linearly from its start value f0 = F(x0) to its end value
f1 = F(x1), trapezoidal)::

    x1 = Phi x0 + G_old[j] u_old + G_new[j] u_new + Ga f0 + G1 f1
    F(x) = -F_c tanh(Cv x / v0) - k3 (Cp x)^3

with ``G1 = int_0^h e^{A s} (1 - s / h) ds Bp`` (the end value's weight) and
``Ga = int_0^h e^{A s} ds Bp - G1``. The friction end value is implicit: with
``xp`` the state without it and ``Mv = Cv G1``, it is the root ``r`` of
``g(r) = r + F_c tanh((Cv xp + Mv r) / v0)``, unique because the friction law is
monotone in the velocity and Mv is a (symmetric, positive semi-definite)
driving-point mobility. Newton steps ``-(I + diag(F_c sech^2 / v0) Mv)^-1 g`` (solved on
the ports not sliding at +-F_c only, :func:`_port_solve`: a sliding port's row is e_i) are
taken whole when they halve max |g|, else to the minimum along them of the convex
merit ``E(r) = r' Mv r / 2 + sum_j F_c v0 log cosh((Cv xp + Mv r)_j / v0)`` (its
gradient is Mv g: a Newton step on g is a descent direction of E; with one port the
line is the whole space, and a stiff friction, far from its root, converges in one
line search where a backtracking search crawls). The cubic spring is not
stiff at the levels used (a hardening spring far below the substep's rate): its end
value is predicted (held), corrected once from the state this gives (Heun), and the
friction re-solved from the corrected prediction.

:func:`port_record` also carries, on request, the state's forward sensitivities to the
friction law's parameters (levels, v0, the port velocity map) through the same substeps: the
linear part is linear in them, the friction's end value is differentiated at its converged
root (implicit function theorem, :func:`_sens_end`), so they are the exact derivative of the
simulation as computed (to the Newton tolerance), at about 2-2.5 simulations' cost for nine
parameters where forward differences take nine.

numba is a dependency of the project; :meth:`workbench.sim.SubstepZoh.advance` with
``engine="python"`` is the pure-NumPy reference of the same arithmetic (tested equal).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["port_record", "port_sample", "NEWTON_TOL", "NEWTON_ITER"]

#: Newton stops when every |g_j| <= NEWTON_TOL * max(F_c) (N), or its step is that small
NEWTON_TOL = 1e-13
#: ... or after this many steps (quadratic convergence needs a handful)
NEWTON_ITER = 60
#: a line search stops when the merit's slope is this fraction of its slope at the start...
_LINE_TOL = 0.01
#: ... or after this many evaluations (bisection halves the bracket at each)
_LINE_ITER = 60


#: tanh(x) is 1 to the last bit for x beyond this (1 - 2 e^-40 rounds to 1)
_TANH_ONE = 20.0


@numba.njit(cache=True, inline="always")
def _tanh(x):
    """tanh(x), the same number, without the library call where it is +-1 (a sliding port's
    friction, |v| >> v0: most of a record's calls, at ~15 ns each)."""
    if x > _TANH_ONE:
        return 1.0
    if x < -_TANH_ONE:
        return -1.0
    return np.tanh(x)


@numba.njit(cache=True, inline="always")
def _trial(a, Mv, Fc, iv0, r, dlt, s, rt, gt, tt):
    """rt = r + s dlt, gt = g(rt), tt = tanh(w / v0) at rt (in place); returns max |gt|."""
    n = r.shape[0]
    gmax = 0.0
    for i in range(n):
        rt[i] = r[i] + s * dlt[i]
    for i in range(n):
        w = a[i]
        for k in range(n):
            w += Mv[i, k] * rt[k]
        tt[i] = _tanh(w * iv0)
        gt[i] = rt[i] + Fc[i] * tt[i]
        gmax = max(gmax, abs(gt[i]))
    return gmax


@numba.njit(cache=True, inline="always")
def _port_map(MT, x, a):
    """a = M x (in place) for a port map M (n_p, n) given as MT = M', summed column by column."""
    for i in range(a.shape[0]):
        a[i] = 0.0
    for m in range(x.shape[0]):
        xm = x[m]
        for i in range(a.shape[0]):
            a[i] += MT[m, i] * xm


@numba.njit(cache=True, inline="always")
def _levels(Fc, k3):
    """(the largest friction level, whether any port has a cubic spring)."""
    fc_max = 0.0
    has_k3 = False
    for i in range(Fc.shape[0]):
        fc_max = max(fc_max, Fc[i])
        has_k3 = has_k3 or k3[i] != 0.0
    return fc_max, has_k3


@numba.njit(cache=True, inline="always")
def _sens_start(x, a, CvT, Fc, iv0, dFc, dlv, dCvT, has_dcv, S, dr, dw):
    """dr (n_th, n_p): the sensitivities of the friction at a sample's start,
    ``r = -F_c tanh(a / v0)``, ``a = Cv x``, ``x`` with sensitivities ``S`` (n_th, n):
    ``dr = -dF_c tanh - F_c sech^2 / v0 (dCv x + Cv S - a dlog v0)``."""
    n_th, n = S.shape
    n_p = Fc.shape[0]
    for q in range(n_th):
        _port_map(CvT, S[q], dw)  # Cv S[q]
        if has_dcv[q]:
            for m in range(n):
                xm = x[m]
                for i in range(n_p):
                    dw[i] += dCvT[q, m, i] * xm
        for i in range(n_p):
            ti = _tanh(a[i] * iv0)
            dr[q, i] = -dFc[q, i] * ti - Fc[i] * (1.0 - ti * ti) * iv0 * (dw[i] - a[i] * dlv[q])


@numba.njit(cache=True, inline="always")
def _gauss_solve(J, R, n_p):
    """Solve ``J x = R[q]`` for every row q of R (n_rhs, >= n_p) in place: Gaussian elimination
    with partial pivoting on J[:n_p, :n_p] (overwritten), the solutions in R[:, :n_p]."""
    n_rhs = R.shape[0]
    for c in range(n_p):
        piv = c
        big = abs(J[c, c])
        for i in range(c + 1, n_p):
            if abs(J[i, c]) > big:
                big = abs(J[i, c])
                piv = i
        if piv != c:
            for k in range(n_p):
                tmp = J[c, k]
                J[c, k] = J[piv, k]
                J[piv, k] = tmp
            for q in range(n_rhs):
                tmp = R[q, c]
                R[q, c] = R[q, piv]
                R[q, piv] = tmp
        for i in range(c + 1, n_p):
            fct = J[i, c] / J[c, c]
            if fct == 0.0:  # nothing to eliminate (a sliding port's row: e_i, s_i = 0)
                continue
            for k in range(c, n_p):
                J[i, k] -= fct * J[c, k]
            for q in range(n_rhs):
                R[q, i] -= fct * R[q, c]
    for q in range(n_rhs):
        for i in range(n_p - 1, -1, -1):
            acc = R[q, i]
            for k in range(i + 1, n_p):
                acc -= J[i, k] * R[q, k]
            R[q, i] = acc / J[i, i]


@numba.njit(cache=True, inline="always")
def _port_solve(Mv, s, R, J, W, idx):
    """Solve ``(I + diag(s) Mv) X = R[q]`` for every row q of R (n_rhs, n_p), in place (X in R).

    A port sliding at +-F_c (tanh 1 to the bit) has slope ``s_i = 0``: its row is ``e_i``, its
    unknown ``R[q, i]`` itself, substituted into the other ports' rows; those ports' (m of them,
    2-3 of a stage's 6 at a time) system is solved by Gaussian elimination with partial
    pivoting in ``J[:m, :m]``, their right-hand sides in ``W[:, :m]`` (W (n_rhs, n_p), idx
    (n_p,) int work arrays). The whole system's solution to rounding, at a fraction of its
    elimination's cost (the elimination dominated a stage's Newton step).
    """
    n_rhs, n_p = R.shape
    m = 0
    for i in range(n_p):
        if s[i] != 0.0:
            idx[m] = i
            m += 1
    if m == 0:
        return
    for a in range(m):
        i = idx[a]
        for b in range(m):
            J[a, b] = s[i] * Mv[i, idx[b]]
        J[a, a] += 1.0
        for q in range(n_rhs):
            acc = 0.0  # the sliding ports' known unknowns, moved to the right-hand side
            for k in range(n_p):
                if s[k] == 0.0:
                    acc += Mv[i, k] * R[q, k]
            W[q, a] = R[q, i] - s[i] * acc
    _gauss_solve(J, W, m)
    for q in range(n_rhs):
        for a in range(m):
            R[q, idx[a]] = W[q, a]


@numba.njit(cache=True, inline="always")
def _sens_end(x, CvT, Fc, iv0, Mv, dFc, dlv, dCvT, has_dcv, Sp, dr, w, sl, J, W, idx):
    """dr (n_th, n_p, in place): the sensitivities of a substep's friction end value ``r``,
    those of the state without it, ``xp``, given (``Sp``, n_th x n); ``x = xp + G1 r`` the end
    state (its sensitivities ``Sp + G1 dr``: :func:`_advance` forms them).

    ``r`` is the root of ``r + F_c tanh(w / v0) = 0``, ``w = Cv x = Cv xp + Mv r``; the implicit
    function theorem: ``(I + diag(s) Mv) dr = -(dF_c tanh + s (dCv x + Cv Sp - w dlog v0))``,
    ``s = F_c sech^2(w / v0) / v0`` (the converged root's, exact to the Newton tolerance: the
    derivative of the simulation as computed, not of a continuous-time idealization), solved by
    :func:`_port_solve` (sl (n_p,), J, W (n_th, n_p), idx: its work arrays).
    """
    n_th, n = Sp.shape
    n_p = Fc.shape[0]
    _port_map(CvT, x, w)
    for i in range(n_p):
        ti = _tanh(w[i] * iv0)
        si = Fc[i] * (1.0 - ti * ti) * iv0
        sl[i] = si
        for q in range(n_th):  # the right-hand sides, in dr
            if si == 0.0:  # a port sliding at +-F_c (tanh 1 to the bit): its force moves
                dr[q, i] = -dFc[q, i] * ti - 0.0  # with its level only (the same number)
                continue
            Sp_w = 0.0
            for m in range(n):
                Sp_w += CvT[m, i] * Sp[q, m]
            if has_dcv[q]:
                for m in range(n):
                    Sp_w += dCvT[q, m, i] * x[m]
            dr[q, i] = -dFc[q, i] * ti - si * (Sp_w - w[i] * dlv[q])
    _port_solve(Mv, sl, dr, J, W, idx)


@numba.njit(cache=True)
def _advance(
    x, PhiT, GaT, G1T, G_oldT, G_newT, has_old, u_new, u_old, CvT, CpT, Fc, v0, k3, Mv,
    has_fr, has_k3, fc_max, xp, f0, c0, r, a, g, J, dlt, rt, t, gt, tt,
    dFc, dlv, dCvT, has_dcv, S, Sp, dr, w, dw, phi_m, phi_i, HT, sl, R1, W1, W, idx,
):  # fmt: skip
    """x (in place) after the ``G_newT.shape[0]`` substeps of one sample (the matrices
    transposed: PhiT = Phi', GaT = Ga', G1T = G1', G_oldT[j] = G_old[j]', CvT = Cv', CpT = Cp').

    ``Phi x`` is summed over Phi's nonzero entries ``PhiT[phi_m, phi_i]`` (:func:`_nonzeros`:
    in the order of the dense sum, the same result; a modal model's Phi is 2x2 blocks, 26 of
    the stage's 256 entries), and so is ``Phi S``: with ``n_th = dFc.shape[0] > 0`` parameters
    (friction only, no cubic spring) also the state's sensitivities ``S[q] = dx / dtheta_q``
    (n_th, n), in place: see :func:`_sens_start` and :func:`_sens_end`; then ``HT`` =
    (Phi G1 + Ga)' (n_p, n, :func:`_folded_input`) and ``W`` (n_th, n_p) a work array. ``sl``
    (n_p,), ``R1``, ``W1`` (1, n_p), ``idx`` (n_p,) int: the port solves' work arrays
    (:func:`_port_solve`).

    Written out in one function: a call with array arguments costs reference counting
    (atomic operations), more than the arithmetic at these sizes. Products M x are summed
    column by column (MT = M'): the n running sums are independent, each summed in the order
    of a row dot product.
    """
    n = x.shape[0]
    n_p = Fc.shape[0]
    n_u = u_new.shape[0]
    n_th = dFc.shape[0]
    iv0 = 1.0 / v0
    stiff = False
    for i in range(n_p):
        stiff = stiff or Fc[i] * Mv[i, i] * iv0 > 1.0
    for j in range(G_newT.shape[0]):
        # port forces at the start of the substep, F(x0): the friction is the end value just
        # solved for (equal to F_c tanh(Cv x0 / v0) to the Newton tolerance), computed at the
        # first substep of the sample only
        if has_fr and j == 0:
            _port_map(CvT, x, a)
            for i in range(n_p):
                r[i] = -Fc[i] * _tanh(a[i] * iv0)
            if n_th > 0:
                _sens_start(x, a, CvT, Fc, iv0, dFc, dlv, dCvT, has_dcv, S, dr, dw)
        for i in range(n_p):
            f0[i] = r[i] if has_fr else 0.0  # r: also the warm start of the end value
            c0[i] = 0.0
        if has_k3:
            for i in range(n_p):
                q = 0.0
                for m in range(n):
                    q += CpT[m, i] * x[m]
                c0[i] = -k3[i] * q * q * q
                f0[i] += c0[i]
        # the state without the friction's end value (the spring's end value held); Phi x
        # over Phi's nonzero entries only, in the dense sum's order (the same result)
        for i in range(n):
            xp[i] = 0.0
        for e in range(phi_m.shape[0]):
            xp[phi_i[e]] += PhiT[phi_m[e], phi_i[e]] * x[phi_m[e]]
        for m in range(n_u):
            um = u_new[m]
            for i in range(n):
                xp[i] += G_newT[j, m, i] * um
        if has_old:
            for m in range(n_u):
                um = u_old[m]
                for i in range(n):
                    xp[i] += G_oldT[j, m, i] * um
        for m in range(n_p):
            fm = f0[m]
            if has_k3:
                cm = c0[m]
                for i in range(n):
                    xp[i] += GaT[m, i] * fm + G1T[m, i] * cm
            else:  # (no spring: c0 = 0, its term skipped)
                for i in range(n):
                    xp[i] += GaT[m, i] * fm
        if n_th > 0:
            # Sp = Phi S + Ga df0 at the sample's first substep (S its start, df0 = dr the start
            # value's, :func:`_sens_start`); after it the end state's S = Sp + G1 dr of the
            # substep before is folded in, Sp = Phi Sp + (Phi G1 + Ga) dr = Phi Sp + H dr
            # (HT = H'), S formed at the sample's end only (one product by G1 a sample, not a
            # substep). dr is sparse (a sliding port's force moves with its own level only):
            # its zeros are skipped
            for q in range(n_th):
                if j == 0:
                    for i in range(n):
                        Sp[q, i] = 0.0
                    for e in range(phi_m.shape[0]):
                        Sp[q, phi_i[e]] += PhiT[phi_m[e], phi_i[e]] * S[q, phi_m[e]]
                    for m in range(n_p):
                        fm = dr[q, m]
                        if fm != 0.0:
                            for i in range(n):
                                Sp[q, i] += GaT[m, i] * fm
                    continue
                for i in range(n):  # S[q] is free within the sample: the product's work row
                    S[q, i] = 0.0
                for e in range(phi_m.shape[0]):
                    S[q, phi_i[e]] += PhiT[phi_m[e], phi_i[e]] * Sp[q, phi_m[e]]
                for m in range(n_p):
                    fm = dr[q, m]
                    if fm != 0.0:
                        for i in range(n):
                            S[q, i] += HT[m, i] * fm
                for i in range(n):
                    Sp[q, i] = S[q, i]
        for rep in range(2 if has_k3 else 1):
            if rep == 1:  # Heun: the spring's end value from the state just found
                for i in range(n_p):
                    q = 0.0
                    for m in range(n):
                        q += CpT[m, i] * x[m]
                    dc = -k3[i] * q * q * q - c0[i]
                    for m in range(n):
                        xp[m] += G1T[i, m] * dc
            for i in range(n):
                x[i] = xp[i]
            if not has_fr:
                continue
            _port_map(CvT, xp, a)
            # Newton on g(r) = r + F_c tanh((a + Mv r) / v0), r warm-started (g, t at r)
            gmax = _trial(a, Mv, Fc, iv0, r, r, 0.0, rt, g, t)
            if stiff:
                # a stiff friction (F_c Mv_jj / v0 > 1) either stops its port within the
                # substep or slides at +-F_c: the force that stops each port alone, clipped
                # to +-F_c, starts Newton near the root where the warm start may be far
                for i in range(n_p):
                    dlt[i] = min(max(-a[i] / Mv[i, i], -Fc[i]), Fc[i]) if Mv[i, i] > 0 else 0.0
                gt_max = _trial(a, Mv, Fc, iv0, dlt, dlt, 0.0, rt, gt, tt)
                if gt_max < gmax:
                    for i in range(n_p):
                        r[i] = rt[i]
                        g[i] = gt[i]
                        t[i] = tt[i]
                    gmax = gt_max
            for _ in range(NEWTON_ITER):
                if gmax <= NEWTON_TOL * fc_max:
                    break
                for i in range(n_p):
                    sl[i] = Fc[i] * (1.0 - t[i] * t[i]) * iv0
                    R1[0, i] = -g[i]
                _port_solve(Mv, sl, R1, J, W1, idx)  # (I + diag(sl) Mv) dlt = -g
                for i in range(n_p):
                    dlt[i] = R1[0, i]
                dmax = 0.0
                for i in range(n_p):
                    dmax = max(dmax, abs(dlt[i]))
                if dmax <= NEWTON_TOL * fc_max:  # a step below the tolerance: the residual
                    for i in range(n_p):  # left is rounding (in Cv xp), not convergence
                        r[i] += dlt[i]
                    break
                # the whole step when it halves max |g| (the quadratic region); else the
                # minimum of the convex merit along it, s in (0, 1]: the root of its slope
                # phi'(s) = q . g(r + s dlt), q = Mv dlt, increasing in s (Newton on phi' kept
                # inside the bracket that phi' changes sign in, bisection when it leaves it)
                gt_max = _trial(a, Mv, Fc, iv0, r, dlt, 1.0, rt, gt, tt)
                if not gt_max <= 0.5 * gmax:
                    for i in range(n_p):
                        acc = 0.0
                        for k in range(n_p):
                            acc += Mv[i, k] * dlt[k]
                        f0[i] = acc  # q (f0 is free until the next substep)
                    slope0 = 0.0
                    dphi = 0.0
                    for i in range(n_p):
                        slope0 += f0[i] * g[i]
                        dphi += f0[i] * gt[i]
                    lo, hi, s = 0.0, 1.0, 1.0
                    for _ls in range(_LINE_ITER):
                        if dphi <= 0.0 and s == 1.0:  # the merit falls all the way: s = 1
                            break
                        if abs(dphi) <= _LINE_TOL * abs(slope0):
                            break
                        if dphi > 0.0:
                            hi = s
                        else:
                            lo = s
                        d2 = 0.0  # phi''(s) = q . (I + diag(F_c sech^2 / v0) Mv) dlt > 0
                        for i in range(n_p):
                            d2 += f0[i] * (dlt[i] + Fc[i] * (1.0 - tt[i] * tt[i]) * iv0 * f0[i])
                        s_new = s - dphi / d2 if d2 > 0.0 else 0.5 * (lo + hi)
                        if not (lo < s_new < hi):
                            s_new = 0.5 * (lo + hi)
                        s = s_new
                        gt_max = _trial(a, Mv, Fc, iv0, r, dlt, s, rt, gt, tt)
                        dphi = 0.0
                        for i in range(n_p):
                            dphi += f0[i] * gt[i]
                for i in range(n_p):
                    r[i] = rt[i]
                    g[i] = gt[i]
                    t[i] = tt[i]
                gmax = gt_max
            for m in range(n_p):
                rm = r[m]
                for i in range(n):
                    x[i] += G1T[m, i] * rm
            if n_th > 0:
                _sens_end(x, CvT, Fc, iv0, Mv, dFc, dlv, dCvT, has_dcv, Sp, dr, w, sl, J, W, idx)
    for q in range(n_th):  # the end state's sensitivities S = Sp + G1 dr
        for i in range(n):
            S[q, i] = Sp[q, i]
        for m in range(n_p):
            dm = dr[q, m]
            if dm != 0.0:
                for i in range(n):
                    S[q, i] += G1T[m, i] * dm


@numba.njit(cache=True)
def _nonzeros(PhiT):
    """(rows, cols) int arrays of PhiT's nonzero entries, row by row (the order of the dense
    product's sums): a modal model's Phi is 2x2 blocks, 26 of the stage's 256 entries."""
    n = PhiT.shape[0]
    nnz = 0
    for m in range(n):
        for i in range(n):
            nnz += PhiT[m, i] != 0.0
    phi_m = np.empty(nnz, np.int64)
    phi_i = np.empty(nnz, np.int64)
    e = 0
    for m in range(n):
        for i in range(n):
            if PhiT[m, i] != 0.0:
                phi_m[e] = m
                phi_i[e] = i
                e += 1
    return phi_m, phi_i


@numba.njit(cache=True)
def port_sample(x, PhiT, GaT, G1T, G_oldT, G_newT, has_old, u_new, u_old, CvT, CpT, Fc, v0, k3, Mv):
    """The state after one sample from ``x`` (a new array); ``u_new`` = u[k-m], ``u_old`` =
    u[k-m-1] (n_u,). Transposed shapes: PhiT (n, n), GaT / G1T (n_p, n), G_oldT / G_newT
    (n_sub, n_u, n), CvT / CpT (n, n_p); Fc / k3 (n_p,) N and N/m^3, v0 m/s, Mv = Cv G1
    (n_p, n_p)."""
    n = x.shape[0]
    n_p = Fc.shape[0]
    out = x.copy()
    fc_max, has_k3 = _levels(Fc, k3)
    phi_m, phi_i = _nonzeros(PhiT)
    _advance(
        out, PhiT, GaT, G1T, G_oldT, G_newT, has_old, u_new, u_old, CvT, CpT, Fc, v0, k3, Mv,
        fc_max > 0.0, has_k3, fc_max, np.empty(n), np.empty(n_p), np.empty(n_p),
        np.empty(n_p), np.empty(n_p), np.empty(n_p), np.empty((n_p, n_p)), np.empty(n_p),
        np.empty(n_p), np.empty(n_p), np.empty(n_p), np.empty(n_p),
        np.empty((0, n_p)), np.empty(0), np.empty((0, n, n_p)), np.empty(0, np.bool_),
        np.empty((0, n)),
        np.empty((0, n)), np.empty((0, n_p)), np.empty(n_p), np.empty(n_p), phi_m, phi_i,
        np.empty((0, n)), np.empty(n_p), np.empty((1, n_p)), np.empty((1, n_p)),
        np.empty((0, n_p)), np.empty(n_p, np.int64),
    )  # fmt: skip
    return out


@numba.njit(cache=True)
def _folded_input(PhiT, GaT, G1T):
    """HT = (Phi G1 + Ga)' (n_p, n): the weight of a substep's friction end value in the next
    substep's state without its own (``xp+ = Phi (xp + G1 r) + Ga r + ...``)."""
    n_p, n = GaT.shape
    HT = GaT.copy()
    for m in range(n_p):
        for i in range(n):
            acc = 0.0
            for k in range(n):
                acc += PhiT[k, i] * G1T[m, k]
            HT[m, i] += acc
    return HT


@numba.njit(cache=True)
def port_record(
    PhiT, GaT, G1T, G_oldT, G_newT, has_old, C, D, CvT, CpT, Fc, v0, k3, Mv, um, um1, y, p,
    dFc, dlv, dCvT, has_dcv, dy,
):  # fmt: skip
    """Run a record from rest: y[k] = C x + D um[k], p[k] = Cp x (written), then one sample.

    ``um`` = u[k-m], ``um1`` = u[k-m-1] (N, n_u), saturated; y (N, n_y), p (N, n_p); the
    other arguments as :func:`port_sample`'s.

    Sensitivities of the outputs to ``n_th = dFc.shape[0]`` parameters theta (0: none; friction
    only, no cubic spring), forward, alongside the simulation: ``dy[k, :, q] = C dx[k] /
    dtheta_q`` (written, (N, n_y, n_th)), given how the law depends on them: ``dFc[q]`` =
    dF_c / dtheta_q (n_th, n_p) N, ``dlv[q]`` = dlog v0 / dtheta_q (n_th,), ``dCvT[q]`` =
    (dCv / dtheta_q)' (n_th, n, n_p; row q read only if ``has_dcv[q]``, (n_th,) bool). The
    linear part does not depend on theta; x starts at rest, so its sensitivities at 0.
    """
    n = PhiT.shape[0]
    n_p = Fc.shape[0]
    n_y = C.shape[0]
    n_u = um.shape[1]
    n_th = dFc.shape[0]
    x = np.zeros(n)
    fc_max, has_k3 = _levels(Fc, k3)
    xp = np.empty(n)
    f0 = np.empty(n_p)
    c0 = np.empty(n_p)
    r = np.empty(n_p)
    a = np.empty(n_p)
    g = np.empty(n_p)
    J = np.empty((n_p, n_p))
    dlt = np.empty(n_p)
    rt = np.empty(n_p)
    t = np.empty(n_p)
    gt = np.empty(n_p)
    tt = np.empty(n_p)
    S = np.zeros((n_th, n))
    Sp = np.empty((n_th, n))
    dr = np.zeros((n_th, n_p))
    w = np.empty(n_p)
    dw = np.empty(n_p)
    phi_m, phi_i = _nonzeros(PhiT)
    HT = _folded_input(PhiT, GaT, G1T) if n_th > 0 else np.empty((0, n))
    sl = np.empty(n_p)
    R1 = np.empty((1, n_p))
    W1 = np.empty((1, n_p))
    W = np.empty((n_th, n_p))
    idx = np.empty(n_p, np.int64)
    for k in range(um.shape[0]):
        for i in range(n_y):
            acc = 0.0
            for m in range(n):
                acc += C[i, m] * x[m]
            for m in range(n_u):
                acc += D[i, m] * um[k, m]
            y[k, i] = acc
            for q in range(n_th):
                acc = 0.0
                for m in range(n):
                    acc += C[i, m] * S[q, m]
                dy[k, i, q] = acc
        _port_map(CpT, x, p[k])
        _advance(
            x, PhiT, GaT, G1T, G_oldT, G_newT, has_old, um[k], um1[k], CvT, CpT, Fc, v0, k3, Mv,
            fc_max > 0.0, has_k3, fc_max, xp, f0, c0, r, a, g, J, dlt, rt, t, gt, tt,
            dFc, dlv, dCvT, has_dcv, S, Sp, dr, w, dw, phi_m, phi_i, HT, sl, R1, W1, W, idx,
        )  # fmt: skip
