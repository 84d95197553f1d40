"""The one simulator: ZOH with an exact delay, linear and nonlinear paths, the closed loop.

Data flow::

    continuous (A, B) + delay_s --c2d_zoh--> (Ad, B0, B1, m)     x+ = Ad x + B0 u[k-m] + B1 u[k-m-1]
        |                                         |
        |                                   delay_augmented --> discrete (A, B, C, D), input u[k]
        |                                         |
        '--substep_zoh (port nonlinearities)      '--dlsim (lifted blocks, BLAS) --> y (N, n_y)

    closed_loop(plant, controller, r=, d=):  e = r - y,  u = d + u_c[k - delay_samples]
        linear plant and linear controller -> one discrete LTI system driven by [r, d, v] (dlsim)
        linear controller, plant.sampled_step() (quantization, saturation, delay: static
            nonlinearities)                -> one numba kernel (workbench.compiled)
        otherwise                          -> plant.step / controller.step sample by sample

Every simulator of the project calls these functions: ``workbench.core.lti`` re-exports
``c2d_zoh`` and ``simulate_zoh``; ``plants.sim`` builds its substep propagation
with :func:`substep_zoh`; ``workbench.diagnosis.nonlinear`` steps its port model with it too;
``workbench.experiments`` runs its closed loops through :func:`closed_loop`.

Sampling convention (spec 1a): ``u[k]`` is held over [k/fs, (k+1)/fs), ``y[k]`` is
sampled at k/fs; arrays are (N, n_channels).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any, Literal

import numpy as np
import scipy.linalg

from workbench.core.errors import InputError
from workbench.core.lti import as_matrices

__all__ = [
    "phi_gamma",
    "split_delay",
    "c2d_zoh",
    "delayed",
    "delay_augmented",
    "discretize",
    "dlsim",
    "simulate_zoh",
    "phi_gamma_foh",
    "PortLaw",
    "SubstepZoh",
    "PortSensitivity",
    "substep_zoh",
    "closed_loop_matrices",
    "closed_loop",
    "is_linear_additive",
]

#: Block length of the lifted recursion in :func:`dlsim` (16-32 is fastest on the stage loop).
_LIFT = 16


# ------------------------------------------------------------------ discretization
def phi_gamma(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A h}, int_0^h e^{A s} ds B) by one matrix exponential (Van Loan).

    Parameters
    ----------
    A : (n, n) array
    B : (n, n_u) array
    h : float
        Interval, s (>= 0).
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * h
    M[:n, n:] = B * h
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n:]


def split_delay(delay_s: float, dt: float) -> tuple[int, float]:
    """``delay_s = m dt + tau`` with integer m >= 0 and 0 <= tau < dt (tau < 1e-12 dt is 0)."""
    if not np.isfinite(delay_s) or delay_s < 0:
        raise InputError(f"delay_s: expected a finite delay >= 0 s, got {delay_s}")
    m = int(np.floor(delay_s / dt + 1e-12))
    tau = delay_s - m * dt
    if tau < 1e-12 * dt:
        tau = 0.0
    return m, tau


def c2d_zoh(A: np.ndarray, B: np.ndarray, dt: float, *, delay_s: float = 0.0):
    """Exact ZOH discretization with an input delay.

    Returns ``(Ad, B0, B1, m)`` such that, for a delay ``delay_s = m dt + tau``
    (0 <= tau < dt), x[k+1] = Ad x[k] + B0 u[k-m] + B1 u[k-m-1].

    Notes
    -----
    Over one sample the delayed input equals u[k-m-1] on [0, tau) and u[k-m] on
    [tau, dt), which gives B1 = e^{A(dt-tau)} int_0^tau e^{As} ds B and
    B0 = int_0^{dt-tau} e^{As} ds B (Franklin, Powell & Workman, Digital
    Control of Dynamic Systems, 3rd ed., sec. 4.3.4).
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    m, tau = split_delay(delay_s, dt)
    Ad, B0 = phi_gamma(A, B, dt - tau)
    if tau == 0.0:
        return Ad, B0, np.zeros_like(B0), m
    Ptau, Gtau = phi_gamma(A, B, tau)
    return Ad @ Ptau, B0, Ad @ Gtau, m


def delayed(u: np.ndarray, m: int) -> np.ndarray:
    """u[k - m] (zero before the record: at rest), same shape as ``u`` (N, n)."""
    out = np.zeros_like(u)
    if m < u.shape[0]:
        out[m:] = u[: u.shape[0] - m]
    return out


def delay_augmented(Ad, B0, B1, m: int, C, D):
    """One discrete system with input u[k] for the delayed ZOH model of :func:`c2d_zoh`.

    The past inputs d_i = u[k-i], i = 1..m+1, become states after the plant's
    (order: plant states, then d_1, ..., d_{m+1}); y = C x + D u[k-m].

    Returns
    -------
    (A, B, C, D) : arrays of the augmented discrete system.
    """
    n, n_u = np.asarray(B0).shape
    n_y = np.asarray(C).shape[0]
    L = m + 1
    N = n + L * n_u
    Aa = np.zeros((N, N))
    Ba = np.zeros((N, n_u))
    Ca = np.zeros((n_y, N))
    Da = np.zeros((n_y, n_u))
    Aa[:n, :n] = Ad
    Ca[:, :n] = C

    def blk(i):  # columns of d_i
        return slice(n + (i - 1) * n_u, n + i * n_u)

    if m == 0:
        Ba[:n] = B0
        Da[:] = D
    else:
        Aa[:n, blk(m)] = B0
        Ca[:, blk(m)] = D
    Aa[:n, blk(m + 1)] += B1
    Ba[blk(1)] = np.eye(n_u)
    for i in range(2, L + 1):
        Aa[blk(i), blk(i - 1)] = np.eye(n_u)
    return Aa, Ba, Ca, Da


def _model_delay(sys) -> float:
    # an LTIModel carries its delay; a python-control StateSpace has none
    return float(sys.delay_s) if hasattr(sys, "delay_s") else 0.0


def discretize(sys, fs: float, *, delay_s: float | None = None):
    """Discrete (A, B, C, D) at ``fs`` with the input delay as states, input u[k].

    Parameters
    ----------
    sys : control.StateSpace or LTIModel
        Continuous (exact ZOH) or discrete with dt = 1/fs.
    fs : float
        Sampling frequency, Hz.
    delay_s : float, optional
        Input delay, s; default the model's own (``LTIModel.delay_s``, else 0).
        A discrete model takes whole samples only.
    """
    A, B, C, D, dt = as_matrices(sys)
    delay = _model_delay(sys) if delay_s is None else float(delay_s)
    if dt > 0:
        if abs(dt * fs - 1) > 1e-9:
            raise InputError(f"sys: expected a discrete model with dt = {1 / fs:g} s, got {dt:g} s")
        m, tau = split_delay(delay, dt)
        if tau:
            raise InputError(
                f"delay_s: a discrete model takes whole samples, got {delay / dt:g} samples"
            )
        Ad, B0, B1 = A, B, np.zeros_like(B)
    else:
        Ad, B0, B1, m = c2d_zoh(A, B, 1.0 / fs, delay_s=delay)
    return delay_augmented(Ad, B0, B1, m, C, D)


# ------------------------------------------------------------------ linear simulation
def dlsim(A, B, C, D, w: np.ndarray, *, x0=None) -> np.ndarray:
    """Response of x[k+1] = A x[k] + B w[k], y[k] = C x[k] + D w[k] from ``x0`` (default rest).

    Parameters
    ----------
    A, B, C, D : arrays (n, n), (n, n_w), (n_y, n), (n_y, n_w)
    w : (N, n_w) array
    x0 : (n,) array, optional

    Returns
    -------
    (N, n_y) array

    Notes
    -----
    Lifted recursion over blocks of L samples: the state at block starts,
    x_{b+1} = A^L x_b + [A^{L-1} B ... B] w_b, is the only sequential part (N / L
    small matrix-vector products); the outputs inside each block, y_b =
    [C; CA; ...; CA^{L-1}] x_b + T_L w_b (T_L the block-Toeplitz Markov
    parameters), are two matrix products over all blocks at once. Equal to the
    plain recursion to rounding (about 1e-13 relative on the stage's closed
    loop, tested against scipy.signal.dlsim), several times faster for long
    records. Short records (N <= 4 L) run the plain recursion.
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    C = np.asarray(C, float)
    D = np.asarray(D, float)
    w = np.asarray(w, float)
    N, n_w = w.shape
    n = A.shape[0]
    n_y = C.shape[0]
    xk = np.zeros(n) if x0 is None else np.asarray(x0, float).reshape(n)
    y = w @ D.T if np.any(D) else np.zeros((N, n_y))
    if n == 0 or N == 0:
        return y
    L = _LIFT
    if N <= 4 * L:
        drive = w @ B.T
        x = np.empty((N, n))
        for k in range(N):
            x[k] = xk
            xk = A @ xk + drive[k]
        return y + x @ C.T
    nb = -(-N // L)
    W = np.zeros((nb * L, n_w))
    W[:N] = w
    Wb = W.reshape(nb, L * n_w)  # block b: w[bL], ..., w[bL + L - 1]
    P = [np.eye(n)]
    for _ in range(L):
        P.append(A @ P[-1])
    CP = [C @ P[i] for i in range(L)]
    Gam = np.hstack([P[L - 1 - j] @ B for j in range(L)])  # (n, L n_w)
    Obs = np.vstack(CP)  # (L n_y, n)
    H = [C @ np.zeros_like(B)] + [CP[i - 1] @ B for i in range(1, L)]  # Markov parameters
    T = np.zeros((L * n_y, L * n_w))
    for i in range(1, L):
        for j in range(i):
            T[i * n_y : (i + 1) * n_y, j * n_w : (j + 1) * n_w] = H[i - j]
    Z = Wb @ Gam.T
    AL = P[L]
    Xb = np.empty((nb, n))
    for b in range(nb):
        Xb[b] = xk
        xk = AL @ xk + Z[b]
    Yb = Xb @ Obs.T + Wb @ T.T
    return y + Yb.reshape(nb * L, n_y)[:N]


def simulate_zoh(sys, u: np.ndarray, fs: float, *, delay_s: float = 0.0, x0=None) -> np.ndarray:
    """Response of a model to a zero-order-held input, from rest (or ``x0``).

    Parameters
    ----------
    sys : control.StateSpace or workbench.core.model.LTIModel
        Continuous model (discretized exactly with the ZOH at ``fs``) or a
        discrete model whose dt equals 1/fs. An LTIModel's own delay is applied.
    u : (N, n_u) array
        Input samples, held over each sample interval.
    fs : float
        Sampling frequency, Hz.
    delay_s : float
        Input delay added to the model's own, s (any real value >= 0 for a continuous
        model, fractional delays exact; a whole number of samples for a discrete one).
    x0 : (n_x,) array, optional
        Initial state of the model (the delay line starts at rest).

    Returns
    -------
    (N, n_y) array, y[k] sampled at t = k / fs.
    """
    A, B, C, D, dt = as_matrices(sys)
    delay_s = float(delay_s) + float(getattr(sys, "delay_s", 0.0))  # the model's delay travels
    u = np.asarray(u, float)
    if dt > 0:
        if abs(dt * fs - 1) > 1e-9:
            raise InputError(
                f"model: expected a discrete model with dt = {1 / fs:g} s, got dt = {dt:g} s"
            )
        m = int(round(delay_s * fs))
        if abs(delay_s * fs - m) > 1e-6:
            raise InputError(
                f"delay_s: a discrete model delays by whole samples of {dt:g} s, got "
                f"{delay_s:g} s ({delay_s * fs:.4g} samples)"
            )
        Ad, B0, B1 = A, B, np.zeros_like(B)
    else:
        Ad, B0, B1, m = c2d_zoh(A, B, 1.0 / fs, delay_s=delay_s)
    # delayed inputs u[k-m] and u[k-m-1] drive the state; the feedthrough sees
    # u[k-m] only (D u is instantaneous: a fractional delay mixes neighbouring
    # samples in the state, not in D)
    um = delayed(u, m)
    if np.any(B1):
        w = np.hstack([um, delayed(u, m + 1)])
        Bw, Dw = np.hstack([B0, B1]), np.hstack([D, np.zeros_like(D)])
    else:
        w, Bw, Dw = um, B0, D
    return dlsim(Ad, Bw, C, Dw, w, x0=x0)


# ------------------------------------------------------------------ nonlinear ports
def phi_gamma_foh(A: np.ndarray, Bp: np.ndarray, h: float):
    """(e^{A h}, Gamma_0, Gamma_1) of a port force that varies linearly over [0, h].

    ``Gamma_0 = int_0^h e^{A s} ds Bp`` (a force held over the interval) and
    ``Gamma_1 = int_0^h e^{A s} (1 - s / h) ds Bp``, the weight of the force's end value:
    with f(t) = f0 + (f1 - f0) t / h, ``x(h) = e^{A h} x(0) + (Gamma_0 - Gamma_1) f0 +
    Gamma_1 f1``. One matrix exponential of the augmented matrix
    ``[[A h, Bp h, 0], [0, 0, I], [0, 0, 0]]``, whose exponential holds
    ``sum_k (A h)^k Bp h / (k + 1)!`` = Gamma_0 and ``sum_k (A h)^k Bp h / (k + 2)!``
    = Gamma_1 in its first block row (Van Loan).

    Parameters
    ----------
    A : (n, n) array
    Bp : (n, n_p) array
    h : float
        Interval, s (> 0).
    """
    A = np.asarray(A, float)
    Bp = np.asarray(Bp, float)
    n, p = Bp.shape
    M = np.zeros((n + 2 * p, n + 2 * p))
    M[:n, :n] = A * h
    M[:n, n : n + p] = Bp * h
    M[n : n + p, n + p :] = np.eye(p)
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n : n + p], E[:n, n + p :]


@dataclass(frozen=True)
class PortLaw:
    """Port forces of a state: ``F(x) = -F_c tanh(Cv x / v0) - k3 (Cp x)^3``, (n_p,) N.

    Smooth Coulomb friction on the port velocity ``Cv x`` and a hardening spring on
    the port displacement ``Cp x``; 0 in ``friction_force`` / ``cubic_stiffness`` = none.

    Parameters
    ----------
    Cv, Cp : (n_p, n) arrays
        Port velocity (m/s per state) and displacement (m per state).
    friction_force : (n_p,) array
        Coulomb level F_c of each port, N (N m), >= 0.
    friction_velocity : float
        v0 of the smooth law, m/s (rad/s), > 0.
    cubic_stiffness : (n_p,) array
        k3 of each port, N/m^3 (N m/rad^3), >= 0.
    """

    Cv: np.ndarray
    Cp: np.ndarray
    friction_force: np.ndarray
    friction_velocity: float
    cubic_stiffness: np.ndarray

    def __post_init__(self):
        n_p = np.asarray(self.Cv).shape[0]
        for name in ("friction_force", "cubic_stiffness"):
            v = np.broadcast_to(np.asarray(getattr(self, name), float), (n_p,)).copy()
            if not np.all(np.isfinite(v) & (v >= 0)):
                raise InputError(f"PortLaw.{name}: expected {n_p} finite values >= 0, got {v}")
            object.__setattr__(self, name, v)
        if not (np.isfinite(self.friction_velocity) and self.friction_velocity > 0):
            raise InputError(
                f"PortLaw.friction_velocity: expected a velocity > 0 in m/s, "
                f"got {self.friction_velocity!r}"
            )
        object.__setattr__(self, "Cv", np.ascontiguousarray(self.Cv, dtype=float))
        object.__setattr__(self, "Cp", np.ascontiguousarray(self.Cp, dtype=float))

    def force(self, x: np.ndarray) -> np.ndarray:
        """F(x), (n_p,) N, for a state x (n,)."""
        f = -self.friction_force * np.tanh((self.Cv @ x) / self.friction_velocity)
        return f - self.cubic_stiffness * (self.Cp @ x) ** 3


@dataclass(frozen=True)
class SubstepZoh:
    """Propagation over ``n_sub`` substeps of one sample, for port nonlinearities.

    Over substep j the state advances as
    ``x <- Phi x + G_old[j] u[k-m-1] + G_new[j] u[k-m] + (Gp - Gp_end) f0 + Gp_end f1``:
    the linear part exact, the delayed input held and switching exactly at the
    fractional delay, the port force varying linearly from its start value
    f0 = F(x) to its end value f1 = F(x+) (trapezoidal, second order in the
    substep; the friction's end value implicit, solved by a safeguarded Newton
    step, :mod:`workbench._port_kernel`, which says how).

    Parameters
    ----------
    Phi : (n, n) array
    Gp : (n, n_p) array
        Port-force input over one substep, the force held.
    Gp_end : (n, n_p) array
        Weight of the force's end value when it varies linearly (:func:`phi_gamma_foh`).
    G_old, G_new : (n_sub, n, n_u) arrays
    m : int
        Whole samples of the input delay.
    """

    Phi: np.ndarray
    Gp: np.ndarray
    Gp_end: np.ndarray
    G_old: np.ndarray
    G_new: np.ndarray
    m: int

    @property
    def n_sub(self) -> int:
        """Substeps per sample."""
        return int(self.G_new.shape[0])

    @cached_property
    def _kernel_args(self):
        # transposed (the kernel sums column by column: independent running sums)
        c = np.ascontiguousarray
        return (
            c(self.Phi.T),
            c((self.Gp - self.Gp_end).T),
            c(self.Gp_end.T),
            c(self.G_old.transpose(0, 2, 1)),
            c(self.G_new.transpose(0, 2, 1)),
            bool(np.any(self.G_old)),
        )

    def _law_args(self, law: PortLaw):
        c = np.ascontiguousarray
        return (
            c(law.Cv.T),
            c(law.Cp.T),
            law.friction_force,
            float(law.friction_velocity),
            law.cubic_stiffness,
            np.ascontiguousarray(law.Cv @ self.Gp_end),
        )

    def advance(
        self,
        x: np.ndarray,
        u_new: np.ndarray,
        u_old: np.ndarray,
        law: PortLaw,
        *,
        engine: Literal["compiled", "python"] = "compiled",
    ) -> np.ndarray:
        """State after one sample (n,); ``u_new`` = u[k-m], ``u_old`` = u[k-m-1] (n_u,).

        ``engine="python"`` is the NumPy reference of the compiled kernel (same arithmetic).
        """
        x = np.asarray(x, float)
        if engine == "python":
            return _advance_reference(
                self, x, np.asarray(u_new, float), np.asarray(u_old, float), law
            )
        return self.stepper(law)(x, u_new, u_old)

    def stepper(self, law: PortLaw) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
        """``step(x, u_new, u_old)``: :meth:`advance`, compiled, with its matrices prepared once
        (a closed loop steps the plant sample by sample)."""
        from workbench._port_kernel import port_sample

        args = self._kernel_args
        law_args = self._law_args(law)
        c = np.ascontiguousarray

        def step(x, u_new, u_old):
            return port_sample(
                c(x, dtype=float), *args, c(u_new, dtype=float), c(u_old, dtype=float), *law_args
            )

        return step

    def simulate(
        self,
        law: PortLaw,
        um: np.ndarray,
        um1: np.ndarray,
        C: np.ndarray,
        D: np.ndarray,
        *,
        sens: PortSensitivity | None = None,
    ) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Record from rest, compiled: (y, p) with y[k] = C x + D um[k], p[k] = Cp x.

        Parameters
        ----------
        law : PortLaw
        um, um1 : (N, n_u) arrays
            u[k-m] and u[k-m-1], saturated.
        C, D : (n_y, n), (n_y, n_u) arrays
        sens : PortSensitivity, optional
            How the friction law depends on parameters theta (n_th): then also the outputs'
            exact sensitivities, computed forward alongside the simulation (the derivative of
            the simulation as computed, to the Newton tolerance of its friction solve). The
            law must have no cubic spring.

        Returns
        -------
        y : (N, n_y) array
        p : (N, n_p) array
            Port displacements.
        dy : (N, n_y, n_th) array
            With ``sens``: dy / dtheta.
        """
        from workbench._port_kernel import port_record

        c = np.ascontiguousarray
        um = c(um, dtype=float)
        N = um.shape[0]
        n = self.Phi.shape[0]
        n_p = law.Cp.shape[0]
        y = np.empty((N, C.shape[0]))
        p = np.empty((N, n_p))
        if sens is None:
            dFc, dlv, dCvT = np.empty((0, n_p)), np.empty(0), np.empty((0, n, n_p))
            has_dcv = np.empty(0, bool)
        else:
            if np.any(law.cubic_stiffness != 0):
                raise InputError("SubstepZoh.simulate: sensitivities of a cubic spring's record")
            dFc, dlv, dCvT, has_dcv = sens.kernel_args(n, n_p)
        dy = np.empty((N, C.shape[0], dFc.shape[0]))
        port_record(
            *self._kernel_args,
            c(C, dtype=float),
            c(D, dtype=float),
            *self._law_args(law),
            um,
            c(um1, dtype=float),
            y,
            p,
            dFc,
            dlv,
            dCvT,
            has_dcv,
            dy,
        )
        return (y, p) if sens is None else (y, p, dy)


@dataclass(frozen=True)
class PortSensitivity:
    """How a friction :class:`PortLaw` depends on parameters theta (n_th of them), for the
    exact sensitivities of :meth:`SubstepZoh.simulate`.

    Parameters
    ----------
    friction_force : (n_th, n_p) array
        dF_c / dtheta, N per unit of theta (for theta = log F_c: F_c on its port's row).
    log_velocity : (n_th,) array, optional
        dlog v0 / dtheta (1 for theta = log v0); default 0.
    Cv : (n_th, n_p, n) array, optional
        dCv / dtheta, the port velocity map's (m/s per state per unit of theta); default 0.
    """

    friction_force: np.ndarray
    log_velocity: np.ndarray | None = None
    Cv: np.ndarray | None = None

    def kernel_args(self, n: int, n_p: int):
        """(dFc, dlv, dCvT, has_dcv (n_th,) bool) as :func:`workbench._port_kernel.port_record`
        takes them."""
        c = np.ascontiguousarray
        dFc = c(np.asarray(self.friction_force, float).reshape(-1, n_p))
        n_th = dFc.shape[0]
        dlv = np.zeros(n_th) if self.log_velocity is None else self.log_velocity
        dlv = c(np.broadcast_to(np.asarray(dlv, float), (n_th,)))
        if self.Cv is None:
            return dFc, dlv, np.zeros((n_th, n, n_p)), np.zeros(n_th, bool)
        dCv = np.asarray(self.Cv, float).reshape(n_th, n_p, n)
        # per parameter whether it moves Cv at all (the levels and v0 do not: skipped)
        return dFc, dlv, c(dCv.transpose(0, 2, 1)), np.any(dCv != 0, axis=(1, 2))


def _friction_end_reference(a, Mv, Fc, v0, r):
    """NumPy reference of the friction solve of ``workbench._port_kernel`` (same steps)."""
    from workbench._port_kernel import _LINE_ITER, _LINE_TOL, NEWTON_ITER, NEWTON_TOL

    def residual(r):
        t = np.tanh((a + Mv @ r) * (1.0 / v0))
        return r + Fc * t, t

    fc_max = Fc.max()
    g, t = residual(r)
    mv = np.diag(Mv)
    if np.any(Fc * mv / v0 > 1.0):  # stiff: the force that stops each port, clipped
        r0 = np.where(mv > 0, np.clip(-a / np.where(mv > 0, mv, 1.0), -Fc, Fc), 0.0)
        g0, t0 = residual(r0)
        if np.max(np.abs(g0)) < np.max(np.abs(g)):
            r, g, t = r0, g0, t0
    for _ in range(NEWTON_ITER):
        if np.max(np.abs(g)) <= NEWTON_TOL * fc_max:
            break
        J = np.eye(r.size) + (Fc * (1 - t * t) / v0)[:, None] * Mv
        dlt = np.linalg.solve(J, -g)
        if np.max(np.abs(dlt)) <= NEWTON_TOL * fc_max:
            r = r + dlt
            break
        gt, tt = residual(r + dlt)
        s = 1.0
        if not np.max(np.abs(gt)) <= 0.5 * np.max(np.abs(g)):
            q = Mv @ dlt
            slope0, dphi = q @ g, q @ gt
            lo, hi = 0.0, 1.0
            for _ in range(_LINE_ITER):
                if (dphi <= 0 and s == 1.0) or abs(dphi) <= _LINE_TOL * abs(slope0):
                    break
                lo, hi = (lo, s) if dphi > 0 else (s, hi)
                d2 = q @ (dlt + Fc * (1 - tt * tt) / v0 * q)
                s_new = s - dphi / d2 if d2 > 0 else 0.5 * (lo + hi)
                s = s_new if lo < s_new < hi else 0.5 * (lo + hi)
                gt, tt = residual(r + s * dlt)
                dphi = q @ gt
        r, g, t = r + s * dlt, gt, tt
    return r


def _advance_reference(prop: SubstepZoh, x, u_new, u_old, law: PortLaw):
    """NumPy reference of ``workbench._port_kernel.port_sample``."""
    Ga, G1 = prop.Gp - prop.Gp_end, prop.Gp_end
    Fc, v0, k3 = law.friction_force, law.friction_velocity, law.cubic_stiffness
    Mv = law.Cv @ G1
    has_fr, has_k3 = bool(np.any(Fc > 0)), bool(np.any(k3 != 0))
    r = -Fc * np.tanh((law.Cv @ x) / v0)  # the friction at the sample's start
    for j in range(prop.n_sub):
        fr = r if has_fr else np.zeros_like(Fc)  # the end value of the substep before
        c0 = -k3 * (law.Cp @ x) ** 3
        xp = prop.Phi @ x + prop.G_new[j] @ u_new + Ga @ (fr + c0) + G1 @ c0
        if np.any(prop.G_old):
            xp = xp + prop.G_old[j] @ u_old
        for rep in range(2 if has_k3 else 1):
            if rep == 1:  # Heun: the spring's end value from the state just found
                xp = xp + G1 @ (-k3 * (law.Cp @ x) ** 3 - c0)
            if has_fr:
                r = _friction_end_reference(law.Cv @ xp, Mv, Fc, v0, r)
                x = xp + G1 @ r
            else:
                x = xp
    return x


def substep_zoh(A, B, Bp, dt: float, n_sub: int, *, delay_s: float = 0.0) -> SubstepZoh:
    """The :class:`SubstepZoh` of continuous (A, B, Bp) at sample time ``dt``.

    Parameters
    ----------
    A : (n, n) array
    B : (n, n_u) array
        Input matrix of the (delayed, zero-order-held) input.
    Bp : (n, n_p) array
        Input matrix of the port forces.
    dt : float
        Sample time, s.
    n_sub : int
        Substeps per sample (>= 1).
    delay_s : float
        Input delay, s (fractional part exact).
    """
    if isinstance(n_sub, bool) or int(n_sub) != n_sub or n_sub < 1:
        raise InputError(f"substeps: expected an integer >= 1, got {n_sub!r}")
    n_sub = int(n_sub)
    h = dt / n_sub
    m, tau = split_delay(delay_s, dt)
    Phi, Gp, Gp_end = phi_gamma_foh(A, Bp, h)
    _, G_h = phi_gamma(A, B, h)
    # every substep but the one the input switches in holds one input throughout: one
    # exponential for all of them (a 128-substep sample would otherwise take 256)
    G_old = np.zeros((n_sub,) + G_h.shape)
    G_new = np.zeros((n_sub,) + G_h.shape)
    for j in range(n_sub):
        t0, t1 = j * h, (j + 1) * h
        if tau <= t0:  # the new input over the whole substep
            G_new[j] = G_h
        elif tau >= t1:  # the old input over the whole substep
            G_old[j] = G_h
        else:  # old input over [t0, tau], new over [tau, t1]
            P1, G_new[j] = phi_gamma(A, B, t1 - tau)
            G_old[j] = P1 @ phi_gamma(A, B, tau - t0)[1]
    return SubstepZoh(Phi=Phi, Gp=Gp, Gp_end=Gp_end, G_old=G_old, G_new=G_new, m=m)


# ------------------------------------------------------------------ closed loop
def _with_output_delay(Ac, Bc, Cc, Dc, L: int):
    """The controller followed by L samples of pure delay on each output."""
    for _ in range(L):  # q+ = Cc x + Dc e ; u = q
        n, n_u = Ac.shape[0], Cc.shape[0]
        Ac = np.block([[Ac, np.zeros((n, n_u))], [Cc, np.zeros((n_u, n_u))]])
        Bc = np.vstack([Bc, Dc])
        Cc = np.hstack([np.zeros((n_u, n)), np.eye(n_u)])
        Dc = np.zeros_like(Dc)
    return Ac, Bc, Cc, Dc


def closed_loop_matrices(plant_abcd, controller_abcd, *, delay_samples: int = 0):
    """Discrete closed loop: inputs [r; d; v], outputs [u; y], states [plant; controller].

    Parameters
    ----------
    plant_abcd : (A, B, C, D)
        Discrete plant u -> y (delay as states, :func:`discretize`).
    controller_abcd : (A, B, C, D)
        Discrete controller e -> u_c (spec 5: e = r - y).
    delay_samples : int
        Loop delay between the controller output and the plant input, samples.

    Notes
    -----
    e = r - y, u = d + u_c (delayed), y = C_p x_p + D_p u + v (v: measurement
    noise). With M = (I + D_c D_p)^-1, u = M (d + D_c r - D_c v + C_c x_c - D_c C_p x_p).
    """
    Ap, Bp, Cp, Dp = (np.asarray(a, float) for a in plant_abcd)
    Ac, Bc, Cc, Dc = _with_output_delay(
        *(np.asarray(a, float) for a in controller_abcd), int(delay_samples)
    )
    n_p, n_c = Ap.shape[0], Ac.shape[0]
    n_u, n_y = Bp.shape[1], Cp.shape[0]
    M = np.linalg.inv(np.eye(n_u) + Dc @ Dp)
    Ux = np.hstack([-M @ Dc @ Cp, M @ Cc])
    Uw = np.hstack([M @ Dc, M, -M @ Dc])
    Yx = np.hstack([Cp, np.zeros((n_y, n_c))]) + Dp @ Ux
    Yw = Dp @ Uw + np.hstack([np.zeros((n_y, n_y + n_u)), np.eye(n_y)])
    Ew = np.hstack([np.eye(n_y), np.zeros((n_y, n_u + n_y))]) - Yw  # e = r - y
    A = np.block([[Ap, np.zeros((n_p, n_c))], [np.zeros((n_c, n_p)), Ac]])
    A = A + np.vstack([Bp @ Ux, -Bc @ Yx])
    B = np.vstack([Bp @ Uw, Bc @ Ew])
    return A, B, np.vstack([Ux, Yx]), np.vstack([Uw, Yw])


@dataclass(frozen=True, eq=False)
class _ModelPlant:
    """An LTI model in the plant contract: noise-free, its delay in the loop (internal)."""

    sys: Any
    fs: float

    @property
    def n_u(self) -> int:
        return np.asarray(self.sys.B).shape[1]

    @property
    def n_y(self) -> int:
        return np.asarray(self.sys.C).shape[0]

    def init(self, rng):
        A, *_ = self.abcd
        return np.zeros(A.shape[0])

    @cached_property
    def abcd(self):
        return discretize(self.sys, self.fs)

    def step(self, x, u_k):
        A, B, C, D = self.abcd
        return C @ x + D @ u_k, A @ x + B @ u_k

    def sampled_step(self):
        from workbench.compiled import SampledStep

        A, B, C, D = self.abcd
        n_y = C.shape[0]
        return SampledStep(
            A=A,
            B0=B,
            B1=np.zeros_like(B),
            m=0,
            C=C,
            D=D,
            saturation=np.full(B.shape[1], np.inf),
            raw_map=np.eye(n_y),
            decouple=np.eye(n_y),
            noise_std=np.zeros(n_y),
            quantization=0.0,
        )


def _is_plant_object(plant) -> bool:
    return hasattr(plant, "step") and hasattr(plant, "linear_model")


def is_linear_additive(plant, u_probe: np.ndarray) -> bool:
    """True when ``plant.simulate(u) - plant.simulate(0)`` is its linear model's ZOH response.

    Checked on the probe input with one fixed seed (the same noise cancels),
    to 1e-6 relative: then the plant is linear with additive output noise.
    """
    seed = 20240601  # any fixed seed: the same noise in both runs cancels
    y1 = np.asarray(plant.simulate(u_probe, rng=np.random.default_rng(seed)), float)
    y0 = np.asarray(plant.simulate(np.zeros_like(u_probe), rng=np.random.default_rng(seed)), float)
    y_lin = simulate_zoh(plant.linear_model(), u_probe, plant.fs, delay_s=plant.delay_s)
    scale = np.linalg.norm(y_lin)
    return bool(scale > 0 and np.linalg.norm(y1 - y0 - y_lin) <= 1e-6 * scale)


def _signal(x, n: int, N: int | None, name: str) -> np.ndarray | None:
    if x is None:
        return None
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[1] != n or (N is not None and x.shape[0] != N):
        want = f"({'N' if N is None else N}, {n})"
        raise InputError(f"{name}: expected shape {want}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(f"{name}: expected finite values")
    return x


def closed_loop(
    plant,
    controller,
    *,
    r: np.ndarray | None = None,
    d: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    delay_samples: int = 0,
    method: Literal["auto", "linear", "step"] = "auto",
    engine: Literal["auto", "compiled", "python"] = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-loop response from rest of any plant with any :class:`controllers.Controller`.

    Parameters
    ----------
    plant : Plant or control.StateSpace or LTIModel
        A ``plants`` object (noise, quantization, nonlinearities its own), or a
        linear model (continuous: ZOH at the controller's fs with the model's
        delay; discrete: dt = 1/fs), noise-free.
    controller : Controller
        e (n_y) -> u_c (n_u) at the plant's fs, e = r - y.
    r : (N, n_y) array, optional
        Reference on the measured outputs (default 0).
    d : (N, n_u) array, optional
        Excitation added at the plant input, N (default 0). One of r, d is needed.
    rng : numpy.random.Generator, optional
        Source of a plant's noise (required for plant objects).
    delay_samples : int
        Computation delay of the loop, samples: u[k] = d[k] + u_c[k - delay_samples].
    method : {"auto", "linear", "step"}
        ``"linear"``: one discrete LTI system driven by [r, d, v] with v the
        plant's noise (``plant.simulate(0)``), needs a linear controller and a
        plant linear with additive noise; ``"auto"`` checks that (the plant by
        superposition on a probe of the excitation). ``"step"``: ``plant.step``
        and ``controller.step`` sample by sample; u[k] must not depend on y[k]:
        needs ``delay_samples >= 1`` or a controller with ``output(state)``
        (no direct feedthrough).
    engine : {"auto", "compiled", "python"}
        How ``"step"`` runs. ``"compiled"``: one numba kernel
        (:mod:`workbench.compiled`) for a linear controller on a plant that
        describes its step (``plant.sampled_step()``: matrices, delay,
        saturation, noise, quantization), same result as ``"python"`` to
        rounding; ``"python"``: ``plant.step`` / ``controller.step``;
        ``"auto"``: compiled where it applies (a nonlinear controller such as MPC,
        or friction in the plant, steps in Python). numba is a dependency: a
        broken install is an ImportError, never a silent fallback.

    Returns
    -------
    u : (N, n_u) array
        Plant input, N.
    y : (N, n_y) array
        Measured output, m.
    """
    if isinstance(delay_samples, bool) or int(delay_samples) != delay_samples or delay_samples < 0:
        raise InputError(f"delay_samples: expected an integer >= 0, got {delay_samples!r}")
    delay_samples = int(delay_samples)
    if engine not in ("auto", "compiled", "python"):
        raise InputError(f"engine: expected 'auto', 'compiled' or 'python', got {engine!r}")
    model = not _is_plant_object(plant)
    if model:
        plant = _ModelPlant(plant, float(controller.fs))
        plant.abcd  # noqa: B018 - discretize now: a wrong dt is refused before any work
    elif rng is None or not isinstance(rng, np.random.Generator):
        raise InputError(
            f"rng: expected a numpy.random.Generator for the plant's noise, got {rng!r}"
        )
    n_u, n_y = plant.n_u, plant.n_y
    if controller.n_u != n_u or controller.n_y != n_y:
        raise InputError(
            f"controller: expected {n_y} inputs and {n_u} outputs to match the plant, "
            f"got {controller.n_y} and {controller.n_u}"
        )
    if abs(controller.fs - plant.fs) > 1e-9 * plant.fs:
        raise InputError(
            f"controller: expected fs = {plant.fs:g} Hz like the plant, got {controller.fs:g}"
        )
    if r is None and d is None:
        raise InputError("closed_loop: expected a reference r (N, n_y) or an excitation d (N, n_u)")
    N = (np.asarray(r) if r is not None else np.asarray(d)).shape[0]
    r = _signal(r, n_y, N, "r")
    d = _signal(d, n_u, N, "d")
    r_given = r  # None: no reference (the compiled loop reads none)
    r = np.zeros((N, n_y)) if r is None else r
    d = np.zeros((N, n_u)) if d is None else d
    compiled = None
    if engine != "python" and method in ("auto", "step"):
        compiled = _sampled_step(plant, controller)
    if method == "auto" and compiled is not None:
        if delay_samples or not np.any(controller.statespace().D):
            # exact for linear and nonlinear plants alike: no linearity probe needed
            method = "step"
    if method == "auto":
        linear = bool(controller.linear)
        if linear and not model:
            n_p = min(N, 512)
            # the excitation itself, or unit white noise (N) when only r is given
            probe = d[:n_p] if np.any(d) else np.random.default_rng(1).standard_normal((n_p, n_u))
            linear = is_linear_additive(plant, probe)
        method = "linear" if linear else "step"
    if method == "linear":
        if not controller.linear:
            raise InputError(
                "method: 'linear' needs a linear controller (controller.linear is False)"
            )
        P = (
            plant.abcd
            if model
            else discretize(plant.linear_model(), plant.fs, delay_s=plant.delay_s)
        )
        K = controller.statespace()
        A, B, C, D = closed_loop_matrices(P, (K.A, K.B, K.C, K.D), delay_samples=delay_samples)
        _check_stable(A)
        if model:
            v = np.zeros((N, n_y))
        else:
            v = np.asarray(plant.simulate(np.zeros((N, n_u)), rng=rng), float)
        out = dlsim(A, B, C, D, np.hstack([r, d, v]))
        return out[:, :n_u], out[:, n_u:]
    if method == "step":
        if compiled is not None:
            from workbench.compiled import run_compiled_loop

            K = controller.statespace()
            step = compiled
            if step.quantization == 0 and np.all(np.isinf(step.saturation)):
                # a linear loop: refused when unstable, as the linear path does
                P = delay_augmented(step.A, step.B0, step.B1, step.m, step.C, step.D)
                T = step.decouple @ step.raw_map
                P = (P[0], P[1], T @ P[2], T @ P[3])
                _check_stable(
                    closed_loop_matrices(P, (K.A, K.B, K.C, K.D), delay_samples=delay_samples)[0]
                )
            return run_compiled_loop(step, (K.A, K.B, K.C, K.D), r_given, d, rng, delay_samples)
        if engine == "compiled":
            raise InputError(
                "engine: 'compiled' needs a linear controller and a plant with sampled_step() "
                "(no friction or cubic spring); use engine='python'"
            )
        return _step_loop(plant, controller, r, d, rng, delay_samples)
    raise InputError(f"method: expected 'auto', 'linear' or 'step', got {method!r}")


@lru_cache(maxsize=32)
def _spectral_radius(n: int, a_bytes: bytes) -> float:
    """Memoized on the matrix's bytes: a repeated run of one loop checks it once (1.3 ms for
    the stage's 64-state loop)."""
    A = np.frombuffer(a_bytes, dtype=float).reshape(n, n)
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if n else 0.0


def _check_stable(A: np.ndarray) -> None:
    A = np.ascontiguousarray(A, dtype=float)
    rho = _spectral_radius(A.shape[0], A.tobytes())
    if rho >= 1:
        raise InputError(
            f"controller: the closed loop is unstable (spectral radius {rho:.4f} >= 1); "
            "lower the crossover or add a notch"
        )


def _sampled_step(plant, controller):
    """The plant's ``SampledStep`` when the compiled loop applies, else None."""
    if not controller.linear or not hasattr(plant, "sampled_step"):
        return None
    return plant.sampled_step()


def _step_loop(plant, controller, r, d, rng, delay_samples: int):
    from controllers.protocol import StrictlyProper

    if delay_samples == 0 and not isinstance(controller, StrictlyProper):
        raise InputError(
            "controller: stepping the loop needs delay_samples >= 1 or a controller with "
            "output(state) (u[k] must not depend on y[k])"
        )
    N = r.shape[0]
    u = np.empty_like(d)
    y = np.empty((N, plant.n_y))
    ps: Any = plant.init(rng)
    cs = controller.init()
    # pending controller outputs: pending[0] is applied at this sample
    pending = [np.zeros(plant.n_u) for _ in range(delay_samples)]
    for k in range(N):
        if delay_samples:
            u[k] = d[k] + pending.pop(0)
        else:
            u[k] = d[k] + controller.output(cs)
        y[k], ps = plant.step(ps, u[k])
        uc, cs = controller.step(cs, r[k] - y[k])
        if delay_samples:
            pending.append(uc)
    return u, y
