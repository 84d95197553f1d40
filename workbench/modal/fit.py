"""Modal parameter estimation from a MIMO FRF (seed 001, sections 4-5).

Data flow::

    FrfData (spec 1b: freq, G (n_f, n_y, n_u), G_var)
      --lscf--> StabilizationDiagram: poles of the polyreference least-squares
                complex-frequency estimator at every model order 1..max_order,
                each marked stable in frequency / damping against the order below
      --select_poles--> initial (freq_hz, damping) of the physical modes
      --ModalStructure + diagnosis.fit.fit--> noise-weighted (1/G_var)
                Levenberg-Marquardt fit of all FRF elements at once:
                G(s) = sum_k c_k b_k^T / (s^2 + 2 z_k w_k s + w_k^2) + D [+ L / s^2]
                (rank-one residues, residual compliance D, optional rigid / lower
                residual term L for modes below the band)
      --> ModalFit: ModalModel, frequencies and damping +- std, mode table,
                arrays for the spec-2 model file

The nonlinear fit reuses the one fitting engine of the workbench
(:func:`workbench.diagnosis.fit.fit`, variable projection): the nonlinear
parameters are each mode's frequency, log damping and input vector ``b_k``
(normalized to 1 at its largest entry, which removes the scale shared with
``c_k``); the output vectors ``c_k``, ``D`` and ``L`` enter linearly and are
solved in closed form inside every residual evaluation. The engine gets the exact
variable-projection Jacobian (:meth:`ModalStructure.jacobian`, Golub-Pereyra) instead
of finite differences: 6 Jacobians instead of ~230 residuals on the beam (38 theta).

References
----------
B. Peeters, H. Van der Auweraer, P. Guillaume, J. Leuridan, "The PolyMAX
frequency-domain method: a new standard for modal parameter estimation?",
Shock and Vibration 11 (2004) 395-409.
P. Guillaume et al., "A poly-reference implementation of the least-squares
complex frequency-domain estimator", IMAC XXI, 2003.
G.H. Golub, V. Pereyra, "The differentiation of pseudo-inverses and nonlinear
least squares problems whose variables separate", SIAM J. Numer. Anal. 10 (1973).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from workbench.core.arrays import readonly
from workbench.core.errors import InputError
from workbench.diagnosis.fit import FitResult, Realized, fit
from workbench.diagnosis.problem import FrfProblem
from workbench.io.formats import FrfData
from workbench.modal.model import ModalModel, Mode

__all__ = [
    "StabilizationDiagram",
    "ModalFit",
    "ModalStructure",
    "lscf",
    "select_poles",
    "fit_modal",
    "plot_stabilization",
    "plot_fit_overlay",
]


# ------------------------------------------------------------------ LSCF
@dataclass(frozen=True)
class StabilizationDiagram:
    """Poles of the p-LSCF estimator at every model order.

    Attributes
    ----------
    order : (n_p,) int array
        Model order (polynomial degree) of each pole.
    freq_hz : (n_p,) array
        Natural frequency ``|s| / 2 pi``, Hz.
    damping : (n_p,) array
        Damping ratio ``-Re(s) / |s|``.
    stable_freq, stable_damping : (n_p,) bool arrays
        A pole of the order below lies within ``freq_tol`` (relative) and its
        damping within ``damping_tol`` (relative).
    band_hz : (2,) array
        Frequency band the estimator saw, Hz.
    order_max : (n_p,) int array
        Highest order computed in the sub-band of each pole (see :func:`lscf`).
    """

    order: np.ndarray
    freq_hz: np.ndarray
    damping: np.ndarray
    stable_freq: np.ndarray
    stable_damping: np.ndarray
    band_hz: np.ndarray
    order_max: np.ndarray

    def __post_init__(self):
        keys = ("order", "freq_hz", "damping", "stable_freq", "stable_damping", "band_hz")
        for key in (*keys, "order_max"):
            object.__setattr__(self, key, readonly(getattr(self, key)))

    @property
    def stable(self) -> np.ndarray:
        """(n_p,) bool: stable in frequency and damping, physical (0 < damping < 1)."""
        return self.stable_freq & self.stable_damping & (self.damping > 0) & (self.damping < 1)


def _lscf_weights(data: FrfData) -> np.ndarray:
    """Scalar weight per line and output (n_f, n_y): 1 / noise std (mean over inputs).

    Without ``G_var``: 1 / the output row's norm, so that every line counts alike.
    """
    if data.G_var is not None and np.any(data.G_var > 0):
        var = np.mean(data.G_var, axis=2)
        floor = 1e-6 * np.median(var[var > 0])
        return 1.0 / np.sqrt(np.maximum(var, floor))
    norm = np.linalg.norm(data.G, axis=2)
    return 1.0 / np.where(norm > 0, norm, np.max(norm) + 1e-300)


def lscf(
    data: FrfData,
    *,
    max_order: int = 30,
    band_ratio: float = 10.0,
    freq_tol: float = 0.01,
    damping_tol: float = 0.05,
) -> StabilizationDiagram:
    """Polyreference least-squares complex-frequency (p-LSCF) poles at orders 1..max_order.

    Right matrix-fraction model per output row ``H_o(w) = B_o(w) A(w)^-1`` in
    the z-domain basis ``Omega = exp(j w Ts)``, ``Ts = 1 / (2 f_max)``; the
    numerator coefficients are eliminated (reduced normal equations), the
    highest denominator coefficient is fixed to the identity, and the poles are
    the eigenvalues of the block companion matrix, ``s = ln(z) / Ts``.

    A band wider than ``band_ratio`` (f_max / f_min) is split into log-equal
    sub-bands, each estimated on its own lines (widened by 1.5x on either
    side) and keeping the poles of its own part: one ``Ts`` for a band of
    0.25-1000 Hz puts the suspension modes at ``z ~ 1`` where the estimator
    cannot resolve them (beam: 2.6 and 3.2 Hz were missed at order 30).

    Parameters
    ----------
    data : FrfData
        FRF (n_f, n_y, n_u); ``G_var`` weights the lines.
    max_order : int
        Highest polynomial order; an order p gives ``p n_u`` poles (lower in a
        sub-band with few lines).
    band_ratio : float
        Widest frequency ratio estimated at once.
    freq_tol, damping_tol : float
        Relative tolerances of the stability marks against the order below.
    """
    if not (isinstance(max_order, int | np.integer) and 1 <= max_order <= 200):
        raise InputError(f"max_order: expected an integer in 1..200, got {max_order!r}")
    if not band_ratio > 1.5:
        raise InputError(f"band_ratio: expected > 1.5, got {band_ratio!r}")
    f = data.freq
    lo, hi = float(f[0]), float(f[-1])
    n_bands = max(1, int(np.ceil(np.log(hi / lo) / np.log(band_ratio))))
    edges = lo * (hi / lo) ** (np.arange(n_bands + 1) / n_bands)
    parts = []
    for b in range(n_bands):
        sel = (f >= edges[b] / 1.5) & (f <= edges[b + 1] * 1.5)
        # R_o needs about 2 lines per coefficient
        q_max = min(int(max_order), int(np.sum(sel)) // 2 - 1)
        if q_max < 1:
            continue
        order, freq, damp = _lscf_band(f[sel], data.G[sel], _lscf_weights(data)[sel], q_max)
        last = b == n_bands - 1
        keep = (freq >= edges[b]) & ((freq <= edges[b + 1]) if last else (freq < edges[b + 1]))
        parts.append((order[keep], freq[keep], damp[keep], q_max))
    order = np.concatenate([p[0] for p in parts]).astype(int)
    freq = np.concatenate([p[1] for p in parts])
    damp = np.concatenate([p[2] for p in parts])
    top = np.concatenate([np.full(p[0].size, p[3]) for p in parts]).astype(int)
    sf, sd = _stability(order, freq, damp, freq_tol, damping_tol)
    return StabilizationDiagram(
        order=order,
        freq_hz=freq,
        damping=damp,
        stable_freq=sf,
        stable_damping=sd,
        band_hz=np.array([lo, hi]),
        order_max=top,
    )


def _lscf_band(f: np.ndarray, G: np.ndarray, W: np.ndarray, p: int):
    """p-LSCF on one band: (order, freq_hz, damping) of the poles at orders 1..p.

    ``f`` (n_f,) Hz, ``G`` (n_f, n_y, n_u), ``W`` (n_f, n_y) weights.
    """
    n_y, n_u = G.shape[1:]
    Ts = 1.0 / (2.0 * f[-1])
    Om = np.exp(1j * 2 * np.pi * f * Ts)[:, None] ** np.arange(p + 1)[None]  # (n_f, p+1)
    nb = (p + 1) * n_u
    R = np.zeros((n_y, p + 1, p + 1))
    S = np.zeros((n_y, p + 1, nb))
    T = np.zeros((n_y, nb, nb))
    for o in range(n_y):
        X = W[:, o, None] * Om  # (n_f, p+1)
        # Y[f, (r, i)] = -W Om^r H_o,i: the rows of alpha_r ordered r-major
        Y = -(X[:, :, None] * G[:, o, None, :]).reshape(f.size, nb)
        # Re(A^H B) = Ar^T Br + Ai^T Bi: one real product on stacked parts, half the flops of
        # the complex product whose imaginary part would be thrown away
        Xs = np.concatenate([X.real, X.imag])
        Ys = np.concatenate([Y.real, Y.imag])
        R[o] = Xs.T @ Xs
        S[o] = Xs.T @ Ys
        T[o] = Ys.T @ Ys
    # the reduced normal matrix of order q is sum_o T_o - S_o^T R_o^-1 S_o on the leading
    # (q + 1) rows of R_o, S_o: with R_o = L_o L_o^T, the leading block of L_o is the factor of
    # the leading block of R_o and Z_o = L_o^-1 S_o serves every order (S_o^T R_o^-1 S_o =
    # Z_q^T Z_q on Z_o's leading rows): one factorization per output instead of one per order.
    # A narrow band makes R_o nearly singular at high orders: there the factor is not trusted
    # (Cholesky fails, or its diagonal spans > 1e6) and every order solves with R_o's block
    Z = np.empty_like(S)
    chol = True
    for o in range(n_y):
        try:
            L = np.linalg.cholesky(R[o])
        except np.linalg.LinAlgError:
            chol = False
            break
        dg = np.abs(np.diag(L))
        if not dg.min() > 1e-6 * dg.max():
            chol = False
            break
        Z[o] = scipy.linalg.solve_triangular(L, S[o], lower=True)
    T_sum = T.sum(axis=0)
    orders, freqs, damps = [], [], []
    for q in range(1, p + 1):
        nq = (q + 1) * n_u
        if chol:
            Zq = Z[:, : q + 1, :nq].reshape(n_y * (q + 1), nq)
            M = T_sum[:nq, :nq] - Zq.T @ Zq
        else:
            M = T_sum[:nq, :nq].copy()
            for o in range(n_y):
                So = S[o, : q + 1, :nq]
                M -= So.T @ np.linalg.solve(R[o, : q + 1, : q + 1], So)
        # alpha_q = I: [alpha_0..alpha_{q-1}] from the first q n_u rows
        m = q * n_u
        try:
            alpha = -np.linalg.solve(M[:m, :m], M[:m, m:])  # (q n_u, n_u)
        except np.linalg.LinAlgError:
            continue
        comp = np.zeros((m, m))
        comp[:-n_u, n_u:] = np.eye(m - n_u)
        # A(z) v = 0, A(z) = sum_r z^r alpha_r, alpha_q = I: z^q v = -sum_{r<q} z^r alpha_r v
        comp[-n_u:, :] = -np.hstack([alpha[r * n_u : (r + 1) * n_u] for r in range(q)])
        z = np.linalg.eigvals(comp)
        z = z[(np.abs(z) > 0) & (z.imag > 0)]  # one of each conjugate pair; real poles: no mode
        s = np.log(z) / Ts
        wn = np.abs(s)
        orders.append(np.full(s.size, q))
        freqs.append(wn / (2 * np.pi))
        damps.append(-s.real / wn)
    if not orders:
        return np.zeros(0, int), np.zeros(0), np.zeros(0)
    return np.concatenate(orders), np.concatenate(freqs), np.concatenate(damps)


def _stability(order, freq, damp, freq_tol, damping_tol):
    """Stable marks: nearest pole of the order below within the relative tolerances."""
    sf = np.zeros(freq.size, bool)
    sd = np.zeros(freq.size, bool)
    for q in np.unique(order):
        cur = np.flatnonzero(order == q)
        prev = np.flatnonzero(order == q - 1)
        if prev.size == 0:
            continue
        df = np.abs(freq[cur][:, None] - freq[prev][None]) / freq[cur][:, None]
        nearest = np.argmin(df, axis=1)
        sf[cur] = df[np.arange(cur.size), nearest] < freq_tol
        dz = np.abs(damp[cur] - damp[prev][nearest]) / np.maximum(np.abs(damp[cur]), 1e-12)
        sd[cur] = sf[cur] & (dz < damping_tol)
    return sf, sd


def select_poles(
    diagram: StabilizationDiagram,
    *,
    n_modes: int | None = None,
    cluster_tol: float = 0.005,
    min_share: float = 0.3,
    max_damping: float = 0.2,
) -> tuple[np.ndarray, np.ndarray]:
    """Physical modes from the stabilization diagram: clusters of stable poles.

    Stable poles inside the band are grouped by frequency (a new cluster where
    consecutive sorted frequencies differ by more than ``cluster_tol``,
    relative). Poles stable in frequency with a damping ratio in (0,
    ``max_damping``) are clustered; a cluster is a mode when it holds such poles
    in at least ``min_share`` of the orders of its sub-band, and poles stable in
    damping as well in a third of that; with ``n_modes`` the ``n_modes`` clusters
    holding the most orders are taken instead. Each mode's estimate is the
    median frequency and damping of its cluster's poles at the highest orders
    (the upper half of the orders it appears in).

    Returns
    -------
    freq_hz, damping : (n_modes,) arrays, ascending frequency
    """
    lo, hi = diagram.band_hz
    z = diagram.damping
    ok = diagram.stable_freq & (z > 0) & (z < max_damping)
    ok &= (diagram.freq_hz >= lo) & (diagram.freq_hz <= hi)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        raise InputError(
            "modal fit: the stabilization diagram has no stable pole in the band; "
            "expected resonances in the FRF (raise max_order or check the data)"
        )
    idx = idx[np.argsort(diagram.freq_hz[idx])]
    fr = diagram.freq_hz[idx]
    breaks = np.flatnonzero(np.diff(fr) / fr[1:] > cluster_tol) + 1
    clusters = np.split(idx, breaks)
    counts = np.array([np.unique(diagram.order[c]).size for c in clusters])
    full = np.array([np.unique(diagram.order[c[diagram.stable[c]]]).size for c in clusters])
    n_orders = np.array([diagram.order_max[c].max() for c in clusters])
    if n_modes is None:
        # stable in frequency in min_share of the orders, and in damping too in a third
        # of that: a lightly damped mode at the band's low end scatters in damping by more
        # than the tolerance between orders at 1 % noise (beam, 3.24 Hz: stable in
        # frequency in 10 of 13 orders, in both in 3)
        keep = np.flatnonzero((counts >= min_share * n_orders) & (full >= min_share / 3 * n_orders))
    else:
        # a cluster is a candidate when its pole recurs at two orders at least
        cand = np.flatnonzero(counts >= 2)
        if n_modes > cand.size:
            raise InputError(
                f"modes: expected at most {cand.size} (the stable clusters of the "
                f"stabilization diagram), got {n_modes}"
            )
        keep = np.sort(cand[np.argsort(-counts[cand], kind="stable")[:n_modes]])
    freq, damp = [], []
    for k in keep:
        c = clusters[k]
        top = c[diagram.order[c] >= np.median(diagram.order[c])]
        freq.append(float(np.median(diagram.freq_hz[top])))
        damp.append(float(np.median(diagram.damping[top])))
    order = np.argsort(freq)
    return np.asarray(freq)[order], np.asarray(damp)[order]


# ------------------------------------------------------- nonlinear fit
#: the upper-residual pseudo-mode starts at this factor times the highest fitted line
UPPER_FACTOR = 1.5
#: and with this damping ratio
UPPER_DAMPING = 0.02


def _solve_rows(X: np.ndarray, problem: FrfProblem) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares per output row for real coefficients of a shared basis.

    Row ``i`` minimizes ``sum_{f,j} w_fij^2 |G_fij - sum_p X_fjp x_ip|^2``.

    Parameters
    ----------
    X : (n_f, n_u, n_p) complex array
        Basis: the response of coefficient p at input j.

    Returns
    -------
    x, x_std : (n_y, n_p) arrays; ``x_std`` for unit noise (scaled by the engine).
    """
    x, std, _, _ = _project_rows(X, problem)
    return x, std


def _project_rows(X: np.ndarray, problem: FrfProblem) -> tuple[np.ndarray, ...]:
    """:func:`_solve_rows`, the normal matrices ``A_i`` and their inverses (n_y, n_p, n_p)."""
    n_f, n_u, n_p = X.shape
    G, w2 = problem.data.G, problem.w2
    n_y = G.shape[1]
    Xf = X.reshape(n_f * n_u, n_p)
    # A_i = sum_{f,j} w2_fij Re(conj(X_fjp) X_fjq) = Re(Xw_i^H Xw_i), Xw_i = sqrt(w2_i) X: one
    # (n_p x n_f n_u) GEMM per row (forming every X_p conj(X_q) product first cost ~100x more)
    W = np.sqrt(w2.transpose(1, 0, 2).reshape(n_y, n_f * n_u))
    A = np.empty((n_y, n_p, n_p))
    Xs = np.concatenate([Xf.real, Xf.imag])  # Re(Xw^H Xw) = Xr^T Xr + Xi^T Xi, one real GEMM
    for i in range(n_y):
        Xw = Xs * np.tile(W[i], 2)[:, None]
        A[i] = Xw.T @ Xw
    WG = (w2 * G).transpose(0, 2, 1).reshape(n_f * n_u, n_y)
    rhs = (Xf.conj().T @ WG).real.T  # (n_y, n_p)
    x = np.zeros((n_y, n_p))
    std = np.zeros_like(x)
    A_inv = np.empty_like(A)
    for i in range(n_y):
        scale = np.sqrt(np.diag(A[i]))
        scale = np.where(scale > 0, scale, 1.0)
        cov = np.linalg.inv(A[i] / np.outer(scale, scale) + 1e-13 * np.eye(n_p))
        x[i] = cov @ (rhs[i] / scale) / scale
        std[i] = np.sqrt(np.abs(np.diag(cov))) / scale
        A_inv[i] = cov / np.outer(scale, scale)
    return x, std, A, A_inv


def _denominators(s: np.ndarray, freq_hz: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """``s^2 + 2 z w s + w^2`` per line and mode, (n_f, n_m)."""
    w = 2 * np.pi * np.asarray(freq_hz)
    return s[:, None] ** 2 + 2 * np.asarray(damping) * w * s[:, None] + w**2


def _extra_basis(
    s: np.ndarray, n_u: int, rigid: bool, upper_hz: float | None, upper_damping: float = 0.0
) -> np.ndarray:
    """Basis of D, then L / s^2 (rigid), then E / den_up(s) (upper): (n_f, n_u, k n_u)."""
    eye = np.broadcast_to(np.eye(n_u), (s.size, n_u, n_u)).astype(complex)
    parts = [eye]
    if rigid:
        parts.append(eye / (s**2)[:, None, None])
    if upper_hz is not None:
        den = _denominators(s, [upper_hz], [upper_damping])[:, 0]
        parts.append(eye / den[:, None, None])
    return np.concatenate(parts, axis=2)


def _full_residues(problem: FrfProblem, freq_hz, damping, rigid, upper_hz, upper_z) -> np.ndarray:
    """Unconstrained real residues R_k (n_m, n_y, n_u) at fixed poles (the rank-one start)."""
    n_u, n_m = problem.data.n_u, len(freq_hz)
    inv = 1.0 / _denominators(problem.s, freq_hz, damping)  # (n_f, n_m)
    eye = np.eye(n_u)
    modal = (inv[:, None, :, None] * eye[None, :, None, :]).reshape(-1, n_u, n_m * n_u)
    extra = _extra_basis(problem.s, n_u, rigid, upper_hz, upper_z)
    x, _ = _solve_rows(np.concatenate([modal, extra], 2), problem)
    return x[:, : n_m * n_u].reshape(problem.data.n_y, n_m, n_u).transpose(1, 0, 2)


@dataclass(frozen=True)
class ModalStructure:
    """The modal model as a :class:`workbench.diagnosis.fit.Structure` (variable projection).

    ``theta`` = (freq_hz (n_m), ln damping (n_m), the free entries of every b_k,
    mode by mode: b_k has 1 at ``pivot[k]``). For given theta the output vectors
    c_k, the residual compliance D and the rigid term L are solved in closed form.

    Attributes
    ----------
    theta0 : (n_theta,) array
        Start point.
    pivot : (n_m,) int array
        Input whose entry of b_k is fixed to 1.
    n_u, n_y : int
    rigid : bool
        Include the lower residual / rigid term ``L / s^2``.
    upper_hz : float or None
        Include the upper residual ``E / (s^2 + 2 z_up w_up s + w_up^2)``, a
        pseudo-mode above the band with a full residue E; its frequency
        ``w_up / 2 pi`` (Hz) and ``ln z_up`` are the last two entries of theta,
        started at ``upper_hz`` and 0.02, the frequency kept within ``[1.02, 5] x``
        the top line.
    input_names, output_names : tuple of str
    """

    theta0: np.ndarray
    pivot: np.ndarray
    n_u: int
    n_y: int
    rigid: bool = False
    upper_hz: float | None = None
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    effect: str = "modal_fit"
    theta_names: tuple[str, ...] = field(default=())
    # the last projection (theta, problem) -> basis and linear solution: the engine asks for the
    # residual and then the normal equations at the same theta, one projection serves both
    _memo: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def n_modes(self) -> int:
        return int(np.asarray(self.pivot).size)

    def unpack(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(freq_hz (n_m,), damping (n_m,), B (n_m, n_u)) from theta."""
        m, n_u = self.n_modes, self.n_u
        theta = np.asarray(theta, float)
        B = np.ones((m, n_u))
        free = ~np.eye(n_u, dtype=bool)[np.asarray(self.pivot)]
        B[free] = theta[2 * m : 2 * m + m * (n_u - 1)]
        return theta[:m], np.exp(theta[m : 2 * m]), B

    def upper_at(self, theta: np.ndarray) -> tuple[float | None, float]:
        """The upper pseudo-mode's frequency, Hz (None without one), and damping ratio."""
        if self.upper_hz is None:
            return None, 0.0
        return float(theta[-2]), float(np.exp(theta[-1]))

    def grid(self, problem, base):
        return [np.asarray(self.theta0, float)]

    def bounds(self, problem, base):
        m = self.n_modes
        f0 = np.asarray(self.theta0[:m])
        nb = m * (self.n_u - 1)
        lo = np.concatenate([0.8 * f0, np.full(m, np.log(1e-6)), np.full(nb, -50.0)])
        hi = np.concatenate([1.25 * f0, np.full(m, np.log(0.9)), np.full(nb, 50.0)])
        if self.upper_hz is not None:
            top = float(problem.freq[-1])
            lo = np.append(lo, [1.02 * top, np.log(1e-4)])
            hi = np.append(hi, [5.0 * top, np.log(0.5)])
        return lo, hi

    def n_linear(self, base) -> int:
        return self.n_y * (self.n_modes + self.n_u * (1 + self.rigid + (self.upper_hz is not None)))

    def _projection(self, theta, problem) -> tuple[np.ndarray, ...]:
        """Basis ``X`` (n_f, n_u, n_p) at theta and :func:`_project_rows` on it (memoized)."""
        theta = np.asarray(theta, float)
        memo = self._memo
        if memo.get("problem") is problem and np.array_equal(memo.get("theta"), theta):
            return memo["value"]
        freq, damp, B = self.unpack(theta)
        inv = 1.0 / _denominators(problem.s, freq, damp)  # (n_f, m)
        upper_hz, upper_z = self.upper_at(theta)
        X = np.concatenate(
            [
                inv[:, None, :] * B.T[None],
                _extra_basis(problem.s, self.n_u, self.rigid, upper_hz, upper_z),
            ],
            2,
        )
        value = (X, *_project_rows(X, problem))
        memo.update(problem=problem, theta=theta.copy(), value=value)
        return value

    def build(self, theta, problem, base) -> Realized:
        freq, damp, B = self.unpack(theta)
        m, n_u = self.n_modes, self.n_u
        upper_hz, upper_z = self.upper_at(theta)
        _, x, x_std, _, _ = self._projection(theta, problem)
        C = x[:, :m].T  # (m, n_y)
        linear = {"c": C, "D": x[:, m : m + n_u]}
        std = {"c": x_std[:, :m].T, "D": x_std[:, m : m + n_u]}
        at = m + n_u
        for key, on in (("L", self.rigid), ("E", self.upper_hz is not None)):
            if on:
                linear[key], std[key] = x[:, at : at + n_u], x_std[:, at : at + n_u]
                at += n_u
        modes = []
        if self.rigid:
            modes.append(Mode("rigid", 0.0, 0.0, np.zeros(n_u), np.zeros(self.n_y), N0=linear["L"]))
        modes += [Mode("flexible", freq[k], damp[k], B[k], C[k]) for k in range(m)]
        if upper_hz is not None:
            # the pseudo-mode: flexible, its full residue as the exact numerator
            modes.append(
                Mode(
                    "flexible",
                    upper_hz,
                    upper_z,
                    np.zeros(n_u),
                    np.zeros(self.n_y),
                    N0=linear["E"],
                    effect="upper_residual",
                )
            )
        model = ModalModel(
            modes=tuple(modes),
            D=linear["D"],
            input_names=self.input_names,
            output_names=self.output_names,
        )
        return Realized(model, linear, std)

    def jacobian(self, theta, problem, base) -> np.ndarray:
        """Jacobian of ``problem.residual(self.build(theta).model)`` w.r.t. theta, (n_obs, n_theta).

        The exact variable-projection derivative (Golub & Pereyra 1973): the linear
        coefficients ``x_i`` of every output row move with theta as the weighted least
        squares solution does. Rows are ordered as :meth:`FrfProblem.residual` stacks
        them: (line, output, input, real / imaginary).

        Notes
        -----
        Per output row ``i``, with the weighted basis ``Phi = w X`` (stacked real),
        ``A = Phi^T Phi``, the residual ``r = w G - Phi x`` and ``x = A^-1 Phi^T w G``::

            dx/dt = A^-1 (dPhi^T r - Phi^T dPhi x)
            dr/dt = -(dPhi x + Phi dx/dt)

        (``-P_perp dPhi x`` is Kaufman's part; the other, ``-Phi A^-1 dPhi^T r``,
        vanishes for a zero residual). ``dPhi/dt`` is sparse: a mode's frequency and
        ``ln`` damping move its column of the basis, ``d(1/den)/df = -(2 pi)(2 z s +
        2 w)/den^2``, ``d(1/den)/d ln z = -2 z w s / den^2``; an entry ``b_kj`` scales
        mode k's column at input j; the upper pseudo-mode's two parameters move the
        ``E`` columns.
        """
        n_f, n_y, n_u, n_t = problem.freq.size, self.n_y, self.n_u, np.size(theta)
        out = np.empty((n_f, n_y, n_u, 2, n_t))
        for i, V, P, _, _, dx in self._rows(theta, problem):
            # dr/dt = -(dPhi x + Phi dx/dt), rows (line, output, input, re / im)
            for part in (0, 1):
                np.subtract(
                    (P[part] @ -dx).reshape(n_f, n_u, n_t),
                    V[part].reshape(n_f, n_u, n_t),
                    out=out[:, i, :, part],
                )
        return out.reshape(-1, n_t)

    def normal_equations(self, theta, problem, base, r) -> tuple[np.ndarray, np.ndarray]:
        """``(J^T J, J^T r)`` of :meth:`jacobian` without forming ``J`` (n_obs x n_t).

        With row ``i``'s ``J_i = -(V + P dx)`` and ``P^T V = T``, ``P^T P = A_i``::

            J_i^T J_i = V^T V + T^T dx + dx^T T + dx^T A_i dx
            J_i^T r_i = -(V^T r_i + dx^T P^T r_i)

        (``P^T r_i`` vanishes at the projected solution; kept for the rounding). The
        beam's modal fit (59 940 x 38) saves the 18 MB Jacobian and its Gram product
        every iteration.

        Parameters
        ----------
        r : (n_obs,) array
            The residual at ``theta`` (:meth:`FrfProblem.residual` order).
        """
        n_f, n_y, n_u, n_t = problem.freq.size, self.n_y, self.n_u, np.size(theta)
        r4 = np.asarray(r, float).reshape(n_f, n_y, n_u, 2)
        H = np.zeros((n_t, n_t))
        g = np.zeros(n_t)
        for i, V, P, T, A_i, dx in self._rows(theta, problem):
            TdX = T.T @ dx
            H += TdX + TdX.T + dx.T @ (A_i @ dx)
            for part in (0, 1):
                r_ip = r4[:, i, :, part].reshape(-1)
                H += V[part].T @ V[part]
                g -= V[part].T @ r_ip + dx.T @ (P[part].T @ r_ip)
        return H, g

    def _rows(self, theta, problem):
        """The Jacobian's parts, one output row at a time (see :meth:`jacobian`).

        Yields ``(i, (V_re, V_im), (P_re, P_im), T, A_i, dx)``: the weighted model derivative at
        fixed linear coefficients ``V`` (n_f n_u, n_t), the weighted basis ``P`` (n_f n_u,
        n_p), ``T = P^T V`` summed over both parts, the normal matrix ``A_i`` and
        ``dx/dtheta`` (n_p, n_t); row ``i``'s Jacobian is ``-(V + P dx)``. ``V`` lives in a
        buffer reused for the next row.
        """
        theta = np.asarray(theta, float)
        freq, damp, B = self.unpack(theta)
        m, n_u, n_y, n_t = self.n_modes, self.n_u, self.n_y, theta.size
        s = problem.s[:, None]
        n_f = s.shape[0]
        inv = 1.0 / _denominators(problem.s, freq, damp)  # (n_f, m)
        omega = 2 * np.pi * freq
        d_freq = -(inv * inv) * (2 * np.pi) * (2 * damp * s + 2 * omega)
        d_lnz = -(inv * inv) * (2 * damp * omega) * s
        upper_hz, upper_z = self.upper_at(theta)
        X, x, _, A, A_inv = self._projection(theta, problem)  # X: (n_f, n_u, n_p)
        C = x[:, :m]  # (n_y, m): c_k as columns
        kf, jf = np.nonzero(~np.eye(n_u, dtype=bool)[np.asarray(self.pivot)])  # b[free] order
        tb = 2 * m + np.arange(kf.size)
        w = problem.w.transpose(1, 0, 2)  # (n_y, n_f, n_u)
        pred = np.einsum("fjp,ip->ifj", X, x)
        rw = w * w * (problem.data.G.transpose(1, 0, 2) - pred)  # w^2 (G - X x)
        # dPhi^T r, (n_y, n_p, n_t): nonzero only in the columns each parameter moves
        Q = np.zeros((n_y, X.shape[2], n_t))
        ar = np.arange(m)
        rwB = rw @ B.T  # (n_y, n_f, m)
        Q[:, ar, ar] = np.sum(d_freq.conj() * rwB, axis=1).real
        Q[:, ar, m + ar] = np.sum(d_lnz.conj() * rwB, axis=1).real
        Q[:, kf, tb] = (rw.transpose(0, 2, 1) @ inv.conj())[:, jf, kf].real  # (n_y, n_u, m)
        d_up = ()
        if upper_hz is not None:
            col = m + n_u * (1 + int(self.rigid)) + np.arange(n_u)
            inv_up = 1.0 / _denominators(problem.s, [upper_hz], [upper_z])[:, 0]
            w_up = 2 * np.pi * upper_hz
            s1 = problem.s
            d_up = (
                -(inv_up * inv_up) * (2 * np.pi) * (2 * upper_z * s1 + 2 * w_up),
                -(inv_up * inv_up) * (2 * upper_z * w_up) * s1,
            )
            for t, d in zip((n_t - 2, n_t - 1), d_up):
                Q[:, col, t] = np.einsum("f,ifj->ij", d.conj(), rw).real
        d_re = [np.ascontiguousarray(d.real) for d in (d_freq, d_lnz, inv, *d_up)]
        d_im = [np.ascontiguousarray(d.imag) for d in (d_freq, d_lnz, inv, *d_up)]
        n_p = X.shape[2]
        # V_i = w dX/dt x_i, output row i's derivative of the model at fixed x, real and
        # imaginary parts apart, (n_f, n_u, n_t) in the order of the Jacobian's rows (no
        # transposed copy at the end); built one row at a time in two reused buffers (the
        # whole (n_y, ...) array is 9 MB per part, slower to touch than to recompute)
        V = np.zeros((2, n_f, n_u, n_t))
        for i in range(n_y):
            wCB = w[i][..., None] * (C[i] * B.T)[None]  # (n_f, n_u, m)
            for part, dd in ((0, d_re), (1, d_im)):
                Vp = V[part]
                np.multiply(wCB, dd[0][:, None, :], out=Vp[..., :m])
                np.multiply(wCB, dd[1][:, None, :], out=Vp[..., m : 2 * m])
                for t, k, j in zip(tb, kf, jf):
                    np.multiply(w[i][:, j] * C[i, k], dd[2][:, k], out=Vp[:, j, t])
                if upper_hz is not None:
                    wE = w[i] * x[i, col]  # (n_f, n_u): w_fij E_ij
                    np.multiply(wE, dd[3][:, None], out=Vp[..., n_t - 2])
                    np.multiply(wE, dd[4][:, None], out=Vp[..., n_t - 1])
            Xw = w[i][:, :, None] * X
            Pr = np.ascontiguousarray(Xw.real).reshape(n_f * n_u, n_p)
            Pi = np.ascontiguousarray(Xw.imag).reshape(n_f * n_u, n_p)
            Vr_i = V[0].reshape(n_f * n_u, n_t)
            Vi_i = V[1].reshape(n_f * n_u, n_t)
            T = Pr.T @ Vr_i + Pi.T @ Vi_i  # Phi^T dPhi x, (n_p, n_t)
            dx = A_inv[i] @ (Q[i] - T)
            yield i, (Vr_i, Vi_i), (Pr, Pi), T, A[i], dx

    def report(self, fit_result, problem, base):
        freq, damp, _ = self.unpack(fit_result.theta)
        return {"freq_hz": freq.tolist(), "damping": damp.tolist()}, {}


@dataclass(frozen=True)
class ModalFit:
    """Result of :func:`fit_modal`.

    Attributes
    ----------
    model : ModalModel
        Continuous modal model: the flexible modes (rank-one residues
        ``c_k b_k^T``, ``b_k`` = 1 at its largest entry), D the residual
        compliance (m/N), a rigid mode with numerator L when fitted.
    freq_hz, freq_std_hz : (n_m,) arrays, Hz
    damping, damping_std : (n_m,) arrays
    b : (n_m, n_u) array; c, c_std : (n_m, n_y) arrays (units of G over b)
    D : (n_y, n_u) array, m/N; L : (n_y, n_u) array or None, m/(N s^2)
    E : (n_y, n_u) array or None, m/(N s^2); upper_hz : float or None
        Upper residual ``E / (s^2 + (2 pi upper_hz)^2)``.
    diagram : StabilizationDiagram
    initial_freq_hz, initial_damping : (n_m,) arrays
        The selected poles of the diagram (start of the fit).
    result : FitResult
        The engine's result (cost, sigma2, theta +- std, status).
    """

    model: ModalModel
    freq_hz: np.ndarray
    freq_std_hz: np.ndarray
    damping: np.ndarray
    damping_std: np.ndarray
    b: np.ndarray
    c: np.ndarray
    c_std: np.ndarray
    D: np.ndarray
    L: np.ndarray | None
    E: np.ndarray | None
    upper_hz: float | None
    diagram: StabilizationDiagram
    initial_freq_hz: np.ndarray
    initial_damping: np.ndarray
    result: FitResult

    def __post_init__(self):
        for key in ("freq_hz", "freq_std_hz", "damping", "damping_std", "b", "c", "c_std", "D"):
            object.__setattr__(self, key, readonly(getattr(self, key), float))
        for key in ("L", "E"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, readonly(getattr(self, key), float))

    @property
    def n_modes(self) -> int:
        return self.freq_hz.size

    @property
    def error(self) -> float:
        """Mean over lines of ||G - G_model||_F / ||G||_F (spec 3)."""
        return self.result.error

    @property
    def status(self) -> str:
        return self.result.status

    def table(self) -> list[dict]:
        """The mode table: one dict per mode (JSON-ready)."""
        return [
            {
                "mode": k + 1,
                "freq_hz": float(self.freq_hz[k]),
                "freq_std_hz": float(self.freq_std_hz[k]),
                "damping": float(self.damping[k]),
                "damping_std": float(self.damping_std[k]),
                "b": self.b[k].tolist(),
                "c": self.c[k].tolist(),
            }
            for k in range(self.n_modes)
        ]

    def table_text(self) -> str:
        lines = [" mode   freq (Hz)    +- std     damping    +- std      |b_k|      |c_k|"]
        for k in range(self.n_modes):
            lines.append(
                f"{k + 1:5d} {self.freq_hz[k]:11.4f} {self.freq_std_hz[k]:9.2e} "
                f"{self.damping[k]:10.5f} {self.damping_std[k]:9.2e} "
                f"{np.linalg.norm(self.b[k]):10.3e} {np.linalg.norm(self.c[k]):10.3e}"
            )
        return "\n".join(lines)

    def summary(self) -> dict:
        """Mode table, fit figures and names (JSON-ready)."""
        return {
            "modes": self.table(),
            "n_modes": self.n_modes,
            "error": float(self.error),
            "sigma2": float(self.result.sigma2),
            "status": self.status,
            "rigid": self.L is not None,
            "D": self.D.tolist(),
            "input_names": list(self.model.input_names),
            "output_names": list(self.model.output_names),
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """The modal data stored beside A, B, C, D in the spec-2 model file (``modal_*`` keys)."""
        out = {
            "modal_freq_hz": np.asarray(self.freq_hz),
            "modal_freq_std_hz": np.asarray(self.freq_std_hz),
            "modal_damping": np.asarray(self.damping),
            "modal_damping_std": np.asarray(self.damping_std),
            "modal_b": np.asarray(self.b),
            "modal_c": np.asarray(self.c),
            "modal_c_std": np.asarray(self.c_std),
            "modal_D": np.asarray(self.D),
        }
        if self.L is not None:
            out["modal_L"] = np.asarray(self.L)
        if self.E is not None:
            out["modal_E"] = np.asarray(self.E)
            out["modal_upper_hz"] = np.asarray(self.upper_hz)
        return out


def band_data(data: FrfData, band_hz: tuple[float, float] | None) -> FrfData:
    """The lines of ``data`` inside ``band_hz`` (Hz, inclusive); all lines for None."""
    if band_hz is None:
        return data
    f1, f2 = (float(v) for v in band_hz)
    if not (np.isfinite(f1) and np.isfinite(f2) and 0 <= f1 < f2):
        raise InputError(f"band: expected 0 <= F1 < F2 Hz, got {f1:g} {f2:g}")
    sel = (data.freq >= f1) & (data.freq <= f2)
    if np.sum(sel) < 8:
        raise InputError(
            f"band: expected at least 8 lines in {f1:g}..{f2:g} Hz, got {int(np.sum(sel))} "
            f"(data: {data.freq[0]:g}..{data.freq[-1]:g} Hz)"
        )
    return FrfData(
        freq=data.freq[sel],
        G=data.G[sel],
        G_var=None if data.G_var is None else data.G_var[sel],
        fs=data.fs,
        input_names=data.input_names,
        output_names=data.output_names,
    )


def fit_modal(
    data: FrfData,
    *,
    n_modes: int | None = None,
    band_hz: tuple[float, float] | None = None,
    max_order: int = 30,
    rigid: bool | None = None,
    upper: bool = True,
    max_nfev: int = 100,
    blas_threads: int | None = 1,
) -> ModalFit:
    """Modal parameters of a MIMO FRF: p-LSCF start, then a weighted rank-one LM fit.

    Parameters
    ----------
    data : FrfData
        FRF (n_f, n_y, n_u), m/N or any consistent unit; ``G_var`` (its
        variance) weights every element by ``1 / sqrt(G_var)``; without it every
        line is weighted by ``1 / ||G(f)||_F``.
    n_modes : int, optional
        Number of modes to fit (the most stable clusters of the diagram);
        default: every cluster stable in 30 % of its orders.
    band_hz : (F1, F2), optional
        Fit only the lines in this band, Hz.
    max_order : int
        Highest p-LSCF order of the stabilization diagram.
    rigid : bool, optional
        Add a rigid / lower residual term ``L / s^2`` (rigid-body modes, modes
        below the band). Default: only when ``band_hz`` leaves out lines of the
        data below the band (the modes there act as ``L / s^2`` in it).
    upper : bool
        Add the upper residual ``E / (s^2 + w_up^2)``, ``f_up`` fitted, started at
        ``UPPER_FACTOR`` times the top line: the modes above the band are not
        constant there
        (beam: its 1239 Hz mode is 2.9x its static value at 1000 Hz; with D
        alone the 9th mode's damping came out 0.5 % and its frequency 0.013 %
        off at 1 % noise, several standard deviations).
    max_nfev : int
        Residual evaluations of the Levenberg-Marquardt (trust-region) search.
    blas_threads : int or None
        BLAS threads for the fit's duration (:func:`workbench.core.blas.limited_blas`):
        its products are small (beam, 3 x 3 x 2000 lines: 7 ms CPU per residual on one
        thread, 111 ms on two of a busy 2-core machine); None keeps the caller's.

    Returns
    -------
    ModalFit
    """
    from workbench.core.blas import limited_blas

    with limited_blas(blas_threads):
        return _fit_modal(data, n_modes, band_hz, max_order, rigid, upper, max_nfev)


def _fit_modal(data, n_modes, band_hz, max_order, rigid, upper, max_nfev) -> ModalFit:
    if not isinstance(data, FrfData):
        raise InputError(
            f"modal fit: expected an FRF measurement (spec 1b), got {type(data).__name__}"
        )
    if n_modes is not None and not (isinstance(n_modes, int | np.integer) and n_modes >= 1):
        raise InputError(f"modes: expected an integer >= 1, got {n_modes!r}")
    if rigid is None:
        rigid = band_hz is not None and float(band_hz[0]) > float(data.freq[0])
    data = band_data(data, band_hz)
    diagram = lscf(data, max_order=max_order)
    f0, z0 = select_poles(diagram, n_modes=n_modes)
    z0 = np.clip(z0, 1e-5, 0.5)
    problem = FrfProblem(data)
    upper_hz = UPPER_FACTOR * float(data.freq[-1]) if upper else None
    R = _full_residues(problem, f0, z0, rigid, upper_hz, UPPER_DAMPING)
    b0 = np.zeros((f0.size, data.n_u))
    for k in range(f0.size):
        _, sv, Vt = np.linalg.svd(R[k])
        b0[k] = Vt[0]
    pivot = np.argmax(np.abs(b0), axis=1)
    b0 = b0 / b0[np.arange(f0.size), pivot][:, None]
    free = ~np.eye(data.n_u, dtype=bool)[pivot]
    tail = [[upper_hz, np.log(UPPER_DAMPING)]] if upper else []
    theta0 = np.concatenate([f0, np.log(z0), b0[free]] + tail)
    names = [f"freq_hz_{k + 1}" for k in range(f0.size)]
    names += [f"ln_damping_{k + 1}" for k in range(f0.size)]
    names += [f"b_{k + 1}_{j + 1}" for k in range(f0.size) for j in range(data.n_u) if free[k, j]]
    names += ["upper_hz", "ln_upper_damping"] if upper else []
    structure = ModalStructure(
        theta0=theta0,
        pivot=pivot,
        n_u=data.n_u,
        n_y=data.n_y,
        rigid=rigid,
        upper_hz=upper_hz,
        input_names=data.input_names,
        output_names=data.output_names,
        theta_names=tuple(names),
    )
    base = ModalModel(modes=(), D=np.zeros((data.n_y, data.n_u)))
    res = fit(structure, problem, base, starts=[theta0], n_starts=1, max_nfev=max_nfev)
    structure._memo.clear()  # the result keeps the structure, not the fit's working arrays
    freq, damp, B = structure.unpack(res.theta)
    m = f0.size
    order = np.argsort(freq)
    lin, lin_std = res.realized.linear, res.realized.linear_std
    return ModalFit(
        model=res.model,
        freq_hz=freq[order],
        freq_std_hz=res.theta_std[:m][order],
        damping=damp[order],
        damping_std=(damp * res.theta_std[m : 2 * m])[order],
        b=B[order],
        c=lin["c"][order],
        c_std=lin_std["c"][order],
        D=lin["D"],
        L=lin.get("L"),
        E=lin.get("E"),
        upper_hz=structure.upper_at(res.theta)[0],
        diagram=diagram,
        initial_freq_hz=f0,
        initial_damping=z0,
        result=res,
    )


# --------------------------------------------------------------- plots
def plot_stabilization(result: ModalFit, path: str | os.PathLike) -> None:
    """Stabilization diagram (PNG): poles by order over the FRF sum, the selected modes marked."""
    from workbench.plotting import new_figure, save_png

    dg = result.diagram
    fig = new_figure(8, 4.5)
    ax = fig.subplots()
    ax2 = ax.twinx()
    f = result.model.core_frf(np.geomspace(dg.band_hz[0], dg.band_hz[1], 2000))
    ax2.semilogy(np.geomspace(dg.band_hz[0], dg.band_hz[1], 2000), np.sum(np.abs(f), (1, 2)), "0.6")
    ax2.set_ylabel("sum |G| of the fitted model", fontsize=8)
    marks = (
        (~dg.stable_freq, "x", "0.5", "new"),
        (dg.stable_freq & ~dg.stable_damping, "o", "b", "stable f"),
        (dg.stable, "s", "r", "stable f, damping"),
    )
    for sel, marker, color, label in marks:
        ax.plot(dg.freq_hz[sel], dg.order[sel], marker, color=color, ms=3, mfc="none", label=label)
    for fk in result.freq_hz:
        ax.axvline(fk, color="g", lw=0.6)
    ax.set_xscale("log")
    ax.set_xlim(*dg.band_hz)
    ax.set_xlabel("frequency, Hz")
    ax.set_ylabel("model order")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(f"p-LSCF stabilization diagram, {result.n_modes} modes selected (green)")
    save_png(fig, path)


def plot_fit_overlay(result: ModalFit, data: FrfData, path: str | os.PathLike) -> None:
    """Measured vs fitted FRF per element with the +-2 sigma band (PNG)."""
    from workbench.plotting import save_bode_overlay

    lo, hi = result.diagram.band_hz
    sel = (data.freq >= lo) & (data.freq <= hi)
    save_bode_overlay(
        path,
        data.freq[sel],
        data.G[sel],
        result.model.frf(data.freq[sel]),
        None if data.G_var is None else data.G_var[sel],
        input_names=data.input_names,
        output_names=data.output_names,
    )
