"""Response of an FE model at any of its sensors: modal sum plus residual compliance.

    G(s) = sum_{k < n_d} (C phi_k)(B^T phi_k)^T / (s^2 + 2 zeta_k w_k s + w_k^2)  +  D_res

over the modes whose damping the file gives (``n_d``: all modes for a scalar
damping), with the modes beyond them entering statically,
``D_res = sum_{k >= n_d} (C phi_k)(B^T phi_k)^T / w_k^2`` (residual compliance).
The output map ``C`` may hold sensors the measurement never had: the updated
model predicts them (seed 001, spatio-temporal prediction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.core.errors import InputError

from .eigen import solve_modes
from .model import FEModel

__all__ = ["ModalTerms", "modal_terms", "predict_frf"]

#: Above this many DOFs only the lowest modes are solved (sparse shift-invert).
DENSE_MAX_DOF = 2000


@dataclass(frozen=True, eq=False)
class ModalTerms:
    """The FE model's response in modal terms at chosen channels.

    Attributes
    ----------
    freq_hz, damping : (k,) arrays
        Dynamic modes: frequency (Hz) and damping ratio.
    c : (k, n_y) array ; b : (k, n_u) array
        Mass-normalized modal output and input vectors (m per modal unit, modal force per N).
    D : (n_y, n_u) array
        Residual compliance of the modes left out, m/N.
    """

    freq_hz: np.ndarray
    damping: np.ndarray
    c: np.ndarray
    b: np.ndarray
    D: np.ndarray

    def frf(self, freq_hz) -> np.ndarray:
        """G at ``freq_hz`` (n_f,) Hz: (n_f, n_y, n_u) complex, m/N."""
        s = 2j * np.pi * np.asarray(freq_hz, float)
        w = 2 * np.pi * self.freq_hz
        h = 1.0 / (s[:, None] ** 2 + 2 * self.damping * w * s[:, None] + w**2)
        return np.einsum("fk,ky,ku->fyu", h, self.c, self.b) + self.D


def modal_terms(
    fe: FEModel,
    *,
    alpha=None,
    outputs=None,
    inputs=None,
    n_modes: int | None = None,
) -> ModalTerms:
    """Modal terms of ``fe`` at ``outputs``/``inputs`` (names; default all).

    ``n_modes`` caps the dynamic modes (default: those with a damping in the file);
    the rest of the spectrum is the residual compliance, exact from all modes for
    a model of up to ``DENSE_MAX_DOF`` DOFs, else ``C K^-1 B`` minus the dynamic
    part (needs K nonsingular; 0 otherwise).
    """
    oi = np.arange(len(fe.output_names)) if outputs is None else fe.output_index(outputs, "outputs")
    ii = np.arange(len(fe.input_names)) if inputs is None else fe.input_index(inputs, "inputs")
    n_d = fe.n_dof if fe.damping_scalar else min(fe.damping.size, fe.n_dof)
    if n_modes is not None:
        if int(n_modes) < 1:
            raise InputError(f"n_modes: expected >= 1, got {n_modes!r}")
        n_d = min(n_d, int(n_modes))
    K, M = fe.matrices(alpha)
    Co, Bi = fe.C[oi], fe.B[:, ii]
    if fe.n_dof <= DENSE_MAX_DOF:
        modes = solve_modes(K, M)
        c_all = (Co @ modes.Phi).T
        b_all = (Bi.T @ modes.Phi).T
        rest = slice(n_d, None)
        D = np.einsum("ky,ku,k->yu", c_all[rest], b_all[rest], 1.0 / modes.lam[rest])
    else:
        modes = solve_modes(K, M, n_d)
        c_all = (Co @ modes.Phi).T
        b_all = (Bi.T @ modes.Phi).T
        D = np.zeros((oi.size, ii.size))
        if modes.lam[0] > 0:
            D = Co @ np.linalg.solve(K, Bi) - np.einsum(
                "ky,ku,k->yu", c_all, b_all, 1.0 / modes.lam
            )
    return ModalTerms(
        freq_hz=modes.freq_hz[:n_d],
        damping=fe.mode_damping(n_d),
        c=c_all[:n_d],
        b=b_all[:n_d],
        D=D,
    )


def predict_frf(fe: FEModel, freq_hz, *, alpha=None, outputs=None, inputs=None) -> np.ndarray:
    """Predicted FRF (n_f, n_y, n_u), m/N, of ``fe`` at ``outputs`` x ``inputs`` (names)."""
    return modal_terms(fe, alpha=alpha, outputs=outputs, inputs=inputs).frf(freq_hz)
