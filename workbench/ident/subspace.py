"""Subspace identification, open loop and closed loop (orthogonal projection).

One entry point, :func:`identify_subspace`, for five methods:

============  ===============================================================
``cl-n4sid``  project u, y onto the row space of [R_p; R_f], then N4SID
``cl-moesp``  ... then MOESP (PO-MOESP weighting)
``cl-cva``    ... then CVA
``n4sid``     open-loop N4SID on (u, y); biased on closed-loop data
``moesp``     open-loop MOESP on (u, y); biased on closed-loop data
============  ===============================================================

Every method reduces the data to a small factor ``L`` (rows x c) with
``L L^T`` the Gram of the (projected) block-Hankel data, so all later steps
cost nothing in ``N``; see :mod:`workbench.ident.gram`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg

from workbench.core.arrays import readonly
from workbench.core.errors import DataWarning, InputError
from workbench.ident.gram import hankel, hankel_gram
from workbench.ident.order import suggest_order
from workbench.io.formats import TimeData

__all__ = ["SubspaceResult", "identify_subspace", "METHODS"]

Method = Literal["cl-n4sid", "cl-moesp", "cl-cva", "n4sid", "moesp"]
METHODS: tuple[str, ...] = ("cl-n4sid", "cl-moesp", "cl-cva", "n4sid", "moesp")


@dataclass(frozen=True)
class SubspaceResult:
    """An identified discrete-time model and what the order choice rests on.

    Attributes
    ----------
    model : control.StateSpace
        Discrete model, ``dt = 1 / fs``; input N (``u``), output m (``y``).
        With ``input_delay > 0`` it maps ``u[k - input_delay]`` to ``y[k]``:
        the rational part only; :attr:`lti_model` carries the delay.
    singular_values : (n_sv,) array
        Singular values of the weighted projection, largest first (scaled
        data, so dimensionless).
    order : int
        Order of ``model``.
    suggested_order : int
        Order at the largest gap of ``singular_values`` (see
        :func:`~workbench.ident.order.suggest_order`).
    gap : float
        ``s[suggested_order - 1] / s[suggested_order]``, the ratio it rests on.
    method : str
        One of :data:`METHODS`.
    block_rows : int
        ``i``, block rows of the past and of the future.
    input_delay : int
        Input delay in samples removed from the data before identification.
    fs : float
        Sampling frequency, Hz.
    notes : tuple of str
    bd_method : str
        How B and D were estimated: least squares on the simulated output
        (open-loop methods) or from the projected data (closed-loop methods,
        where the output-error least squares is biased by the feedback).
    x0 : (n,) array or None
        Initial state of the identification record (least-squares route only).
    """

    model: object
    singular_values: np.ndarray
    order: int
    suggested_order: int
    gap: float
    method: str
    block_rows: int
    input_delay: int = 0
    fs: float = 1.0
    notes: tuple[str, ...] = field(default=())
    bd_method: str = ""
    x0: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "singular_values", readonly(self.singular_values, float))
        if self.x0 is not None:
            object.__setattr__(self, "x0", readonly(self.x0, float))

    @property
    def delay_s(self) -> float:
        """Input delay removed before identification, s."""
        return self.input_delay / self.fs

    @property
    def lti_model(self):
        """The identified model with its delay: a :class:`~workbench.core.model.LTIModel`.

        ``model`` is the rational part (a ``StateSpace`` cannot hold the delay);
        this one carries ``delay_s = input_delay / fs`` exactly, so its FRF,
        simulation and model file include the delay. Pass this one on.
        """
        from workbench.core.model import LTIModel

        return LTIModel.from_statespace(self.model, delay_s=self.delay_s)


def identify_subspace(
    data: TimeData,
    *,
    method: Method = "cl-moesp",
    order: int | None = None,
    block_rows: int = 20,
    input_delay: int = 0,
    feedthrough: bool = True,
    max_order: int | None = None,
    factorization: Literal["gram", "qr"] = "gram",
    projection: Literal["auto", "lags", "periodic"] = "auto",
    chunk: int = 4096,
    bd: Literal["auto", "least-squares", "projection"] = "auto",
    orders=None,
) -> SubspaceResult:
    """Identify a discrete state-space model from a time record.

    Parameters
    ----------
    data : TimeData
        ``u`` (N, n_u) plant input, N; ``y`` (N, n_y) output, m; ``r``
        (N, n_u) exogenous excitation at the plant input (required by the
        ``cl-*`` methods); ``fs`` Hz.
    method : {"cl-n4sid", "cl-moesp", "cl-cva", "n4sid", "moesp"}
        Closed-loop (projection onto r) or plain open-loop method.
    order : int, optional
        Model order; default the suggested order.
    block_rows : int
        ``i``: block rows of the past and of the future Hankel matrices.
        Must satisfy ``i * n_y > order``.
    input_delay : int
        Known input delay in samples: ``y[k]`` is paired with
        ``u[k - input_delay]`` (and ``r``), so the model needs no delay
        states. The result keeps it (``delay_s``).
    feedthrough : bool
        Estimate ``D``; if False, ``D = 0`` (strictly proper plant).
    max_order : int, optional
        Largest order considered by the suggestion; default ``i * n_y // 2``.
    factorization : {"gram", "qr"}
        ``"gram"``: the structured Gram of the block-Hankel matrix from
        correlation sums, ``O(N * rows)`` work, memory independent of N.
        ``"qr"``: QR of the explicit Hankel matrix (reference; memory ``O(N)``).
    projection : {"auto", "lags", "periodic"}
        Closed-loop methods only. ``"lags"``: onto the row space of the
        block-Hankel ``[R_p; R_f]`` (2 i lags of r; any excitation).
        ``"periodic"``: the data are periodic (``data.period``): the
        steady-state periods (all but the first) are averaged and u, y
        projected onto the span of all circular lags of r, i.e. onto r's
        excited DFT lines. ``"auto"``: periodic when ``data.period`` is set and
        the record holds at least two periods.
    chunk : int
        Samples per chunk of the correlation sums.
    bd : {"auto", "least-squares", "projection"}
        Route to B and D. ``"least-squares"``: B, D and the initial state
        jointly by linear least squares on the simulated output (SLICOT
        IB01CD; :func:`workbench.ident.validate.least_squares_bd_x0`), which
        needs no rest at the start and no white input. ``"projection"``: the
        Toeplitz relation of the (projected) data below. ``"auto"``: least
        squares for the open-loop methods, projection for the closed-loop
        ones (on closed-loop data the output error is correlated with u
        through the controller, so its least squares is biased).
    orders : sequence of int, optional
        Realize each of these orders from one decomposition and return a list
        of results (the order scan); ``order`` is then ignored.

    Returns
    -------
    SubspaceResult (a list of them with ``orders``)

    Notes
    -----
    With ``Z = [U_f; W_p; Y_f]``, ``W_p = [U_p; Y_p]``, and ``L`` its lower
    LQ factor with blocks ``L_ab`` (Van Overschee & De Moor 1996, sec. 4.3):
    N4SID takes the SVD of the oblique projection ``L32 L22^+ [L21 L22]``;
    MOESP that of ``L32 L22^+ L22`` (``W2 = Pi_perp(U_f)``); CVA that of
    ``W1 L32 L22^+ L22`` with ``W1 = ((Y_f/U_f^perp)(Y_f/U_f^perp)^T)^(-1/2)``.
    ``Gamma = W1^-1 U_n S_n^(1/2)``, ``C`` its first block row and ``A`` from
    shift invariance. Open loop: ``B, D, x0`` by least squares on the
    simulated output (see ``bd``). Closed loop: ``B, D`` by least squares from the Toeplitz relation
    ``Gamma^perp Y_f U_f^+ = Gamma^perp H_i`` (Verhaegen 1994), linear in
    ``[D; B]``.

    Closed loop (Huang, Ding & Qin 2005): ``U`` and ``Y`` are first projected
    onto the row space of ``[R_p; R_f]``. With ``G_RR = L_R L_R^T`` (Cholesky)
    the projected data are ``M Q_R`` with ``M = G_XR L_R^-T`` and ``Q_R``
    orthonormal, so the open-loop problem is solved on the small ``M``.

    References
    ----------
    P. Van Overschee, B. De Moor, Subspace Identification for Linear Systems,
    Kluwer, 1996. B. Huang, S.X. Ding, S.J. Qin, Closed-loop subspace
    identification: an orthogonal projection approach, J. Process Control 15
    (2005) 53-66. M. Verhaegen, Identification of the deterministic part of
    MIMO state space models given in innovations form from input-output data,
    Automatica 30 (1994) 61-74.
    """
    if not isinstance(data, TimeData):
        raise InputError(f"data: expected time-domain data (TimeData), got {type(data).__name__}")
    if method not in METHODS:
        raise InputError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    if factorization not in ("gram", "qr"):
        raise InputError(f"factorization: expected 'gram' or 'qr', got {factorization!r}")
    closed = method.startswith("cl-")
    if closed and data.r is None:
        raise InputError(
            f"method {method!r}: expected closed-loop data with the excitation 'r', got none; "
            "use n4sid or moesp for open-loop data"
        )
    i = int(block_rows)
    n_u, n_y = data.n_u, data.n_y
    input_delay = int(input_delay)
    if input_delay < 0:
        raise InputError(f"input_delay: expected an integer >= 0 samples, got {input_delay}")
    N = data.n_samples - input_delay
    if i < 2:
        raise InputError(f"block_rows: expected an integer >= 2, got {block_rows}")
    n_rows = 2 * i * (n_u + n_y + (n_u if closed else 0))
    if N - 2 * i + 1 < 2 * n_rows:
        raise InputError(
            f"data: expected at least {2 * n_rows + 2 * i - 1} samples for {i} block rows, "
            f"got {N}; use fewer block rows"
        )
    if max_order is None:
        max_order = max(1, i * n_y // 2)
    max_order = min(int(max_order), i * n_y - 1)
    if bd not in ("auto", "least-squares", "projection"):
        raise InputError(f"bd: expected 'auto', 'least-squares' or 'projection', got {bd!r}")
    for o in [order] if orders is None else list(orders):
        if o is not None and not 1 <= int(o) < i * n_y:
            raise InputError(
                f"order: expected 1 <= order < block_rows * n_y = {i * n_y}, got {o}; "
                "increase block_rows"
            )
    if order is not None and not 1 <= int(order) < i * n_y:
        raise InputError(
            f"order: expected 1 <= order < block_rows * n_y = {i * n_y}, got {order}; "
            "increase block_rows"
        )

    # Align u, r with y for a known input delay; views, no copies.
    u = data.u[: data.n_samples - input_delay]
    y = data.y[input_delay:]
    su = _scale(u, "u")
    sy = _scale(y, "y")
    signals = [u, y]
    scales = [su, sy]
    if closed:
        r = data.r[: data.n_samples - input_delay]
        _scale(r, "r")
        signals = [r, u, y]
        scales = [su, su, sy]

    if projection not in ("auto", "lags", "periodic"):
        raise InputError(f"projection: expected 'auto', 'lags' or 'periodic', got {projection!r}")
    periodic = closed and (
        projection == "periodic"
        or (projection == "auto" and data.period is not None and data.n_samples >= 2 * data.period)
    )
    if periodic and (data.period is None or data.period <= 2 * i + 1):
        raise InputError(
            f"projection 'periodic': expected periodic data with a period > 2 * block_rows + 1 = "
            f"{2 * i + 1} samples, got period {data.period}"
        )
    if periodic:
        L, S_cva = _periodic_factor(
            data,
            input_delay=input_delay,
            su=su,
            sy=sy,
            i=i,
            cva=method.endswith("cva"),
            chunk=chunk,
        )
    else:
        L, S_cva = _data_factor(
            signals,
            scales,
            i=i,
            n_r=n_u if closed else 0,
            n_u=n_u,
            n_y=n_y,
            N=N,
            factorization=factorization,
            chunk=chunk,
            cva=method.endswith("cva"),
        )
    L, r1 = _rank_revealing(L, i * n_u)
    Gamma_full, sv, W1inv = _weighted_svd(L, S_cva, r1=r1, i=i, n_u=n_u, n_y=n_y, method=method)
    suggested, gap = suggest_order(sv, max_order=max_order)
    dec = _Decomposition(
        data=data,
        method=method,
        closed=closed,
        periodic=periodic,
        L=L,
        r1=r1,
        Gamma_full=Gamma_full,
        sv=sv,
        W1inv=W1inv,
        su=su,
        sy=sy,
        u=u,
        y=y,
        i=i,
        input_delay=input_delay,
        feedthrough=feedthrough,
        suggested=suggested,
        gap=gap,
        bd=bd,
    )
    if orders is not None:
        return [_realize(dec, int(n)) for n in orders]
    return _realize(dec, suggested if order is None else int(order))


@dataclass(frozen=True)
class _Decomposition:
    """Everything the realization of one order needs (internal; small but for u, y views)."""

    data: TimeData
    method: str
    closed: bool
    periodic: bool
    L: np.ndarray
    r1: int
    Gamma_full: np.ndarray
    sv: np.ndarray
    W1inv: np.ndarray
    su: np.ndarray
    sy: np.ndarray
    u: np.ndarray
    y: np.ndarray
    i: int
    input_delay: int
    feedthrough: bool
    suggested: int
    gap: float
    bd: str


def _realize(dec: _Decomposition, n: int) -> SubspaceResult:
    """A, C from the observability matrix of order n; B, D (and x0) by the chosen route."""
    data, i, sv = dec.data, dec.i, dec.sv
    n_u, n_y = data.n_u, data.n_y
    Gamma = dec.W1inv @ dec.Gamma_full[:, :n] * np.sqrt(sv[:n])
    C = Gamma[:n_y]
    A = np.linalg.lstsq(Gamma[:-n_y], Gamma[n_y:], rcond=None)[0]
    use_ls = dec.bd == "least-squares" or (dec.bd == "auto" and not dec.closed)
    x0 = None
    notes = []
    if use_ls:
        from workbench.ident.validate import DivergentModel, least_squares_bd_x0

        try:
            B, D, x0 = least_squares_bd_x0(
                A, C, dec.u, dec.y, su=dec.su, sy=dec.sy, feedthrough=dec.feedthrough
            )
        except DivergentModel as exc:
            # an unstable A: the output-error least squares is ill-posed; keep a model
            use_ls = False
            notes.append(f"{exc}; B, D from the projected data instead of least squares")
    if use_ls:
        bd_route = "least squares on the simulated output (B, D, x0 jointly)"
    else:
        B, D = _b_d(dec.L, A, C, r1=dec.r1, i=i, n_u=n_u, n_y=n_y, feedthrough=dec.feedthrough)
        bd_route = "projection (Toeplitz relation of the projected data)"

    # undo the channel scaling: y = sy * y_s, u = su * u_s (the state is unchanged)
    su, sy = dec.su, dec.sy
    B = B / su[None, :]
    C = sy[:, None] * C
    D = sy[:, None] * D / su[None, :]
    import control

    model = control.ss(
        A, B, C, D, 1.0 / data.fs, inputs=list(data.input_names), outputs=list(data.output_names)
    )
    if np.max(np.abs(np.linalg.eigvals(A))) >= 1.0:
        notes.append("the identified model has poles on or outside the unit circle")
    if dec.r1 < i * n_u:
        notes.append(
            f"U_f is numerically rank-deficient ({dec.r1} of {i * n_u}: a band-limited excitation)"
            + (
                "; the N4SID oblique projection is ill-posed here, prefer MOESP or CVA"
                if dec.method.endswith("n4sid")
                else ""
            )
        )
    if dec.periodic:
        notes.append(
            f"periodic projection: {data.n_samples // data.period} periods, the first of each "
            "experiment block dropped as a transient"
        )
    return SubspaceResult(
        model=model,
        singular_values=sv,
        order=n,
        suggested_order=dec.suggested,
        gap=dec.gap,
        method=dec.method,
        block_rows=i,
        input_delay=dec.input_delay,
        fs=data.fs,
        notes=tuple(notes),
        bd_method=bd_route,
        x0=x0,
    )


# ----------------------------------------------------------------- internals
def _scale(x: np.ndarray, name: str) -> np.ndarray:
    s = np.sqrt(np.einsum("ij,ij->j", x, x) / x.shape[0])  # no O(N) temporary
    if np.any(s == 0):
        k = int(np.flatnonzero(s == 0)[0])
        raise InputError(
            f"data: key '{name}': channel {k} is identically zero; it cannot be identified"
        )
    return s


def _data_factor(signals, scales, *, i, n_r, n_u, n_y, N, factorization, chunk, cva):
    """Lower factor L (rows x c) of Z = [U_f; U_p; Y_p; Y_f] (projected onto R if n_r).

    Also returns the Gram of the raw (unprojected) ``Y_f / U_f^perp``, the CVA
    weight's argument: on projected closed-loop data with ``n_y <= n_u`` that
    Gram is square and full rank within the projected space, so weighting by
    it would whiten every direction alike.
    """
    k = 2 * i
    m = n_r + n_u + n_y

    def rows(offset: int, width: int, blocks) -> np.ndarray:
        return np.concatenate([np.arange(a * m + offset, a * m + offset + width) for a in blocks])

    past, future = range(0, i), range(i, k)
    iu, iy = n_r, n_r + n_u
    order_z = np.concatenate(
        [rows(iu, n_u, future), rows(iu, n_u, past), rows(iy, n_y, past), rows(iy, n_y, future)]
    )
    if factorization == "qr":
        H = hankel(signals, scales, n_blocks=k, n_samples=N)
        iuf, iyf = rows(iu, n_u, future), rows(iy, n_y, future)
        S = _perp_gram(H[iyf] @ H[iyf].T, H[iyf] @ H[iuf].T, H[iuf] @ H[iuf].T) if cva else None
        if n_r:
            ir = rows(0, n_r, range(k))
            Rt = np.linalg.qr(np.vstack([H[ir], H[order_z]]).T, mode="r")
            M = Rt[: ir.size, ir.size :].T  # coordinates of Z in the orthonormal basis of R
            return np.linalg.qr(M.T, mode="r").T, S
        Rt = np.linalg.qr(H[order_z].T, mode="r")
        return Rt.T, S
    iuf, iyf = rows(iu, n_u, future), rows(iy, n_y, future)
    if n_r and not cva:
        # the projection onto R needs the rows of R alone: G_RR and G_RZ
        ir = rows(0, n_r, range(k))
        G_R = hankel_gram(signals, scales, n_blocks=k, n_samples=N, chunk=chunk, rows=ir)
        M = _project_onto(G_R[:, ir], G_R[:, order_z])
        return _lq(M), None
    G = hankel_gram(signals, scales, n_blocks=k, n_samples=N, chunk=chunk)
    S = _perp_gram(G[np.ix_(iyf, iyf)], G[np.ix_(iyf, iuf)], G[np.ix_(iuf, iuf)]) if cva else None
    if n_r:
        ir = rows(0, n_r, range(k))
        M = _project_onto(G[np.ix_(ir, ir)], G[np.ix_(ir, order_z)])
        return _lq(M), S
    return _factor(G[np.ix_(order_z, order_z)]), S


def _lq(M: np.ndarray) -> np.ndarray:
    """Lower LQ factor L of M (rows x c), ``L L^T = M M^T``: the R factor of M^T, transposed."""
    # M^T is Fortran-ordered when M is C-ordered: LAPACK factors it in place, no copy
    return scipy.linalg.qr(M.T, mode="r", overwrite_a=True, check_finite=False)[0].T


def _factor(Gz: np.ndarray) -> np.ndarray:
    """Lower LQ factor L (rows x c) with L L^T = Gz (Cholesky; eigen square root if singular)."""
    try:
        return np.linalg.cholesky(Gz)
    except np.linalg.LinAlgError:
        # rank-deficient (noise-free) data: a symmetric square root, then LQ
        lam, V = np.linalg.eigh(Gz)
        lam = np.clip(lam, 0.0, None)
        keep = lam > lam[-1] * 1e-15 * Gz.shape[0]
        F = V[:, keep] * np.sqrt(lam[keep])
        return np.linalg.qr(F.T, mode="r").T


def _periodic_factor(data, *, input_delay, su, sy, i, cva, chunk, n_transient=1):
    """L for closed-loop periodic data: projection onto r as a selection of r's DFT lines.

    The steady-state periods are averaged; for a periodic ``r`` the row space
    of all its (circular) lags is the set of periodic signals on r's excited
    lines, so the orthogonal projection of u and y onto it keeps exactly those
    lines. The projected signals are periodic and noise-reduced; their
    circular block-Hankel Gram is block-Toeplitz, ``G[a, b] = F_{b-a}``.
    """
    from workbench.signals.periodic import periodic_record

    P = int(data.period)
    # A record may hold several experiments (blocks of identical periods, each
    # its own r): each block is projected onto its own r's lines, and the
    # circular Grams of the blocks add up.
    rec = periodic_record(data, n_transient=n_transient, min_periods=1, reference="r")
    # y[k + d] with u[k] in the periodic steady state: a circular shift, exp(+j 2 pi k d / P)
    shift = np.exp(2j * np.pi * np.arange(rec.n_bins) * input_delay / P)[:, None]
    blocks = []
    for b in range(rec.n_blocks):
        mask = rec.excited[b][:, None]
        uh = np.fft.irfft(rec.U[b] * mask, n=P, axis=0) / su
        yh = np.fft.irfft(rec.Y[b] * shift * mask, n=P, axis=0) / sy
        blocks.append(np.hstack([uh, yh]))
    n_u, n_y = data.n_u, data.n_y
    m, k = n_u + n_y, 2 * i
    # sum over blocks and t of z_t z_{t+d}^T, circular
    F = [sum(z.T @ np.roll(z, -d, axis=0) for z in blocks) for d in range(k)]
    G = np.empty((k * m, k * m))
    G4 = G.reshape(k, m, k, m)
    for d in range(k):
        a = np.arange(k - d)
        G4[a, :, a + d, :] = F[d]
        G4[a + d, :, a, :] = F[d].T

    def rows(offset, width, blocks):
        return np.concatenate([np.arange(b * m + offset, b * m + offset + width) for b in blocks])

    past, future = range(0, i), range(i, k)
    order_z = np.concatenate(
        [rows(0, n_u, future), rows(0, n_u, past), rows(n_u, n_y, past), rows(n_u, n_y, future)]
    )
    S = None
    if cva:  # the raw data's Y_f / U_f^perp, noise included (see _data_factor)
        N = data.n_samples - input_delay
        Graw = hankel_gram(
            [data.u[:N], data.y[input_delay:]], [su, sy], n_blocks=k, n_samples=N, chunk=chunk
        )
        iuf, iyf = rows(0, n_u, future), rows(n_u, n_y, future)
        S = _perp_gram(Graw[np.ix_(iyf, iyf)], Graw[np.ix_(iyf, iuf)], Graw[np.ix_(iuf, iuf)])
    return _factor(G[np.ix_(order_z, order_z)]), S


def _perp_gram(G_yy, G_yu, G_uu) -> np.ndarray:
    """Gram of Y / U^perp: ``G_yy - G_yu G_uu^+ G_uy`` (symmetric, PSD)."""
    lam, V = np.linalg.eigh(G_uu)
    keep = lam > lam[-1] * 1e-12
    W = (G_yu @ V[:, keep]) / np.sqrt(lam[keep])
    S = G_yy - W @ W.T
    return 0.5 * (S + S.T)


def _project_onto(G_RR: np.ndarray, G_RZ: np.ndarray) -> np.ndarray:
    """Coordinates ``M`` (n_z, r) of Z/R in an orthonormal basis of the row space of R.

    ``M = G_ZR V diag(lam)^-1/2`` with ``G_RR = V diag(lam) V^T``, keeping the
    eigenvalues above ``1e-12 lam_max``: a band-limited excitation (a multisine
    up to 60 % of Nyquist, say) leaves a numerically null part of its lagged
    row space, which carries no data and is dropped rather than inverted.
    """
    # G_RR is a gathered copy: LAPACK's divide and conquer (syevd, numpy's driver too) may
    # overwrite it, and the finite check is the data's, done at the boundary
    lam, V = scipy.linalg.eigh(G_RR, driver="evd", overwrite_a=True, check_finite=False)
    keep = lam > lam[-1] * 1e-12
    if not np.any(keep) or lam[-1] <= 0:
        raise InputError("data: key 'r': the excitation is zero; closed-loop methods need r")
    # eigenvalues ascend: the kept ones are a tail, and the scaling goes on the small factor
    first = int(np.argmax(keep))
    return G_RZ.T @ (V[:, first:] / np.sqrt(lam[first:]))


def _rank_revealing(L: np.ndarray, a: int, *, rtol: float = 1e-8) -> tuple[np.ndarray, int]:
    """Rotate the columns of L so that U_f (the first ``a`` rows) spans the first r1 columns.

    Needed when U_f is numerically rank-deficient (a band-limited excitation,
    or data projected onto one): the LQ factor's block-1 columns beyond the
    rank are arbitrary directions, and the state information that Y_f has
    there would be taken for U_f's. Returns the rotated L and the rank r1.
    """
    c = L.shape[1]
    d = np.abs(np.diag(L[: min(a, c), : min(a, c)]))
    if a <= c and d.size and d.min() > 1e-7 * d.max():
        return L, a
    _, s1, Vt = np.linalg.svd(L[:a], full_matrices=True)
    r1 = int(np.sum(s1 > rtol * s1[0]))
    L = L @ Vt.T
    L[:a, r1:] = 0.0
    return L, r1


def _weighted_svd(L, S_cva, *, r1, i, n_u, n_y, method):
    """Left singular vectors, singular values, and W1^-1 of the weighted projection."""
    a = i * n_u
    b = i * (n_u + n_y)
    c = L.shape[1]
    c1 = slice(0, r1)
    c2 = slice(r1, c)  # everything orthogonal to U_f (block-3 columns are 0 in W_p's rows)
    L21, L22 = L[a : a + b, c1], L[a : a + b, c2]
    L32 = L[a + b :, c2]
    n4sid = method.endswith("n4sid")
    if not n4sid:
        # MOESP and CVA use L22 only through the projector onto its row space: when L22 has
        # full column rank that is the identity on the c2 columns (L32 L22^+ L22 = L32), and
        # its singular values alone tell it; the vectors are needed only below full rank
        s22 = scipy.linalg.svdvals(L22, check_finite=False)
        full = s22.size == L22.shape[1] and (s22.size == 0 or s22[-1] > s22[0] * 1e-8)
    if n4sid or not full:
        # orthonormal basis of the row space of L22 (rank-revealing)
        U22, s22, Vt22 = np.linalg.svd(L22, full_matrices=False)
    tol = s22[0] * 1e-8 if s22.size else 0.0
    r22 = int(np.sum(s22 > tol))
    if n4sid:
        # O_i = L32 L22^+ [L21 L22]
        V = Vt22[:r22].T  # (cols of c2, r22)
        L22p = V @ (U22[:, :r22] / s22[:r22]).T
        O = L32 @ L22p @ np.hstack([L21, L22])
        W1inv = np.eye(i * n_y)
        target = O
    else:
        # L32 L22^+ L22 in the basis V of L22's row space (the same singular values and left
        # vectors as in any orthonormal basis of it: with full rank, the c2 columns themselves)
        target = L32 if full else L32 @ Vt22[:r22].T
        W1inv = np.eye(i * n_y)
        if method.endswith("cva"):
            lam, E = np.linalg.eigh(S_cva)
            floor = lam[-1] * 1e-12
            if np.any(lam <= floor):
                warnings.warn(
                    "cva: (Y_f/U_f^perp) is rank-deficient (noise-free data); "
                    "its inverse square root is regularized",
                    DataWarning,
                    stacklevel=3,
                )
            lam = np.maximum(lam, floor)
            W1 = (E / np.sqrt(lam)) @ E.T
            W1inv = (E * np.sqrt(lam)) @ E.T
            target = W1 @ target
    Us, sv = scipy.linalg.svd(target, full_matrices=False, check_finite=False)[:2]
    return Us, sv, W1inv


def _b_d(L, A, C, *, r1, i, n_u, n_y, feedthrough):
    """[D; B] by least squares from Gamma^perp Y_f U_f^+ = Gamma^perp H_i."""
    n = A.shape[0]
    a = i * n_u
    b = i * (n_u + n_y)
    Gam = np.empty((i * n_y, n))
    Gam[:n_y] = C
    for p in range(1, i):
        Gam[p * n_y : (p + 1) * n_y] = Gam[(p - 1) * n_y : p * n_y] @ A
    Ug = np.linalg.svd(Gam, full_matrices=True)[0]
    P = Ug[:, n:].T  # (i n_y - n, i n_y), P Gamma = 0
    L11 = L[:a, :r1]
    L31 = L[a + b :, :r1]
    if r1 == a and not np.any(np.abs(L11[np.triu_indices(a, 1)]) > 1e-8):  # lower triangular
        K = P @ scipy.linalg.solve_triangular(L11, L31.T, lower=True, trans="T").T  # P L31 L11^-1
    else:
        K = P @ L31 @ np.linalg.pinv(L11)
    # block row q: [P_q, sum_{p > q} P_p C A^(p - q - 1)]; the tails by Horner's rule from the
    # last block row up, tail_q = P_(q+1) C + tail_(q+1) A
    n_p = P.shape[0]
    tails = np.zeros((i, n_p, n))
    for q in range(i - 2, -1, -1):
        tails[q] = P[:, (q + 1) * n_y : (q + 2) * n_y] @ C + tails[q + 1] @ A
    if feedthrough:
        Pq = P.reshape(n_p, i, n_y).transpose(1, 0, 2)  # (i, n_p, n_y): block q is P_q
        rows = list(np.concatenate([Pq, tails], axis=2))
    else:
        rows = list(tails)
    rhs = list(K.reshape(n_p, i, n_u).transpose(1, 0, 2))
    if r1 == a:
        sol = np.linalg.lstsq(np.vstack(rows), np.vstack(rhs), rcond=None)[0]
    else:
        # U_f rank-deficient: only P H_i Pi is known, Pi the projector onto U_f's range;
        # sum_q N_q X (E_q^T Pi) = K, solved for vec(X) (Kronecker form).
        Pi = L11 @ np.linalg.pinv(L11)
        n_x = rows[0].shape[1]
        M = np.zeros((P.shape[0] * a, n_x * n_u))
        for q in range(i):
            M += np.kron(Pi[q * n_u : (q + 1) * n_u].T, rows[q])
        x = np.linalg.lstsq(M, K.reshape(-1, order="F"), rcond=None)[0]
        sol = x.reshape(n_x, n_u, order="F")
    if feedthrough:
        return sol[n_y:], sol[:n_y]
    return sol, np.zeros((n_y, n_u))
