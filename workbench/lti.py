"""Linear-system numerics shared by every part of the workbench.

Frequency responses in the one layout of the project, (n_f, n_y, n_u), exact
zero-order-hold discretization with an input delay, zero-order-hold
simulation from rest, and the two relative-error measures of the exchange
spec (section 3), so that ``compare`` and ``diagnose`` compute them alike.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = [
    "frf",
    "delay_frf",
    "zoh_frf",
    "c2d_zoh",
    "simulate_zoh",
    "relative_error_frf",
    "relative_error_time",
    "as_matrices",
]


def as_matrices(sys) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """(A, B, C, D, dt) of a ``StateSpace`` as float arrays; dt = 0 for continuous."""
    dt = sys.dt
    dt = 0.0 if (dt is None or dt is False or dt == 0) else float(dt)
    return (
        np.asarray(sys.A, float),
        np.asarray(sys.B, float),
        np.asarray(sys.C, float),
        np.asarray(sys.D, float),
        dt,
    )


def frf(sys, freq_hz, *, delay_s: float = 0.0) -> np.ndarray:
    """Frequency response of a state-space model at ``freq_hz``.

    Parameters
    ----------
    sys : control.StateSpace
        Continuous (dt = 0) or discrete model.
    freq_hz : (n_f,) array
        Frequencies, Hz.
    delay_s : float
        Input delay, s, applied as the exact factor exp(-j w delay_s).

    Returns
    -------
    (n_f, n_y, n_u) complex array

    Notes
    -----
    C (sI - A)^-1 B + D with s = jw (continuous) or s = exp(jw dt) (discrete),
    through the eigen-decomposition of A when it is well conditioned (checked
    against direct solves at a few lines), else by batched LU solves in chunks
    of lines (exact for defective A such as rigid-body double integrators).
    """
    A, B, C, D, dt = as_matrices(sys)
    f = np.atleast_1d(np.asarray(freq_hz, float))
    w = 2 * np.pi * f
    s = np.exp(1j * w * dt) if dt > 0 else 1j * w
    n = A.shape[0]
    G = np.broadcast_to(D.astype(complex), (f.size,) + D.shape).copy()
    if n:
        G += _resolvent_frf(A, B, C, s)
    if delay_s:
        G *= delay_frf(f, delay_s)[:, None, None]
    return G


def _solve_frf(A, B, C, s) -> np.ndarray:
    n = A.shape[0]
    eye = np.eye(n)
    out = np.empty((s.size, C.shape[0], B.shape[1]), complex)
    chunk = max(1, 2**22 // (n * n))  # bound the (chunk, n, n) stack to ~64 MB
    for lo in range(0, s.size, chunk):
        sl = slice(lo, lo + chunk)
        M = s[sl, None, None] * eye - A
        out[sl] = C @ np.linalg.solve(M, np.broadcast_to(B, (M.shape[0],) + B.shape))
    return out


def _resolvent_frf(A, B, C, s) -> np.ndarray:
    """C (sI - A)^-1 B at every s, shape (n_f, n_y, n_u)."""
    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) < 1e6:
        CV = C @ V
        VB = np.linalg.solve(V, B.astype(complex))
        G = np.einsum("yk,fk,ku->fyu", CV, 1.0 / (s[:, None] - lam[None, :]), VB)
        probe = np.unique(np.linspace(0, s.size - 1, 4).astype(int))
        ref = _solve_frf(A, B, C, s[probe])
        scale = np.linalg.norm(ref, axis=(1, 2)) + 1e-300
        if np.all(np.linalg.norm(G[probe] - ref, axis=(1, 2)) <= 1e-9 * scale):
            return G
    return _solve_frf(A, B, C, s)


def delay_frf(freq_hz, delay_s: float) -> np.ndarray:
    """exp(-j 2 pi f delay_s), shape (n_f,)."""
    return np.exp(-2j * np.pi * np.asarray(freq_hz, float) * delay_s)


def zoh_frf(freq_hz, fs: float) -> np.ndarray:
    """Frequency response of a zero-order hold, exp(-j w T/2) sinc(w T / 2), shape (n_f,).

    A continuous plant sampled behind a ZOH shows this factor times its own
    response (below Nyquist, neglecting aliasing); measured FRFs in the spec
    have it divided out.
    """
    f = np.asarray(freq_hz, float)
    T = 1.0 / fs
    return np.exp(-1j * np.pi * f * T) * np.sinc(f * T)


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
    n, m_u = B.shape
    m = int(np.floor(delay_s / dt + 1e-12))
    tau = delay_s - m * dt
    if tau < 1e-12 * dt:
        tau = 0.0

    def phi_gamma(h: float):
        M = np.zeros((n + m_u, n + m_u))
        M[:n, :n] = A * h
        M[:n, n:] = B * h
        E = scipy.linalg.expm(M)
        return E[:n, :n], E[:n, n:]

    Ad, B0 = phi_gamma(dt - tau)
    if tau == 0.0:
        return Ad, B0, np.zeros_like(B0), m
    Ptau, Gtau = phi_gamma(tau)
    return Ad @ Ptau, B0, Ad @ Gtau, m


def simulate_zoh(sys, u: np.ndarray, fs: float, *, delay_s: float = 0.0, x0=None) -> np.ndarray:
    """Response of a model to a zero-order-held input, from rest (or ``x0``).

    Parameters
    ----------
    sys : control.StateSpace
        Continuous model (discretized exactly with the ZOH at ``fs``) or a
        discrete model whose dt equals 1/fs.
    u : (N, n_u) array
        Input samples, held over each sample interval.
    fs : float
        Sampling frequency, Hz.
    delay_s : float
        Input delay, s (any real value >= 0; fractional delays are exact).

    Returns
    -------
    (N, n_y) array, y[k] sampled at t = k / fs.
    """
    A, B, C, D, dt = as_matrices(sys)
    u = np.asarray(u, float)
    N = u.shape[0]
    n = A.shape[0]
    if dt > 0:
        if abs(dt * fs - 1) > 1e-9:
            raise ValueError(
                f"sys: expected a discrete model with dt = {1 / fs:g} s, got dt = {dt:g} s"
            )
        if delay_s:
            raise ValueError("delay_s with a discrete model: add the delay to the model instead")
        Ad, B0, B1, m = A, B, np.zeros_like(B), 0
    else:
        Ad, B0, B1, m = c2d_zoh(A, B, 1.0 / fs, delay_s=delay_s)
    # delayed input sequences u[k-m] and u[k-m-1] (zero before the record: at rest)
    um = np.zeros_like(u)
    if m < N:
        um[m:] = u[: N - m]
    um1 = np.zeros_like(u)
    if m + 1 < N:
        um1[m + 1 :] = u[: N - m - 1]
    drive = um @ B0.T + um1 @ B1.T  # (N, n)
    x = np.zeros((N, n))
    if n:
        xk = np.zeros(n) if x0 is None else np.asarray(x0, float)
        for k in range(N):
            x[k] = xk
            xk = Ad @ xk + drive[k]
    # the direct feedthrough sees the delayed input too; a fractional delay
    # mixes the two neighbouring samples only in the state, not in D (D u is
    # instantaneous), so D acts on the integer-delayed input.
    return x @ C.T + um @ D.T


def relative_error_frf(G_meas: np.ndarray, G_model: np.ndarray) -> float:
    """Spec measure for FRF data: mean over lines of ||G_meas - G_model||_F / ||G_meas||_F."""
    num = np.linalg.norm(G_meas - G_model, axis=(1, 2))
    den = np.linalg.norm(G_meas, axis=(1, 2))
    return float(np.mean(num / np.where(den > 0, den, np.inf)))


def relative_error_time(Y: np.ndarray, Y_model: np.ndarray) -> float:
    """Spec measure for time data: ||Y - Y_model||_F / ||Y||_F."""
    den = np.linalg.norm(Y)
    return float(np.linalg.norm(Y - Y_model) / den) if den > 0 else float("inf")
