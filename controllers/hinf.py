"""Discrete-time H-infinity synthesis (Riccati or LMI), mixed-sensitivity plants and weights.

Two syntheses of the same problem, min gamma such that ||T_zw||inf < gamma::

    W1 = weight(100.0, 20.0, 0.5, fs)          # on S: |W1| = 100 at DC, 1 at 20 Hz, 0.5 at Nyquist
    P, n_meas, n_ctrl, rho = mixed_sensitivity(G, W1, W3=weight(0.5, 200.0, 100.0, fs))
    K, report = hinf_riccati(P, n_meas, n_ctrl) # StateSpaceController e -> u, dt = 1/fs
    K, report = hinf_lmi(P, n_meas, n_ctrl)     # the same problem by LMIs (cvxpy)

``hinf_riccati`` (the default of :func:`design_hinf_mixed` and :func:`tune_hinf`)
maps P to continuous time by the inverse bilinear (Tustin) map, which keeps the
H-inf norm and stability exactly, runs SLICOT's SB10AD (Glover-Doyle Riccati
formulas with a gamma iteration; slycot, as ``control.hinfsyn``) and maps the
controller back: milliseconds for the stage's channel plants, and the gamma
optimum to the bisection's accuracy. ``hinf_lmi`` is the convex LMI formulation
of the discrete bounded real lemma with Scherer's change of variables (Scherer,
Gahinet & Chilali 1997; the discrete form as in de Oliveira, Geromel &
Bernussou), solved by cvxpy (CLARABEL if installed, else SCS): no slycot, no
rank assumptions on D12 / D21, seconds per solve, and on badly scaled plants
(a ZOH double integrator with delay at 5 kHz) a gamma above the optimum. It is
kept as the independent cross-check of the tests and as ``method="lmi"``.

Generalized plant convention (D22 handled by a loop transformation)::

    x+ = A x + B1 w + B2 u,   z = C1 x + D11 w + D12 u,   v = C2 x + D21 w + D22 u,   u = K v

Rigid-body trap: a plant with poles on the unit circle (a ZOH double integrator
has two at z = 1) is not reachable from w at those poles in a mixed-sensitivity
plant (w enters only the error), so the gamma-optimal LMI solution runs off to
infinity (X or Y unbounded, the controller ill-conditioned), and the Riccati
synthesis refuses the unit-circle zeros. ``mixed_sensitivity``
therefore designs on a shifted plant: ``A_G -> rho A_G`` with
``rho = 1 - pole_shift`` when G has poles with |z| > 1 - pole_shift. This moves
every plant pole radially inward by the factor rho (an integrator becomes a
low-pass with corner ~ pole_shift * fs / (2 pi) Hz); above that corner the
shifted and the true plant agree, so the design holds there, and below it the
true plant has more gain, so |S| of the true loop is smaller. The true loop's
stability is not implied by the shift: callers must check it (the tests do, on
a double integrator 1/(m s^2) with ZOH).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from controllers.protocol import StateSpaceController
from workbench.core.errors import InputError

#: the syntheses design_hinf_mixed and tune_hinf offer
_METHODS = ("riccati", "lmi")

__all__ = [
    "HinfDesign",
    "HinfReport",
    "design_hinf_mixed",
    "hinf_lmi",
    "hinf_norm_grid",
    "hinf_riccati",
    "mixed_sensitivity",
    "channel_plant",
    "tune_hinf",
    "weight",
]


@dataclass(frozen=True)
class HinfReport:
    """What the synthesis did.

    Attributes
    ----------
    gamma : float
        Bound on ||T_zw||inf of the returned controller: the LMI certificate
        (lmi), or the gamma level the central controller was built for (riccati).
    gamma_opt : float
        The minimized gamma: of the first LMI pass of the attempt that gave the
        controller (lmi; gamma >= gamma_opt, with X, Y bounded it may exceed the
        true optimum slightly), or SB10AD's gamma iteration (riccati).
    solver, status : str
        cvxpy solver and its status (lmi), or "slycot.sb10ad" and "optimal" /
        "backoff <b>" when a larger backoff than asked gave the stable loop (riccati).
    time_s : float
        Wall time of the synthesis, s.
    pole_shift : float
        Radial shift applied to the plant for synthesis (0: none); mixed_sensitivity only.
    method : str
        "riccati" or "lmi".
    """

    gamma: float
    gamma_opt: float
    solver: str
    status: str
    time_s: float
    pole_shift: float = 0.0
    method: str = "lmi"


def _solve(problem, solver: str) -> str:
    """Solve a cvxpy problem; its status, or "solver_error" when the solver gave up."""
    import cvxpy as cp

    try:
        # "Solution may be inaccurate": the status says it (optimal_inaccurate), and
        # the callers check every candidate's closed loop; a warning would only add a line
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Solution may be inaccurate")
            problem.solve(solver=solver)
    except cp.error.SolverError:
        return "solver_error"
    return problem.status


def _solver() -> str:
    import cvxpy as cp

    for name in ("CLARABEL", "SCS"):
        if name in cp.installed_solvers():
            return name
    raise InputError(
        f"hinf: expected cvxpy with CLARABEL or SCS installed, got {cp.installed_solvers()}"
    )


def _discrete(sys, name: str):
    from workbench.core.lti import as_matrices

    try:
        A, B, C, D, dt = as_matrices(sys)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - anything not a model is bad input
        raise InputError(f"{name}: expected a discrete StateSpace or LTIModel, got {exc}") from exc
    if float(getattr(sys, "delay_s", 0.0) or 0.0):
        raise InputError(f"{name}: expected no delay_s (put the delay into the states), got one")
    if not dt or dt <= 0 or dt is True:
        raise InputError(f"{name}: expected a discrete model (dt > 0), got dt = {dt}")
    return (np.asarray(A, float), np.asarray(B, float), np.asarray(C, float),
            np.asarray(D, float), float(dt))  # fmt: skip


def _inverse_tustin(A, B, C, D, dt: float):
    """Continuous (A, B, C, D) whose Tustin map with step dt is the discrete one.

    ``z = (1 + s dt/2) / (1 - s dt/2)``, so ``G_c(j w) = G_d(e^{j theta})``
    with ``w = (2/dt) tan(theta/2)``: the H-inf norm and stability are kept.
    With ``E = (I + A)^-1``: ``Ac = (2/dt) E (A - I)``, ``Bc = (2/sqrt(dt)) E B``,
    ``Cc = (2/sqrt(dt)) C E``, ``Dc = D - C E B`` (B and C split evenly);
    :func:`_tustin` is its exact inverse. Needs no pole at z = -1.
    """
    n = A.shape[0]
    In = np.eye(n)
    if n and np.min(np.abs(np.linalg.eigvals(A) + 1.0)) < 1e-9:
        raise InputError("P: expected no pole at z = -1 (Nyquist) for the bilinear map")
    E = np.linalg.inv(In + A)
    k = 2.0 / np.sqrt(dt)
    return (2.0 / dt) * E @ (A - In), k * E @ B, k * C @ E, D - C @ E @ B


def _tustin(A, B, C, D, dt: float):
    """Discrete (A, B, C, D) of a continuous one by Tustin; inverse of :func:`_inverse_tustin`.

    ``F = (I - A dt/2)^-1``: ``Ad = 2 F - I``, ``Bd = sqrt(dt) F B``,
    ``Cd = sqrt(dt) C F``, ``Dd = D + (dt/2) C F B``.
    """
    n = A.shape[0]
    M = np.eye(n) - A * dt / 2
    if n and np.min(np.abs(np.linalg.eigvals(M))) < 1e-12:
        raise InputError("controller: a pole at s = 2/dt has no Tustin image")
    F = np.linalg.inv(M) if n else M
    r = np.sqrt(dt)
    return 2.0 * F - np.eye(n), r * F @ B, r * C @ F, D + (dt / 2) * C @ F @ B


def _state_scaling(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Diagonal state scaling t (n,) for the LMI: x = diag(t) x_scaled.

    Why: a delayed ZOH double integrator at kHz rates comes as a chain with
    couplings ~ 1/fs and an input column ~ 1e7 after the delay; ``matrix_balance``
    of A alone leaves it (a zero row), and the interior-point solver then fails.
    For a stable A, t_i = (Wc_ii / Wo_ii)^(1/4) from the controllability and
    observability Gramians equalizes their diagonals (the diagonal part of a
    balanced realization, defined also for non-minimal states); otherwise the
    square matrix [[A, B], [C, 0]] (padded) is balanced and its state part kept.
    """
    from scipy.linalg import matrix_balance, solve_discrete_lyapunov

    n = A.shape[0]
    if np.max(np.abs(np.linalg.eigvals(A))) < 1.0 - 1e-9:
        try:
            Bn = B / max(np.abs(B).max(), 1e-300)
            Cn = C / max(np.abs(C).max(), 1e-300)
            wc = np.diag(solve_discrete_lyapunov(A, Bn @ Bn.T)).copy()
            wo = np.diag(solve_discrete_lyapunov(A.T, Cn.T @ Cn)).copy()
            floor = 1e-12 * max(wc.max(), wo.max(), 1e-300)
            t = ((np.maximum(wc, floor)) / np.maximum(wo, floor)) ** 0.25
            if np.all(np.isfinite(t)) and np.all(t > 0):
                return t / np.exp(np.mean(np.log(t)))
        except (np.linalg.LinAlgError, ValueError):
            pass
    k = max(B.shape[1], C.shape[0])
    M = np.zeros((n + k, n + k))
    M[:n, :n], M[:n, n : n + B.shape[1]], M[n : n + C.shape[0], :n] = A, B, C
    _, T = matrix_balance(M, permute=False, separate=False)
    return np.diag(T)[:n].copy()


def _check_plant(P, n_meas, n_ctrl):
    """(A, B, C, D, dt, n_w, n_z) of a generalized plant P, checked at the boundary."""
    A, B, C, D, dt = _discrete(P, "P")
    n_meas, n_ctrl = int(n_meas), int(n_ctrl)
    nw, nz = B.shape[1] - n_ctrl, C.shape[0] - n_meas
    if n_meas < 1 or n_ctrl < 1 or nw < 1 or nz < 1:
        raise InputError(
            f"P: expected >= 1 exogenous input w, performance output z, control u and "
            f"measurement v, got {B.shape[1]} inputs / {C.shape[0]} outputs for "
            f"n_ctrl = {n_ctrl}, n_meas = {n_meas}"
        )
    if A.shape[0] == 0:
        raise InputError("P: expected a plant with states, got a static gain")
    if not np.all(np.isfinite(np.block([[A, B], [C, D]]))):
        raise InputError("P: expected finite matrices, got NaN or inf")
    return A, B, C, D, dt, nw, nz


def _undo_d22(AK, BK, CK, DK, D22):
    """Controller for the plant with D22 from K0 designed with D22 = 0 (either domain).

    ``u = K0 v0`` with ``v0 = v - D22 u``  =>  ``K = K0 (I + D22 K0)^-1``.
    """
    if not np.any(D22):
        return AK, BK, CK, DK
    nu, ny = DK.shape
    M = np.eye(nu) + DK @ D22
    if np.linalg.cond(M) > 1e12:
        raise np.linalg.LinAlgError("I + DK D22 singular: the loop is not well posed")
    E = np.linalg.inv(M)
    return (AK - BK @ D22 @ E @ CK, BK @ (np.eye(ny) - D22 @ E @ DK), E @ CK, E @ DK)


#: SB10AD's INFO codes that mean "gamma too small" (the gamma search raises gamma on them)
_SB10AD_NOT_ADMISSIBLE = (6, 7, 8, 12)


def _sb10ad_refusal(info: int) -> str:
    """The InputError message of an SB10AD failure, in the discrete plant's terms.

    The bilinear image's feedthrough is the discrete plant at Nyquist (s = inf is
    z = -1) and its j-omega axis is the unit circle: SB10AD's assumptions on
    D12, D21 and the j-omega axis zeros are stated for P at z = -1 and on |z| = 1.
    """
    what = {
        1: "[A - z I, B2; C1, D12] of full column rank on |z| = 1 (u -> z without zeros "
        "on the unit circle, z seeing every unit-circle pole), got a rank loss (z does not "
        "depend on u, or a zero of P_zu on the unit circle)",
        2: "[A - z I, B1; C2, D21] of full row rank on |z| = 1 (w -> v without zeros on "
        "the unit circle, w reaching every unit-circle pole), got a rank loss (an "
        "integrator or rigid-body pole of G with pole_shift = 0, or v not disturbed by w)",
        3: "D12 of the bilinear image, P_zu(z = -1), to have full column rank (u seen in z "
        "at Nyquist), got rank deficient (add a constant weight W2 on K S; method='lmi' "
        "does not need it)",
        4: "D21 of the bilinear image, P_vw(z = -1), to have full row rank (every "
        "measurement disturbed by w at Nyquist), got rank deficient (method='lmi' does "
        "not need it)",
        5: "SB10AD's SVDs to converge, got no convergence",
        9: "I + D11hat D22 invertible, got singular",
        10: "the D11 singular values to be computable, got numerical problems",
        11: "I - D22 DK invertible, got singular",
    }.get(info, f"SB10AD to succeed, got INFO = {info}")
    return f"P: H-inf Riccati synthesis (SLICOT SB10AD): expected {what}"


def _singular_feedthrough(A, B, C, D, Dc, nw: int, nz: int) -> int:
    """3 when D12 of the bilinear image is rank deficient, 4 for D21, else 0.

    Relative to the channel's peak gain on the unit circle (64 lines, a scale
    free measure: u, w, z, v come in any units): a smallest singular value
    below 1e-10 of it is a zero at Nyquist, not a design.
    """
    theta = np.pi * (np.arange(64) + 0.5) / 64
    n = A.shape[0]
    H = np.array([D + C @ np.linalg.solve(np.exp(1j * th) * np.eye(n) - A, B) for th in theta])
    for info, blk, hblk in (
        (3, Dc[:nz, nw:], H[:, :nz, nw:]),
        (4, Dc[nz:, :nw], H[:, nz:, :nw]),
    ):
        peak = max(float(np.linalg.norm(h, 2)) for h in hblk)
        if np.linalg.svd(blk, compute_uv=False)[-1] <= 1e-10 * max(peak, 1e-300):
            return info
    return 0


def hinf_riccati(
    P,
    n_meas: int,
    n_ctrl: int,
    *,
    gamma_max: float | None = None,
    backoff: float = 1e-3,
    blas_threads: int | None = 1,
    input_names=(),
    output_names=(),
) -> tuple[StateSpaceController, HinfReport]:
    """Gamma-optimal discrete H-infinity output-feedback controller by Riccati equations.

    P is mapped to continuous time by the inverse bilinear map (:func:`_inverse_tustin`),
    which keeps the H-inf norm and stability exactly; SLICOT's SB10AD (slycot,
    the routine behind ``control.hinfsyn``) finds the optimal gamma by bisection
    and the central controller; the controller is mapped back by Tustin.

    Parameters
    ----------
    P : discrete control.StateSpace or LTIModel
        Generalized plant [w; u] -> [z; v]; the last ``n_ctrl`` inputs are u,
        the last ``n_meas`` outputs are v.
    n_meas, n_ctrl : int
        Measurements v (controller inputs) and controls u (controller outputs).
    gamma_max : float, optional
        Refuse (InputError) when the optimal gamma exceeds this.
    backoff : float
        The controller is the central one at gamma = (1 + backoff) gamma_opt
        (why: at gamma_opt itself I - X Y / gamma^2 is singular and the central
        controller has poles running off to s = -inf, i.e. z -> -1, and gains to
        match). Grows (1e-2, 5e-2, 0.2) until the discrete loop is stable.
    blas_threads : int or None
        BLAS threads for the synthesis (:func:`workbench.core.blas.limited_blas`;
        SB10AD's many small factorizations are ~10x slower with two threads on
        a busy 2-core machine).
    input_names, output_names : sequence of str
        Names of the controller's inputs (measurements) and outputs (controls).

    Returns
    -------
    (StateSpaceController, HinfReport)
        Controller v -> u with dt of P and as many states as P;
        ``report.gamma`` = (1 + backoff) ``report.gamma_opt`` bounds ||T_zw||inf.

    Raises
    ------
    InputError
        Bad P; slycot missing; an SB10AD assumption violated (D12 / D21 of the
        bilinear image rank deficient, i.e. P_zu / P_vw vanishing at Nyquist;
        P_zu / P_vw with zeros on the unit circle), named in the message; no
        stabilizing controller at any gamma (P not stabilizable from u or not
        detectable from v); gamma_opt above gamma_max.

    Notes
    -----
    Why not ``control.hinfsyn(P, nmeas, ncon)`` itself: it calls SB10AD with the
    fixed start gamma = 1e100, and the bisection from there takes ~330 steps
    (0.2 s for the stage's 10-state channel plants, one BLAS thread), and it
    returns the central controller at the optimum itself. Here the start is the
    first admissible gamma of g0, 10 g0, 100 g0, ... with g0 = max(1.01
    sigma_max(D11), 1e-3) of the image (``job=4``: one controller, ~1 ms each),
    then ``job=1`` (bisection) from it, then ``job=4`` at the backed-off gamma:
    ~10x faster, the same optimum (within 5e-5 relative on the stage's
    channel plants; the tests compare with ``control.hinfsyn`` and with
    :func:`hinf_lmi`).

    The plant's states are scaled as for the LMI (:func:`_state_scaling`, a
    diagonal similarity, which commutes with the bilinear map and leaves K
    unchanged): SB10AD's Riccati condition estimates on the stage's channel
    plants rise from ~1e-23 to ~1e-14 with it.

    References
    ----------
    Glover, K. & Doyle, J. C. (1988). State-space formulae for all stabilizing
    controllers that satisfy an H-inf norm bound. Systems & Control Letters 11.
    SLICOT SB10AD documentation (slycot.sb10ad).
    """
    t0 = time.perf_counter()
    A, B, C, D, dt, nw, nz = _check_plant(P, n_meas, n_ctrl)
    n_meas, n_ctrl = int(n_meas), int(n_ctrl)
    backoff = float(backoff)
    if not np.isfinite(backoff) or backoff <= 0:
        raise InputError(f"backoff: expected a relative gamma margin > 0, got {backoff}")
    try:
        from slycot import sb10ad
        from slycot.exceptions import SlycotError
    except ImportError as exc:
        raise InputError(
            "hinf: method 'riccati' needs slycot (pip install slycot), got none; "
            "method='lmi' needs only cvxpy"
        ) from exc
    from workbench.core.blas import limited_blas

    for what, short, have, need in (
        ("D12", "column", nz, n_ctrl),
        ("D21", "row", nw, n_meas),
    ):
        if have < need:
            raise InputError(
                f"P: H-inf Riccati synthesis (SLICOT SB10AD): expected {what} of full {short} "
                f"rank, which needs n_z >= n_ctrl and n_w >= n_meas, got n_z = {nz}, n_w = {nw} "
                f"for n_ctrl = {n_ctrl}, n_meas = {n_meas} (method='lmi' does not need it)"
            )
    n = A.shape[0]
    t = _state_scaling(A, B, C)  # x = diag(t) x_s
    As, Bs, Cs = A * (1.0 / t)[:, None] * t[None, :], B / t[:, None], C * t[None, :]
    Ac, Bc, Cc, Dc = _inverse_tustin(As, Bs, Cs, D, dt)
    D22 = Dc[nz:, nw:].copy()
    Dc = Dc.copy()
    Dc[nz:, nw:] = 0.0  # designed for D22 = 0, undone on K (as hinf_lmi)
    n_in, n_out = B.shape[1], C.shape[0]

    def run(gamma: float, job: int):
        """SB10AD's (gamma, AK, BK, CK, DK, rcond), or the INFO code of its failure."""
        try:
            out = sb10ad(n, n_in, n_out, n_ctrl, n_meas, gamma, Ac, Bc, Cc, Dc, job=job)
        except SlycotError as exc:
            return int(exc.info)
        return out[0], out[1], out[2], out[3], out[4], out[9]

    # gamma > sigma_max(D11) for every admissible controller: the search starts above it
    start = max(1.01 * float(np.linalg.norm(Dc[:nz, :nw], 2)), 1e-3)
    with limited_blas(blas_threads):
        for _ in range(16):  # up to 1e13: gamma_opt of a sane weighting is far below
            got = run(start, 4)
            if isinstance(got, tuple) or got not in _SB10AD_NOT_ADMISSIBLE:
                break
            start *= 10.0
        if isinstance(got, int):
            if got not in _SB10AD_NOT_ADMISSIBLE:
                raise InputError(_sb10ad_refusal(got))
            # SB10AD's own rank test (INFO 3, 4) passes D12 / D21 that are zero up to
            # rounding (a plant zero exactly at z = -1), and then no gamma is admissible
            info = _singular_feedthrough(A, B, C, D, Dc, nw, nz)
            if info:
                raise InputError(_sb10ad_refusal(info))
            raise InputError(
                "P: H-inf Riccati synthesis (SLICOT SB10AD): expected a plant stabilizable "
                "from u and detectable from v, got no admissible controller up to gamma = "
                f"{start / 10:.3g} (INFO = {got})"
            )
        opt = run(start, 1)  # bisection down from the admissible start
        gamma_opt = float(opt[0] if isinstance(opt, tuple) else got[0])
        if gamma_max is not None and gamma_opt > gamma_max:
            raise InputError(
                f"P: H-inf Riccati: expected gamma <= gamma_max = {gamma_max:g}, got optimal "
                f"gamma = {gamma_opt:.6g}"
            )
        found, why = None, "SB10AD found no controller at those gammas"
        for bo in [b for b in (backoff, 1e-2, 5e-2, 0.2) if b >= backoff]:
            res = run(gamma_opt * (1.0 + bo), 4)
            if isinstance(res, int):
                why = f"SB10AD INFO = {res} at gamma_opt (1 + {bo:g})"
                continue
            try:
                AK, BK, CK, DK = _undo_d22(*(np.asarray(x, float) for x in res[1:5]), D22)
            except np.linalg.LinAlgError:
                why = (
                    "I + DK D22 singular: the central controller's gain is infinite at Nyquist "
                    "in the true loop (typical of a design without a weight on u: add a constant "
                    "W2 on K S)"
                )
                continue
            try:
                AK, BK, CK, DK = _tustin(AK, BK, CK, DK, dt)
            except InputError:
                why = "a controller pole at s = 2/dt (no Tustin image)"
                continue
            if _closed_loop_stable(A, B, C, D, nw, nz, AK, BK, CK, DK):
                found = (AK, BK, CK, DK, gamma_opt * (1.0 + bo), bo)
                break
            why = "the discrete closed loop is unstable (in floating point)"
        if found is None:
            raise InputError(
                "P: H-inf Riccati synthesis (SLICOT SB10AD): expected a well-posed stable loop "
                f"with the central controller at gamma = gamma_opt (1 + backoff) up to backoff "
                f"0.2, got {why} (gamma_opt = {gamma_opt:.6g}); method='lmi' may still succeed"
            )
    AK, BK, CK, DK, gamma, bo = found
    status = "optimal" if bo == backoff else f"backoff {bo:g}"
    K = StateSpaceController(
        AK, BK, CK, DK, fs=1.0 / dt, input_names=tuple(input_names),
        output_names=tuple(output_names),
    )  # fmt: skip
    rep = HinfReport(
        gamma=float(gamma),
        gamma_opt=gamma_opt,
        solver="slycot.sb10ad",
        status=status,
        time_s=time.perf_counter() - t0,
        method="riccati",
    )
    return K, rep


def _closed_loop_stable(A, B, C, D, nw, nz, AK, BK, CK, DK) -> bool:
    """Spectral radius < 1 of the discrete loop of P (with its D22) and K (u = K v)."""
    B2, C2, D22 = B[:, nw:], C[nz:], D[nz:, nw:]
    M = np.eye(B2.shape[1]) - DK @ D22  # u = CK xk + DK (C2 x + D22 u)  =>  u = M^-1 (...)
    if np.linalg.cond(M) > 1e12:
        return False
    Mi = np.linalg.inv(M)
    Acl = np.block(
        [
            [A + B2 @ Mi @ DK @ C2, B2 @ Mi @ CK],
            [BK @ (C2 + D22 @ Mi @ DK @ C2), AK + BK @ D22 @ Mi @ CK],
        ]
    )
    if not np.all(np.isfinite(Acl)):
        return False
    return bool(np.max(np.abs(np.linalg.eigvals(Acl))) < 1.0)


def hinf_lmi(
    P,
    n_meas: int,
    n_ctrl: int,
    *,
    gamma_max: float | None = None,
    eps: float = 1e-7,
    backoff: float = 1e-3,
    xy_bounds: tuple[float, ...] = (1e4, 1e3),
    bilinear: bool = False,
    input_names=(),
    output_names=(),
) -> tuple[StateSpaceController, HinfReport]:
    """Gamma-minimal discrete H-infinity output-feedback controller by LMIs.

    Parameters
    ----------
    P : discrete control.StateSpace or LTIModel
        Generalized plant [w; u] -> [z; v]; the last ``n_ctrl`` inputs are u,
        the last ``n_meas`` outputs are v.
    n_meas, n_ctrl : int
        Measurements v (controller inputs) and controls u (controller outputs).
    gamma_max : float, optional
        Refuse (InputError) when the optimal gamma exceeds this.
    eps : float
        Margin for the strict inequalities (LMI >= eps I, scaled problem).
    backoff : float
        Relative gamma backoff of the second pass, which fixes gamma at
        (1 + backoff) gamma_opt and maximizes the coupling margin of X, Y so
        the reconstructed controller is well conditioned.
    xy_bounds : tuple of float
        Bounds on the Lyapunov variables X, Y of the scaled problem (X, Y <= b I),
        tried in turn when the unbounded problem solves only inaccurately.
    bilinear : bool
        Solve the continuous-time LMIs of the bilinear (Tustin) image of P and
        map the controller back (:func:`_inverse_tustin`). The map keeps the
        H-inf norm and stability exactly, so gamma and the controller are
        those of the discrete problem; why: sampled fast (dynamics at
        f << fs, poles near z = 1) the discrete LMIs are ill-conditioned
        (their Lyapunov terms scale like 1 / (1 - |z|)), the continuous ones not.
    input_names, output_names : sequence of str
        Names of the controller's inputs (measurements) and outputs (controls).

    Returns
    -------
    (StateSpaceController, HinfReport)
        Controller v -> u with dt of P; ``report.gamma`` bounds ||T_zw||inf.
    """
    t0 = time.perf_counter()
    A, B, C, D, dt, nw, nz = _check_plant(P, n_meas, n_ctrl)
    n_meas, n_ctrl = int(n_meas), int(n_ctrl)
    solver = _solver()
    # Two diagonal state scalings (A balanced alone; Gramian balanced), the
    # lower certified gamma kept. Why both: neither wins everywhere: a
    # delayed ZOH plant at kHz rates fails outright with the first, a plain
    # double integrator reaches a 30 % lower gamma with it than with the second.
    from scipy.linalg import matrix_balance

    Ps = _inverse_tustin(A, B, C, D, dt) if bilinear else (A, B, C, D)
    scalings = (
        np.diag(matrix_balance(Ps[0], permute=False, separate=False)[1]).copy(),
        _state_scaling(A, B, C),
    )
    D22 = Ps[3][nz:, nw:]
    best, status = None, "not solved"
    for tvec in scalings:  # a diagonal similarity commutes with the bilinear map
        got = _synthesize(
            *Ps, n_meas, n_ctrl, tvec, solver=solver, eps=eps, backoff=backoff,
            xy_bounds=xy_bounds, continuous=bilinear,
        )  # fmt: skip
        if isinstance(got, str):
            status = got
            continue
        if best is None or got[4] < best[4]:
            best = got
    if best is None:
        raise InputError(
            f"P: H-inf LMI infeasible or ill-posed (solver {solver}: {status}): expected a "
            "plant stabilizable from u and detectable from v, no stabilizing controller found"
        )
    AK, BK, CK, DK, gamma, gamma_opt, status = best
    if gamma_max is not None and gamma_opt > gamma_max:
        raise InputError(
            f"P: H-inf LMI: expected gamma <= gamma_max = {gamma_max:g}, got optimal "
            f"gamma = {gamma_opt:.6g}"
        )
    try:
        AK, BK, CK, DK = _undo_d22(AK, BK, CK, DK, D22)
    except np.linalg.LinAlgError as exc:
        raise InputError(
            "P: H-inf LMI: expected a well-posed loop with the controller found, got I + DK D22 "
            "singular (its gain is infinite where the plant's D22 closes the loop)"
        ) from exc
    if bilinear:
        AK, BK, CK, DK = _tustin(AK, BK, CK, DK, dt)
    K = StateSpaceController(
        AK, BK, CK, DK, fs=1.0 / dt, input_names=tuple(input_names),
        output_names=tuple(output_names),
    )  # fmt: skip
    rep = HinfReport(
        gamma=gamma,
        gamma_opt=gamma_opt,
        solver=solver,
        status=status,
        time_s=time.perf_counter() - t0,
    )
    return K, rep


def _synthesize(
    A, B, C, D, n_meas, n_ctrl, tvec, *, solver, eps, backoff, xy_bounds, continuous=False,
    z_gain=1.0, renormalize=True,
):  # fmt: skip
    """One LMI synthesis with the state scaling ``x = diag(tvec) x_s``.

    ``continuous``: (A, B, C, D) is a continuous plant (the bilinear image of
    the discrete one) and the continuous bounded real lemma is used; the
    change of variables and the reconstruction are the same in both domains.
    ``z_gain`` divides z further; with ``renormalize``, a first gamma far from 1
    (scaled problem) makes it solve again with z divided by that gamma (why:
    eps and the solver tolerances are absolute, a scaled gamma of 1e-3 loses them).

    Returns (AK, BK, CK, DK, gamma, gamma_opt, status) of the controller for
    D22 = 0 (ports unscaled), or the last solver status (str) when no
    stabilizing controller came out.
    """
    import cvxpy as cp

    A0, B0, C0, D0 = A, B, C, D
    n = A.shape[0]
    nw, nz = B.shape[1] - n_ctrl, C.shape[0] - n_meas
    B1, B2 = B[:, :nw], B[:, nw:]
    C1, C2 = C[:nz], C[nz:]
    D11, D12, D21 = D[:nz, :nw], D[:nz, nw:], D[nz:, :nw]
    # Scaling (why: a ZOH plant at kHz rates has B ~ 1/fs^2; interior-point
    # solvers then lose digits). States: tvec; u, v: unit column / row norms
    # of [B2; D12] and [C2, D21]. Undone on the controller.
    T = np.diag(tvec)
    Ti = np.diag(1.0 / tvec)
    A, B1, B2, C1, C2 = Ti @ A @ T, Ti @ B1, Ti @ B2, C1 @ T, C2 @ T
    su = 1.0 / np.maximum(np.linalg.norm(np.vstack([B2, D12]), axis=0), 1e-300)
    sv = 1.0 / np.maximum(np.linalg.norm(np.hstack([C2, D21]), axis=1), 1e-300)
    B2, D12 = B2 * su, D12 * su
    C2, D21 = sv[:, None] * C2, sv[:, None] * D21
    sw = max(np.abs(np.block([[B1], [D11], [D21]])).max(), 1e-300)  # w, z scale: gamma unchanged
    sz = max(np.abs(np.block([[C1, D11, D12]])).max(), 1e-300) * z_gain
    B1, D11, D21 = B1 / sw, D11 / (sw * sz), D21 / sw
    C1, D12 = C1 / sz, D12 / sz
    gscale = 1.0 / (sw * sz)  # true gamma = gamma_scaled / gscale

    ny, nu = n_meas, n_ctrl
    X = cp.Variable((n, n), symmetric=True)
    Y = cp.Variable((n, n), symmetric=True)
    Ah = cp.Variable((n, n))
    Bh = cp.Variable((n, ny))
    Ch = cp.Variable((nu, n))
    Dh = cp.Variable((nu, ny))
    g = cp.Variable()
    In, Iw, Iz = np.eye(n), np.eye(nw), np.eye(nz)
    M11 = cp.bmat([[X, In], [In, Y]])
    M12 = cp.bmat([[A @ X + B2 @ Ch, A + B2 @ Dh @ C2], [Ah, Y @ A + Bh @ C2]])
    Bc = cp.bmat([[B1 + B2 @ Dh @ D21], [Y @ B1 + Bh @ D21]])
    Cc = cp.bmat([[C1 @ X + D12 @ Ch, C1 + D12 @ Dh @ C2]])
    Dc = D11 + D12 @ Dh @ D21
    Z2n_w, Z2n_z = np.zeros((2 * n, nw)), np.zeros((2 * n, nz))
    if continuous:  # -[[Acal + Acal', Bcal, Ccal'], [*, -g I, Dcal'], [*, *, -g I]] > 0, M11 > 0
        big = cp.bmat(
            [
                [-(M12 + M12.T), -Bc, -Cc.T],
                [-Bc.T, g * Iw, -Dc.T],
                [-Cc, -Dc, g * Iz],
            ]
        )
    else:
        big = cp.bmat(
            [
                [M11, M12, Bc, Z2n_z],
                [M12.T, M11, Z2n_w, Cc.T],
                [Bc.T, Z2n_w.T, g * Iw, Dc.T],
                [Z2n_z.T, Cc, Dc, g * Iz],
            ]
        )
    m = big.shape[0]
    sym = 0.5 * (big + big.T)  # symmetric by construction; cvxpy wants it explicit
    t = cp.Variable()
    # Attempts: X, Y free first, then bounded (why: singular problems, D12 or
    # D21 rank deficient as in a W1-only design, have X, Y unbounded at the
    # optimum and the solver reports an inaccurate solution; a bound costs a
    # little gamma and keeps the reconstruction well conditioned).
    # Each attempt has two passes. Pass 1 minimizes gamma. Pass 2 fixes gamma
    # slightly above that optimum and maximizes the coupling margin t
    # ([X, I; I, Y] >= t I, so I - X Y is far from singular): a gamma-optimal
    # solution is degenerate and its controller can even destabilize the loop
    # in floating point. Each candidate is checked (closed-loop spectral
    # radius < 1); the backoff grows until one passes.
    found, status = False, "not solved"
    for bound in (None, *xy_bounds):
        base = [sym >> eps * np.eye(m)]
        if continuous:
            base.append(M11 >> eps * np.eye(2 * n))
        if bound is not None:
            base += [X << bound * In, Y << bound * In]
        status = _solve(cp.Problem(cp.Minimize(g), base), solver)
        if status not in ("optimal", "optimal_inaccurate") or g.value is None:
            continue
        if status != "optimal" and bound != xy_bounds[-1]:
            continue
        g1 = float(g.value)
        gamma_opt = g1 / gscale
        if renormalize and not 0.1 < g1 < 10.0:
            return _synthesize(
                A0, B0, C0, D0, n_meas, n_ctrl, tvec, solver=solver, eps=eps, backoff=backoff,
                xy_bounds=xy_bounds, continuous=continuous, z_gain=z_gain * g1, renormalize=False,
            )  # fmt: skip
        if bound is None:  # pass 2 needs bounded X, Y for a finite t
            bound = 100.0 * max(1.0, float(np.abs(X.value).max()), float(np.abs(Y.value).max()))
            base += [X << bound * In, Y << bound * In]
        for bo in (backoff, 1e-2, 5e-2, 0.2):
            g_fix = g1 * (1.0 + bo) + 1e-9
            prob2 = cp.Problem(
                cp.Maximize(t), [g == g_fix, *base, M11 >> t * np.eye(2 * n), t <= 1.0]
            )
            status = _solve(prob2, solver)
            if status not in ("optimal", "optimal_inaccurate") or X.value is None:
                continue
            Xv, Yv = 0.5 * (X.value + X.value.T), 0.5 * (Y.value + Y.value.T)
            # Reconstruction with N = I, M = I - X Y (M N^T = I - X Y).
            Mt = In - Yv @ Xv  # M^T
            Mti = np.linalg.inv(Mt)
            DK = Dh.value
            CK = (Ch.value - DK @ C2 @ Xv) @ Mti
            BK = Bh.value - Yv @ B2 @ DK
            AK = (Ah.value - BK @ C2 @ Xv - Yv @ B2 @ CK @ Mt - Yv @ (A + B2 @ DK @ C2) @ Xv) @ Mti
            Acl = np.block([[A + B2 @ DK @ C2, B2 @ CK], [BK @ C2, AK]])
            ev = np.linalg.eigvals(Acl) if np.all(np.isfinite(Acl)) else np.array([np.inf])
            if np.max(ev.real) < 0.0 if continuous else np.max(np.abs(ev)) < 1.0:
                found = True
                break
        if found:
            break
    if not found:
        return status
    # Undo the u / v scaling (state scaling of P does not touch K's ports).
    BK, CK, DK = BK * sv[None, :], su[:, None] * CK, su[:, None] * DK * sv[None, :]
    return AK, BK, CK, DK, g_fix / gscale, gamma_opt, status


def weight(low_gain: float, crossover_hz: float, high_gain: float, fs: float):
    """First-order weight with |W| = low_gain at DC, 1 at crossover_hz, high_gain at Nyquist.

    W(s) = (s / M + wc) / (s + wc A) with 1/A = low_gain, 1/M = high_gain (the
    usual performance weight for S when low > 1 > high, a roll-off weight for
    T or K S when low < 1 < high), crossing 1 near ``crossover_hz``;
    discretized by Tustin with prewarping at the crossover, so the discrete
    weight has exactly the continuous gain at DC and at ``crossover_hz`` and
    ``high_gain`` at Nyquist.

    Returns
    -------
    control.StateSpace
        SISO, discrete, dt = 1/fs.
    """
    import control

    vals = (low_gain, crossover_hz, high_gain, fs)
    if not all(np.isfinite(v) and v > 0 for v in vals):
        raise InputError(
            f"weight: expected low_gain, crossover_hz, high_gain, fs all > 0, got {vals}"
        )
    if not crossover_hz < fs / 2:
        raise InputError(f"weight: expected crossover_hz < fs/2 = {fs / 2:g}, got {crossover_hz}")
    if (low_gain - 1.0) * (high_gain - 1.0) >= 0:
        raise InputError(
            "weight: expected low_gain and high_gain on opposite sides of 1 (a crossover), "
            f"got {low_gain:g}, {high_gain:g}"
        )
    A_, M_ = 1.0 / low_gain, 1.0 / high_gain
    # |W(j wc')| = 1 fixes the corner: (wc'^2/M^2 + wc^2) = (wc'^2 + wc^2 A^2) with wc' = 2 pi fc.
    wcp = 2 * np.pi * crossover_hz
    wc = wcp * np.sqrt((1 - 1 / M_**2) / (1 - A_**2))
    Wc = control.tf([1.0 / M_, wc], [1.0, wc * A_])
    Wd = control.sample_system(Wc, 1.0 / fs, method="tustin", prewarp_frequency=wcp)
    return control.ss(Wd)


def mixed_sensitivity(G, W1=None, W2=None, W3=None, *, pole_shift: float = 1e-3):
    """Generalized plant for min || [W1 S; W2 K S; W3 T] ||inf of the loop e -> u -> y.

    Loop (spec 5 sign): e = r - y, u = K e, y = G u; S = (I + G K)^-1, T = G K S.
    The plant P has inputs [w (= r, n_y); u (n_u)] and outputs
    [z1 = W1 e; z2 = W2 u; z3 = W3 y; v = e], built with ``control.augw``.

    Parameters
    ----------
    G : discrete control.StateSpace or LTIModel, u (n_u) -> y (n_y)
    W1, W2, W3 : discrete control.StateSpace or None
        Weights on S, K S and T (SISO weights are repeated on the diagonal).
    pole_shift : float
        Plant poles with |z| > 1 - pole_shift (integrators, rigid-body modes)
        are moved inward: A_G -> (1 - pole_shift) A_G for the synthesis (see
        the module doc). 0 disables it.

    Returns
    -------
    (P, n_meas, n_ctrl, rho)
        P a discrete control.StateSpace; rho the factor applied to A_G (1.0 if none).
    """
    import control

    A, B, C, D, dt = _discrete(G, "G")
    if W1 is None and W2 is None and W3 is None:
        raise InputError("mixed_sensitivity: expected at least one weight W1, W2 or W3, got none")
    if not 0 <= pole_shift < 0.5:
        raise InputError(f"pole_shift: expected 0 <= pole_shift < 0.5, got {pole_shift}")
    rho = 1.0
    if pole_shift > 0 and A.size and np.max(np.abs(np.linalg.eigvals(A))) > 1 - pole_shift:
        rho = 1.0 - pole_shift
    Gs = control.ss(rho * A, B, C, D, dt)
    ny, nu = C.shape[0], B.shape[1]
    ws = []
    for name, W, dim in (("W1", W1, ny), ("W2", W2, nu), ("W3", W3, ny)):
        if W is None:
            ws.append(None)
            continue
        Wa, Wb, Wc_, Wd, wdt = _discrete(W, name)
        if not np.isclose(wdt, dt, rtol=1e-9):
            raise InputError(f"{name}: expected dt = {dt:g} s (the plant's), got {wdt:g}")
        if np.any(np.abs(np.linalg.eigvals(Wa)) >= 1.0) if Wa.size else False:
            raise InputError(f"{name}: expected a stable weight (poles inside |z| < 1)")
        Wss = control.ss(Wa, Wb, Wc_, Wd, dt)
        if Wss.ninputs == 1 and Wss.noutputs == 1 and dim > 1:
            Wss = control.append(*([Wss] * dim))
        if Wss.ninputs != dim:
            raise InputError(f"{name}: expected {dim} inputs, got {Wss.ninputs}")
        ws.append(Wss)
    with warnings.catch_warnings():  # augw uses control.connect (deprecated, still exact)
        warnings.filterwarnings("ignore", message=".*connect.*", category=FutureWarning)
        P = control.augw(Gs, *ws)
    return control.ss(P), ny, nu, rho


def design_hinf_mixed(
    G,
    W1=None,
    W2=None,
    W3=None,
    *,
    pole_shift: float = 1e-3,
    gamma_max: float | None = None,
    method: str = "riccati",
    bilinear: bool = False,
) -> tuple[StateSpaceController, HinfReport]:
    """Mixed-sensitivity H-inf controller e -> u for G (dt = 1/fs of G), see mixed_sensitivity.

    ``method``: "riccati" (:func:`hinf_riccati`, default) or "lmi"
    (:func:`hinf_lmi`; ``bilinear`` is its option, the Riccati path is always
    bilinear). The controller is named after G's outputs (inputs) and inputs
    (outputs). ``report.pole_shift`` is the shift actually applied (0 when G
    has no pole near the unit circle); the true loop's stability is the
    caller's to check.
    """
    import dataclasses

    if method not in _METHODS:
        raise InputError(f"method: expected one of {', '.join(_METHODS)}, got {method!r}")
    if bilinear and method != "lmi":
        raise InputError("bilinear: an option of method='lmi' (riccati is always bilinear), "
                         f"got bilinear=True with method={method!r}")  # fmt: skip
    P, n_meas, n_ctrl, rho = mixed_sensitivity(G, W1, W2, W3, pole_shift=pole_shift)
    names = {}
    for key, attrs in (("input_names", ("output_labels", "output_names")),
                       ("output_names", ("input_labels", "input_names"))):  # fmt: skip
        for a in attrs:
            if getattr(G, a, None):
                names[key] = tuple(getattr(G, a))
                break
    if method == "riccati":
        K, rep = hinf_riccati(P, n_meas, n_ctrl, gamma_max=gamma_max, **names)
    else:
        K, rep = hinf_lmi(P, n_meas, n_ctrl, gamma_max=gamma_max, bilinear=bilinear, **names)
    return K, dataclasses.replace(rep, pole_shift=1.0 - rho)


def hinf_norm_grid(sys, n: int = 20000) -> float:
    """||sys||inf of a discrete system on a dense grid of n lines 0..Nyquist (max singular value).

    A lower bound of the true norm (exact up to the grid); inf when unstable.
    """
    A, B, C, D, dt = _discrete(sys, "sys")
    if A.size and np.max(np.abs(np.linalg.eigvals(A))) >= 1.0:
        return float("inf")
    w = np.linspace(0.0, np.pi, int(n))
    z = np.exp(1j * w)
    In = np.eye(A.shape[0])
    best = 0.0
    for zk in z:
        H = D + (C @ np.linalg.solve(zk * In - A, B) if A.size else 0.0)
        best = max(best, float(np.linalg.norm(H, 2)))
    return best


# ------------------------------------------------------------------ the stage design
#: tune_hinf's weights, relative to the scanned target fb (Hz): W1 = weight(_W1_LOW,
#: fb, 1 / ms_max) on S, W2 = _W2 on K S (normalized plant, |G(fb)| = 1: keeps D12
#: full rank), W3 = weight(1 / ms_max, _W3_RATIO fb, _W3_HIGH) on T (roll-off), rigid
#: poles shifted to a corner fb / _SHIFT_RATIO. Chosen with the LMI synthesis on the
#: wafer stage's x channel (a 1-sample-delayed double integrator with two lightly damped
#: modes): W1's low gain 30 (with corner fb / 30) reached a third of the crossover of 10
#: (with fb / 10) because the LMI solution degrades with the wider time-scale spread at
#: 5 kHz. The Riccati synthesis reaches the optimum there (gamma ~40 % below the LMI's on
#: the stage's channels); the weights were not re-tuned for it.
_W1_LOW, _W2, _W3_RATIO, _W3_HIGH, _SHIFT_RATIO = 10.0, 1e-2, 2.0, 100.0, 10.0


@dataclass(frozen=True)
class HinfDesign:
    """Result of :func:`tune_hinf`.

    Attributes
    ----------
    controller : StateSpaceController
        Block-diagonal e -> u (one SISO H-inf controller per DOF), dt = 1/fs.
    target_hz : tuple of float
        Per DOF, the W1 crossing (design target) kept, Hz.
    crossover_hz : tuple of float
        Per DOF, the crossover of the SISO channel loop on the model, Hz.
    gamma : tuple of float
        Per DOF, the certified ||[W1 S; W2 K S; W3 T]||inf of the kept design.
    analysis : workbench.loop.LoopAnalysis
        The MIMO loop on the model (loop-at-a-time figures, all loops closed).
    scanned : tuple of dict
        Every synthesis tried, in order: dof, target_hz, gamma, crossover_hz,
        s_peak, stable, kept (or an ``error`` message when the synthesis failed).
    """

    controller: StateSpaceController
    target_hz: tuple[float, ...]
    crossover_hz: tuple[float, ...]
    gamma: tuple[float, ...]
    analysis: object
    scanned: tuple = ()


def channel_plant(modal, i: int, fs: float, loop_delay_samples: int = 0):
    """The discrete SISO plant u_i -> y_i of a modal model, with its delay and the loop's.

    Only the modes that show on the channel (``|b_k[i] c_k[i]| > 1e-9`` of the
    largest) are kept: the others are uncontrollable or unobservable from it,
    and a synthesis on them is ill-posed. Exact ZOH at fs (workbench.loop.discrete_plant).
    """
    import dataclasses

    from workbench import loop
    from workbench.core.model import LTIModel

    res = np.array([abs(md.b[i] * md.c[i]) for md in modal.modes])
    if not res.size or res.max() <= 0:
        raise InputError(f"channel {i}: expected a mode that input {i} moves and output {i} sees")
    keep = tuple(
        dataclasses.replace(md, b=md.b[[i]], c=md.c[[i]])
        for md, r in zip(modal.modes, res)
        if r > 1e-9 * res.max()
    )
    sub = dataclasses.replace(
        modal, modes=keep, D=modal.D[[i]][:, [i]], transform=None,
        input_names=modal.input_names[i : i + 1], output_names=modal.output_names[i : i + 1],
    )  # fmt: skip
    sys = LTIModel.from_statespace(sub.to_statespace(form="scaled"), delay_s=sub.delay_s)
    return loop.discrete_plant(sys, fs, loop_delay_samples)


def _channel_problem(G, fb: float, fs: float, ms_max: float):
    """tune_hinf's mixed-sensitivity problem at target fb: (g0, G g0, W1, W2, W3, pole_shift).

    The plant is normalized to |G(fb)| = 1 (its controller is the returned one times g0).
    """
    import control

    from workbench.core.lti import frf

    g0 = 1.0 / abs(frf(G, [fb])[0, 0, 0])
    W1 = weight(_W1_LOW, fb, 1.0 / ms_max, fs)
    W2 = control.ss([], [], [], [[_W2]], 1.0 / fs)
    W3 = weight(1.0 / ms_max, _W3_RATIO * fb, _W3_HIGH, fs) if _W3_RATIO * fb < fs / 2 else None
    shift = min(2 * np.pi * fb / _SHIFT_RATIO / fs, 0.4)
    return g0, G * g0, W1, W2, W3, shift


def _siso_candidate(G, fb: float, fs: float, ms_max: float, f, method: str = "riccati"):
    """(controller StateSpace, gamma, crossover Hz, |S|inf, stable) of one target fb on G."""
    import control

    from workbench import loop
    from workbench.core.lti import frf

    g0, Gn, W1, W2, W3, shift = _channel_problem(G, fb, fs, ms_max)
    K, rep = design_hinf_mixed(Gn, W1, W2, W3, pole_shift=shift, method=method)
    Ks = K.statespace() * g0
    Acl = control.feedback(G * Ks).A
    stable = bool(np.max(np.abs(np.linalg.eigvals(Acl))) < 1.0) if Acl.size else True
    L = frf(G, f)[:, 0, 0] * frf(Ks, f)[:, 0, 0]
    fc = loop._first_crossing(f, np.abs(L), 1.0, rising=False)
    return Ks, float(rep.gamma), fc, float(np.max(np.abs(1.0 / (1.0 + L)))), stable


def tune_hinf(
    model,
    *,
    ms_max: float = 2.0,
    loop_delay_samples: int = 0,
    fs: float | None = None,
    progress=None,
    n_scan: int = 9,
    target_range=(0.002, 0.12),
    refine: int = 2,
    method: str = "riccati",
    blas_threads: int | None = 1,
) -> HinfDesign:
    """Per-DOF mixed-sensitivity H-inf design for the highest crossover at |S| <= ms_max.

    Structure (why): the stage's DOFs are decoupled by its gain-balancing and
    sensor matrices, so each diagonal channel u_i -> y_i (:func:`channel_plant`,
    the modes it shows, its delay and the loop's) gets its own SISO design
    (a generalized plant of order ~10 instead of ~30 for the 6x6 model: the
    LMI has ~ 2 n^2 unknowns, and a decentralized controller of low order) and
    the result is the block-diagonal controller, checked on the full MIMO
    model at the end.

    Per DOF, targets fb log-spaced over ``target_range`` (fractions of fs)
    are tried from the highest down, and the first kept design is taken (why
    downward: the crossover grows with the target until |S| breaks the bound,
    so the stage's DOFs need a few syntheses; ~20 ms each by Riccati, seconds
    by LMI)
    (weights: module constants ``_W1_LOW`` ..., the plant normalized
    to |G(fb)| = 1, rigid poles shifted for the synthesis only); a design is
    kept when the true (unshifted) channel loop is stable with
    max |S| <= ms_max. Then
    :func:`workbench.loop.analyze_loop` on the model: while a loop's |S_ii|
    (all loops closed) exceeds ms_max or the MIMO loop is unstable, the
    offending DOFs step down to their next lower kept design.

    Parameters
    ----------
    model : LTIModel, control.StateSpace or ModalModel
        Square plant u -> y (continuous, or discrete with dt = 1/fs), its ``delay_s`` kept.
    ms_max : float
        Bound on |S_ii| per loop (ratio, > 1; 2.0 = 6 dB).
    loop_delay_samples : int
        Computation delay of the real-time loop, samples (in the plant, not in K).
    fs : float, optional
        Controller rate, Hz (default: 1/dt of a discrete model; required otherwise).
    progress : callable(i, n), optional
        Called after each synthesis: i done of at most n (the scan stops early).
    n_scan : int
        Targets tried per DOF.
    target_range : (float, float)
        Lowest and highest target, fractions of fs.
    refine : int
        Geometric bisections between the first kept target and the rejected one above.
    method : str
        The synthesis: "riccati" (:func:`hinf_riccati`, milliseconds each) or
        "lmi" (:func:`hinf_lmi`, seconds each; on the stage's channels its gamma
        is above the optimum, so it keeps lower targets).
    blas_threads : int or None
        BLAS threads for the whole tuning (:func:`workbench.core.blas.limited_blas`).

    Returns
    -------
    HinfDesign

    Raises
    ------
    InputError
        A non-square model, a DOF where no target gives a stable design with
        |S| <= ms_max (e.g. ms_max too close to 1), or no MIMO combination
        meeting the bound.
    """
    from workbench.core.blas import limited_blas

    if method not in _METHODS:
        raise InputError(f"method: expected one of {', '.join(_METHODS)}, got {method!r}")
    with limited_blas(blas_threads):
        return _tune_hinf(
            model, ms_max=ms_max, loop_delay_samples=loop_delay_samples, fs=fs,
            progress=progress, n_scan=n_scan, target_range=target_range, refine=refine,
            method=method,
        )  # fmt: skip


def _tune_hinf(
    model, *, ms_max, loop_delay_samples, fs, progress, n_scan, target_range, refine, method
) -> HinfDesign:
    """:func:`tune_hinf` inside its BLAS limit."""
    import scipy.linalg

    from workbench import loop
    from workbench.core.model import as_model
    from workbench.modal.model import ModalModel

    ms_max = float(ms_max)
    if not np.isfinite(ms_max) or ms_max <= 1.0:
        raise InputError(f"ms_max: expected a bound > 1 on |S|, got {ms_max}")
    m = loop._delay_check(loop_delay_samples)
    if isinstance(model, ModalModel):
        if model.has_outer:
            raise InputError("model: expected a modal model without lags or coupling terms")
        modal = model
        plant = model.to_lti()
        plant = as_model(plant)
    else:
        plant = as_model(model)
        modal = ModalModel.from_statespace(plant)
    if plant.n_u != plant.n_y or plant.n_u == 0:
        raise InputError(
            f"model: expected a square model (one actuator per measured output), got "
            f"{plant.n_u} inputs and {plant.n_y} outputs"
        )
    if plant.is_discrete:
        own = 1.0 / plant.dt
        if fs is not None and abs(float(fs) - own) > 1e-9 * own:
            raise InputError(f"fs: expected the discrete model's rate {own:g} Hz, got {fs:g}")
        fs = own
    elif fs is None or not np.isfinite(fs) or fs <= 0:
        raise InputError(
            f"fs: expected a sampling frequency > 0 Hz for a continuous model, got {fs}"
        )
    fs = float(fs)
    lo, hi = (float(x) for x in target_range)
    if not 0 < lo < hi < 0.25:
        raise InputError(
            f"target_range: expected 0 < low < high < 0.25 (of fs), got {target_range}"
        )
    say = progress or (lambda _i, _n: None)
    names = list(loop._names(plant, "output")) or [f"y{i}" for i in range(plant.n_y)]
    f = loop._default_grid(fs)
    targets = np.geomspace(lo * fs, hi * fs, int(n_scan))

    def candidate(G, i, fb):
        """(fc, fb, gamma, K) when the design at target fb is kept, else None; recorded."""
        tried[0] += 1
        try:
            Ks, gam, fc, s_peak, stable = _siso_candidate(G, fb, fs, ms_max, f, method)
        except InputError as exc:
            scanned.append({"dof": names[i], "target_hz": float(fb), "error": str(exc)})
            say(tried[0], n_total)
            return None
        good = bool(stable and s_peak <= ms_max and np.isfinite(fc))
        scanned.append(
            {"dof": names[i], "target_hz": float(fb), "gamma": gam, "crossover_hz": fc,
             "s_peak": s_peak, "stable": stable, "kept": good}
        )  # fmt: skip
        say(tried[0], n_total)
        return (fc, fb, gam, Ks) if good else None

    def designs(i):
        """DOF i's kept designs (fc, fb, gamma, K), from the highest target down, lazily.

        The first kept one is refined by ``refine`` geometric bisections towards the
        rejected target above it (the grid is coarse, a step of ~1.7 in target), the
        highest crossover of those kept comes first.
        """
        G = channel_plant(modal, i, fs, m)
        above = None
        for fb in targets[::-1]:
            got = candidate(G, i, fb)
            if got is None:
                above = fb
                continue
            if above is not None:
                lo, hi, best = fb, above, got
                for _ in range(int(refine)):
                    mid = float(np.sqrt(lo * hi))
                    trial = candidate(G, i, mid)
                    if trial is None:
                        hi = mid
                    else:
                        lo = mid
                        best = max(best, trial, key=lambda t: t[0])
                if best is not got:
                    yield best
                above = None
            yield got

    tried, scanned, n_total = [0], [], plant.n_u * (len(targets) + int(refine))
    gens = [designs(i) for i in range(plant.n_u)]
    chosen = []
    for i, gen in enumerate(gens):
        first = next(gen, None)
        if first is None:
            raise InputError(
                f"hinf: DOF {names[i]}: no stable design meets |S| <= {ms_max:g} on the model "
                f"(targets {targets[0]:.3g}..{targets[-1]:.3g} Hz)"
            )
        chosen.append(first)
    while True:
        mats = [(Ks.A, Ks.B, Ks.C, Ks.D) for _fc, _fb, _g, Ks in chosen]
        K = StateSpaceController(
            scipy.linalg.block_diag(*[a[0] for a in mats]),
            scipy.linalg.block_diag(*[a[1] for a in mats]),
            scipy.linalg.block_diag(*[a[2] for a in mats]),
            scipy.linalg.block_diag(*[a[3] for a in mats]),
            fs=fs, input_names=tuple(plant.output_names), output_names=tuple(plant.input_names),
            delay_samples=m,
        )  # fmt: skip
        analysis = loop.analyze_loop(plant, K, loop_delay_samples=m)
        over = [i for i, lp in enumerate(analysis.loops) if lp.s_peak > ms_max * (1 + 1e-9)]
        if analysis.stable and not over:
            break
        step = over if over else list(range(plant.n_u))  # unstable: every DOF steps down
        for i in step:
            nxt = next(gens[i], None)
            if nxt is None:
                raise InputError(
                    f"hinf: no combination of the per-DOF designs meets |S| <= {ms_max:g} with "
                    f"all loops closed (stable = {analysis.stable}, loops over the bound: "
                    f"{[names[j] for j in over]})"
                )
            chosen[i] = nxt
    return HinfDesign(
        controller=K,
        target_hz=tuple(float(c[1]) for c in chosen),
        crossover_hz=tuple(float(c[0]) for c in chosen),
        gamma=tuple(float(c[2]) for c in chosen),
        analysis=analysis,
        scanned=tuple(scanned),
    )
