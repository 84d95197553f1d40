"""Linear-system numerics shared by every part of the workbench.

Frequency responses in the one layout of the project, (n_f, n_y, n_u), and
the two relative-error measures of the exchange spec (section 3), so that
``compare`` and ``diagnose`` compute them alike. ZOH discretization and
simulation are in :mod:`workbench.sim` (the one simulator).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "frf",
    "delay_frf",
    "zoh_frf",
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
    sys : control.StateSpace or workbench.core.model.LTIModel
        Continuous (dt = 0) or discrete model; an LTIModel's own delay is applied.
    freq_hz : (n_f,) array
        Frequencies, Hz.
    delay_s : float
        Input delay added to the model's own, s, applied as the exact factor
        exp(-j w delay_s).

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
    delay_s = float(delay_s) + float(getattr(sys, "delay_s", 0.0))  # the model's delay travels
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


def relative_error_frf(G_meas: np.ndarray, G_model: np.ndarray) -> float:
    """Spec measure for FRF data: mean over lines of ||G_meas - G_model||_F / ||G_meas||_F."""
    num = np.linalg.norm(G_meas - G_model, axis=(1, 2))
    den = np.linalg.norm(G_meas, axis=(1, 2))
    return float(np.mean(num / np.where(den > 0, den, np.inf)))


def relative_error_time(Y: np.ndarray, Y_model: np.ndarray) -> float:
    """Spec measure for time data: ||Y - Y_model||_F / ||Y||_F."""
    den = np.linalg.norm(Y)
    return float(np.linalg.norm(Y - Y_model) / den) if den > 0 else float("inf")
