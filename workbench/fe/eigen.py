"""Generalized symmetric eigenproblem K phi = lambda M phi of an FE model, lowest modes.

Small models (or all modes wanted): dense LAPACK ``eigh``. Large banded models
(an FE beam or any model numbered along a line) and only the lowest ``k`` modes
wanted: ARPACK shift-invert Lanczos (``eigsh``) on the banded sparse matrices,
shifted just below zero so rigid modes are found. (A dense solve cannot resolve
the lowest modes of a fine mesh at all: K's largest entries are ~ lambda_max,
and lambda_1 / lambda_max falls below round-off.)

Mode shapes are mass-normalized (``Phi^T M Phi = I``); their sign is fixed so
that the largest-magnitude entry is positive, so results are reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from workbench.core.errors import InputError

__all__ = ["Modes", "solve_modes", "bandwidth"]


@dataclass(frozen=True, eq=False)
class Modes:
    """Eigenpairs, ascending.

    Attributes
    ----------
    lam : (k,) array
        Eigenvalues omega^2, (rad/s)^2 (tiny negative values of rigid modes kept as computed).
    Phi : (n, k) array
        Mass-normalized mode shapes (columns).
    """

    lam: np.ndarray
    Phi: np.ndarray

    @property
    def freq_hz(self) -> np.ndarray:
        """Natural frequencies, Hz (rigid modes' round-off negatives clipped to 0)."""
        return np.sqrt(np.clip(self.lam, 0.0, None)) / (2 * np.pi)


def bandwidth(*mats: np.ndarray) -> int:
    """Half-bandwidth (largest |i - j| of a nonzero) over the given square matrices."""
    b = 0
    for A in mats:
        i, j = np.nonzero(A)
        if i.size:
            b = max(b, int(np.max(np.abs(i - j))))
    return b


def _fix_sign(Phi: np.ndarray) -> np.ndarray:
    idx = np.argmax(np.abs(Phi), axis=0)
    s = np.sign(Phi[idx, np.arange(Phi.shape[1])])
    s[s == 0] = 1.0
    return Phi * s


def _band_upper(A: np.ndarray, b: int) -> np.ndarray:
    """LAPACK upper band storage (b + 1, n) of symmetric ``A``."""
    n = A.shape[0]
    ab = np.zeros((b + 1, n))
    for d in range(b + 1):
        ab[b - d, d:] = np.diagonal(A, d)
    return ab


def solve_modes(
    K: np.ndarray,
    M: np.ndarray,
    n_modes: int | None = None,
    *,
    method: str = "auto",
) -> Modes:
    """Lowest ``n_modes`` eigenpairs of ``K phi = lambda M phi``.

    Parameters
    ----------
    K, M : (n, n) arrays or scipy.sparse matrices
        Symmetric stiffness (positive semi-definite) and mass (positive definite).
        Sparse input goes straight to the sparse shift-invert solver.
    n_modes : int, optional
        Modes wanted; default all (dense).
    method : {"auto", "dense", "banded"}
        "auto": sparse shift-invert when ``n >= 600``, the half-bandwidth
        is below ``n / 20`` and ``n_modes < n / 10``; else dense.
    Returns
    -------
    Modes
    """
    if scipy.sparse.issparse(K) or scipy.sparse.issparse(M):
        # already sparse (a large model): shift-invert directly
        Ks, Ms = scipy.sparse.csc_matrix(K, dtype=float), scipy.sparse.csc_matrix(M, dtype=float)
        n = Ks.shape[0]
        k = n - 2 if n_modes is None else int(n_modes)
        if Ks.shape != (n, n) or Ms.shape != (n, n) or not 1 <= k < n - 1:
            raise InputError(
                f"solve_modes: expected square K, M of one size and 1 <= n_modes < n - 1, got "
                f"{Ks.shape}, {Ms.shape}, {n_modes!r}"
            )
        return _shift_invert(Ks, Ms, k)
    K = np.asarray(K, float)
    M = np.asarray(M, float)
    n = K.shape[0]
    if K.shape != (n, n) or M.shape != (n, n):
        raise InputError(f"solve_modes: expected square K, M of one size, got {K.shape}, {M.shape}")
    k = n if n_modes is None else int(n_modes)
    if not 1 <= k <= n:
        raise InputError(f"solve_modes: expected 1 <= n_modes <= {n}, got {n_modes!r}")
    if method not in ("auto", "dense", "banded"):
        raise InputError(f"solve_modes: method expected auto/dense/banded, got {method!r}")
    b = bandwidth(K, M) if method != "dense" else n
    use_band = method == "banded" or (method == "auto" and n >= 600 and b < n / 20 and k < n / 10)
    if use_band:
        return _sparse(K, M, k, b)
    lam, Phi = scipy.linalg.eigh(K, M, subset_by_index=(0, k - 1))
    return Modes(lam, _fix_sign(Phi))


def _sparse(K, M, k, b):
    offsets = list(range(-b, b + 1))
    Ms = scipy.sparse.diags([np.diagonal(M, d) for d in offsets], offsets, format="csc")
    Ks = scipy.sparse.diags([np.diagonal(K, d) for d in offsets], offsets, format="csc")
    return _shift_invert(Ks, Ms, k)


def _shift_invert(Ks, Ms, k):
    # K may be singular (rigid modes): shift just below zero so K - sigma M is
    # factorizable; -1 (rad/s)^2 (0.16 Hz) sits below the flexible modes of any
    # motion system and next to its rigid modes, which keeps them dominant in the
    # inverted problem (a shift scaled to K's largest entries, ~lambda_max, does not).
    lam, Phi = scipy.sparse.linalg.eigsh(Ks, k=k, M=Ms, sigma=-1.0, which="LM")
    order = np.argsort(lam)
    return Modes(lam[order], _fix_sign(Phi[:, order]))
