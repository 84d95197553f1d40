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

__all__ = ["ModalTerms", "PredictionError", "modal_terms", "predict_frf", "prediction_error"]

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

    def frf(self, freq_hz, *, fs: float | None = None) -> np.ndarray:
        """G at ``freq_hz`` (n_f,) Hz: (n_f, n_y, n_u) complex, m/N.

        With ``fs`` (Hz), the response a sampled experiment measures: the ZOH-
        discretized modes (exact, every mode aliased as sampling folds it),
        divided by the ZOH factor :func:`workbench.core.lti.zoh_frf` as the
        spec's FRF estimate is. Near Nyquist this differs from the continuous
        response by what the modes above Nyquist fold back (beam at 1 kHz of
        2048 Hz sampling: ~12 %); a measurement with an anti-aliasing filter
        needs the continuous one.
        """
        f = np.asarray(freq_hz, float)
        w = 2 * np.pi * self.freq_hz
        if fs is None:
            s = 2j * np.pi * f
            h = 1.0 / (s[:, None] ** 2 + 2 * self.damping * w * s[:, None] + w**2)
            return np.einsum("fk,ky,ku->fyu", h, self.c, self.b) + self.D
        from workbench.core.lti import zoh_frf

        if not (np.isfinite(fs) and fs > 0):
            raise InputError(f"fs: expected a sampling frequency > 0 Hz, got {fs!r}")
        T = 1.0 / float(fs)
        z = np.exp(2j * np.pi * f * T)
        # 1 / ((s - p1)(s - p2)) = r / (s - p1) - r / (s - p2), r = 1 / (p1 - p2); the ZOH
        # equivalent of 1 / (s - p) is ((e^{pT} - 1) / p) / (z - e^{pT}), T for p = 0
        zeta = np.minimum(self.damping, 1 - 1e-9)
        wd = w * np.sqrt(1 - zeta**2)
        h = np.zeros((f.size, w.size), complex)
        for sign in (1.0, -1.0):
            p = -zeta * w + sign * 1j * wd
            r = np.divide(sign, 2j * wd, out=np.zeros_like(p), where=wd > 0)
            ep = np.exp(p * T)
            gain = np.divide(ep - 1, p, out=np.full_like(p, T), where=np.abs(p) > 0)
            h += r * gain / (z[:, None] - ep)
        still = wd == 0  # a rigid mode 1 / s^2: its ZOH equivalent in closed form
        if np.any(still):
            zz = z[:, None]
            h[:, still] = T**2 * (zz + 1) / (2 * (zz - 1) ** 2)
        G = np.einsum("fk,ky,ku->fyu", h, self.c, self.b) + self.D
        return G / zoh_frf(f, fs)[:, None, None]


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


def predict_frf(
    fe: FEModel, freq_hz, *, alpha=None, outputs=None, inputs=None, fs: float | None = None
) -> np.ndarray:
    """Predicted FRF (n_f, n_y, n_u), m/N, of ``fe`` at ``outputs`` x ``inputs`` (names).

    ``fs`` (Hz): predict what a sampled experiment at ``fs`` measures, aliasing
    included (see :meth:`ModalTerms.frf`); default the continuous response.
    """
    return modal_terms(fe, alpha=alpha, outputs=outputs, inputs=inputs).frf(freq_hz, fs=fs)


@dataclass(frozen=True)
class PredictionError:
    """Prediction error against measured FRF lines, and the data's own noise level.

    Both per line as ``||G_pred - G_meas||_F / ||G_meas||_F`` and
    ``||sqrt(G_var)||_F / ||G_meas||_F`` (the error a perfect model would show
    is about this noise level), over the outputs both hold.

    Attributes
    ----------
    outputs : tuple of str
    per_line, noise_per_line : (n_f,) arrays (noise: NaN without G_var)
    mean, median, noise_mean : float
    """

    outputs: tuple[str, ...]
    per_line: np.ndarray
    noise_per_line: np.ndarray
    mean: float
    median: float
    noise_mean: float

    @property
    def ratio_to_noise(self) -> float:
        """Mean error over mean noise level (about 1 for a model right within the noise)."""
        return self.mean / self.noise_mean

    def summary(self) -> dict:
        return {
            "outputs": list(self.outputs),
            "mean": self.mean,
            "median": self.median,
            "noise_mean": self.noise_mean,
            "ratio_to_noise": self.ratio_to_noise,
        }


def prediction_error(G_pred: np.ndarray, outputs, data, *, f_max_hz: float | None = None):
    """Error of a prediction ``G_pred`` (n_f, len(outputs), n_u) against FRF ``data``.

    Parameters
    ----------
    G_pred : (n_f, n_o, n_u) complex array on ``data.freq`` and ``data.input_names``
    outputs : sequence of str
        Names of ``G_pred``'s outputs; only those the data has are scored.
    data : FrfData
    f_max_hz : float, optional
        Score lines up to this frequency only (Hz).

    Returns
    -------
    PredictionError or None
        None when the data has none of ``outputs``.
    """
    outputs = tuple(outputs)
    common = [o for o in outputs if o in data.output_names]
    if not common:
        return None
    sel = np.ones(data.freq.size, bool) if f_max_hz is None else data.freq <= f_max_hz
    if not np.any(sel):
        raise InputError(
            f"prediction error: no line at or below {f_max_hz:g} Hz (data from {data.freq[0]:g} Hz)"
        )
    idx_m = [data.output_names.index(o) for o in common]
    Gp = np.asarray(G_pred)[sel][:, [outputs.index(o) for o in common]]
    Gm = data.G[sel][:, idx_m]
    norm = np.linalg.norm(Gm, axis=(1, 2))
    err = np.linalg.norm(Gp - Gm, axis=(1, 2)) / norm
    if data.G_var is None:
        noise = np.full(err.shape, np.nan)
    else:
        noise = np.sqrt(data.G_var[sel][:, idx_m].sum((1, 2))) / norm
    return PredictionError(
        outputs=tuple(common),
        per_line=err,
        noise_per_line=noise,
        mean=float(err.mean()),
        median=float(np.median(err)),
        noise_mean=float(noise.mean()),
    )
