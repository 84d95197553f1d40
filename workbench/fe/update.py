"""FE model updating (seed 001, section 6): MAC pairing, eigen-sensitivities, regularized GN.

The measured modal data are per mode a natural frequency, a damping ratio and
the rank-one residue ``R_k = c_k b_k^T`` (n_y, n_u) at the measured outputs and
inputs (m/N/s^2). For a mass-normalized FE mode ``phi_k`` the residue is
``(C phi_k)(B^T phi_k)^T``: it carries the mass scaling (so Young's modulus and
density separate) and is independent of the sign of ``phi_k``.

Data flow::

    FEModel(alpha) --solve_modes--> lambda_k, phi_k --C, B--> f_k, R_k(FE)
    MeasuredModes --pair_modes (MAC of vec R, frequency window)--> pairs, unpaired
    residuals  (f_FE / f_meas - 1) / sigma_f,  (R_FE - R_meas) / sigma_R,
               log(alpha / alpha0) / sigma_prior
    Jacobian   d lambda / d alpha_i = phi^T (K_i - lambda M_i) phi,
               d phi / d alpha_i from the bordered (Nelson-type) system, exact for distinct modes
    Gauss-Newton in x = log(alpha / alpha0) with step halving -> alpha, std (from J^T J)

References
----------
M.I. Friswell, J.E. Mottershead, Finite Element Model Updating in Structural
Dynamics, 1995, ch. 6-7 (sensitivity method, regularization toward the nominal).
R.B. Nelson, Simplified calculation of eigenvector derivatives, AIAA J. 14 (1976).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from workbench.core.arrays import readonly
from workbench.core.errors import InputError

from .eigen import Modes, solve_modes
from .model import FEModel

__all__ = [
    "MeasuredModes",
    "UpdateResult",
    "eigen_sensitivities",
    "mac_matrix",
    "pair_aliases",
    "pair_modes",
    "fe_residues",
    "update_fe",
]


@dataclass(frozen=True)
class MeasuredModes:
    """Measured modal parameters.

    Attributes
    ----------
    freq_hz : (n_m,) array
        Natural frequencies, Hz.
    damping : (n_m,) array
        Damping ratios.
    residues : (n_m, n_y, n_u) array
        Real rank-one residues ``c_k b_k^T``, m/N/s^2 (output per input force).
    output_names, input_names : tuple of str
        Channels of the residues, matched to the FE file by name.
    freq_std_hz : (n_m,) array or None
        Standard deviations of the frequencies (from the modal fit), Hz.
    residue_std : (n_m, n_y, n_u) array or None
        Standard deviations of the residue elements.
    """

    freq_hz: np.ndarray
    damping: np.ndarray
    residues: np.ndarray
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    freq_std_hz: np.ndarray | None = None
    residue_std: np.ndarray | None = None

    def __post_init__(self):
        f = readonly(self.freq_hz, float).reshape(-1)
        d = readonly(self.damping, float).reshape(-1)
        R = readonly(self.residues, float)
        if R.shape != (f.size, len(self.output_names), len(self.input_names)) or d.shape != f.shape:
            raise InputError(
                f"measured modes: expected residues ({f.size}, {len(self.output_names)}, "
                f"{len(self.input_names)}) and damping ({f.size},), got {R.shape}, {d.shape}"
            )
        if np.any(f <= 0) or not np.all(np.isfinite(R)):
            raise InputError("measured modes: expected frequencies > 0 Hz and finite residues")
        object.__setattr__(self, "freq_hz", f)
        object.__setattr__(self, "damping", d)
        object.__setattr__(self, "residues", R)
        for key, shape in (("freq_std_hz", f.shape), ("residue_std", R.shape)):
            v = getattr(self, key)
            if v is None:
                continue
            v = readonly(v, float)
            if v.shape != shape or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise InputError(
                    f"measured modes: expected {key} of shape {shape}, finite, >= 0, got {v.shape}"
                )
            object.__setattr__(self, key, v)
        object.__setattr__(self, "output_names", tuple(self.output_names))
        object.__setattr__(self, "input_names", tuple(self.input_names))

    @classmethod
    def from_fit(cls, fit) -> MeasuredModes:
        """The measured modes of a :class:`workbench.modal.fit.ModalFit`.

        Residues ``c_k b_k^T`` (the scale split between ``c_k`` and ``b_k`` drops
        out); their standard deviations ``c_std |b|`` (``b_k`` is pivoted to 1 at
        its largest entry, so the residue's uncertainty is carried by ``c_k``).
        """
        return cls(
            fit.freq_hz,
            fit.damping,
            fit.c[:, :, None] * fit.b[:, None, :],
            fit.model.output_names,
            fit.model.input_names,
            freq_std_hz=fit.freq_std_hz,
            residue_std=fit.c_std[:, :, None] * np.abs(fit.b[:, None, :]),
        )


def eigen_sensitivities(
    fe: FEModel, modes: Modes, alpha=None, *, shapes: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """Derivatives of eigenvalues and mass-normalized mode shapes with respect to alpha.

    Returns
    -------
    dlam : (k, p) array
        ``d lambda_k / d alpha_i = phi_k^T (K_i - lambda_k M_i) phi_k``, (rad/s)^2 per unit.
    dPhi : (p, n, k) array or None
        ``d phi_k / d alpha_i``: solution of the bordered system
        ``[[K - lambda M, M phi], [phi^T M, 0]] [v; mu] = [-(K_i - lambda M_i) phi + dlambda M phi;
        -phi^T M_i phi / 2]`` (keeps ``phi^T M phi = 1``), exact for a distinct eigenvalue.
    """
    K, M = fe.matrices(alpha)
    Phi, lam = modes.Phi, modes.lam
    KiPhi = np.einsum("inm,mk->ink", fe.K_i, Phi)  # (p, n, k)
    MiPhi = np.einsum("inm,mk->ink", fe.M_i, Phi)
    kq = np.einsum("nk,ink->ki", Phi, KiPhi)
    mq = np.einsum("nk,ink->ki", Phi, MiPhi)
    dlam = kq - lam[:, None] * mq
    if not shapes:
        return dlam, None
    n, k = Phi.shape
    p = fe.n_par
    dPhi = np.empty((p, n, k))
    MPhi = M @ Phi
    for j in range(k):
        A = np.zeros((n + 1, n + 1))
        A[:n, :n] = K - lam[j] * M
        A[:n, n] = MPhi[:, j]
        A[n, :n] = MPhi[:, j]
        rhs = np.zeros((n + 1, p))
        rhs[:n] = -(KiPhi[:, :, j] - lam[j] * MiPhi[:, :, j]).T + MPhi[:, [j]] * dlam[j]
        rhs[n] = -0.5 * mq[j]
        dPhi[:, :, j] = scipy.linalg.solve(A, rhs)[:n].T
    return dlam, dPhi


def mac_matrix(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """MAC between the rows of ``A`` (n_a, m) and ``B`` (n_b, m): (n_a, n_b)."""
    A = np.asarray(A).reshape(len(A), -1)
    B = np.asarray(B).reshape(len(B), -1)
    num = np.abs(np.conj(A) @ B.T) ** 2
    den = np.outer(np.sum(np.abs(A) ** 2, 1), np.sum(np.abs(B) ** 2, 1))
    return num / np.where(den > 0, den, np.inf)


def fe_residues(fe: FEModel, Phi: np.ndarray, out_idx, in_idx) -> np.ndarray:
    """Residues ``(C phi_k)(B^T phi_k)^T`` of FE modes at chosen outputs/inputs, (k, n_y, n_u)."""
    c = (fe.C[out_idx] @ Phi).T
    b = (fe.B[:, in_idx].T @ Phi).T
    return c[:, :, None] * b[:, None, :]


def pair_modes(
    meas: MeasuredModes,
    fe_freq_hz: np.ndarray,
    fe_res: np.ndarray,
    *,
    mac_min: float = 0.8,
    freq_window: float = 0.3,
) -> tuple[list[tuple[int, int]], list[int], np.ndarray]:
    """One-to-one pairing of measured and FE modes by the MAC of their residues.

    A measured mode pairs only with an FE mode within ``freq_window`` (relative)
    in frequency and with MAC >= ``mac_min``; best MAC first. A measured mode with
    no such partner (an in-plane mode seen by a tilted sensor, absent from an
    out-of-plane FE model) is left unpaired, never forced onto an FE mode.

    Returns
    -------
    pairs : list of (i_measured, k_fe), by measured index
    unpaired : list of measured indices
    mac : (n_m, n_fe) array
    """
    mac = mac_matrix(meas.residues, fe_res)
    close = np.abs(fe_freq_hz[None, :] / meas.freq_hz[:, None] - 1.0) <= freq_window
    score = np.where(close & (mac >= mac_min), mac, -1.0)
    pairs = []
    used_m, used_f = set(), set()
    for flat in np.argsort(-score, axis=None):
        i, k = np.unravel_index(flat, score.shape)
        if score[i, k] < 0:
            break
        if i in used_m or k in used_f:
            continue
        pairs.append((int(i), int(k)))
        used_m.add(i)
        used_f.add(k)
    pairs.sort()
    unpaired = [i for i in range(meas.freq_hz.size) if i not in used_m]
    return pairs, unpaired, mac


def pair_aliases(
    meas: MeasuredModes,
    unpaired,
    fe_freq_hz: np.ndarray,
    mac: np.ndarray,
    fs: float,
    *,
    mac_min: float = 0.8,
    window: float = 0.02,
) -> list[tuple[int, int]]:
    """Unpaired measured modes that are sampled images of FE modes above Nyquist.

    A mode at ``f > fs / 2`` of a plant sampled without an anti-aliasing filter
    shows in the measured FRF at its image ``|f - m fs|`` (nearest multiple m):
    the 1239 Hz mode of a beam sampled at 2048 Hz appears as a mode at 809 Hz.
    It pairs when the image is within ``window`` (relative) of the measured
    frequency and the residue MAC is at least ``mac_min``.

    Returns
    -------
    list of (i_measured, k_fe)
    """
    f = np.asarray(fe_freq_hz, float)
    image = np.abs(f - np.round(f / fs) * fs)
    above = f > fs / 2
    out, used = [], set()
    for i in unpaired:
        close = above & (np.abs(image / meas.freq_hz[i] - 1.0) <= window) & (mac[i] >= mac_min)
        close[list(used)] = False
        if np.any(close):
            k = int(np.flatnonzero(close)[np.argmax(mac[i, close])])
            out.append((int(i), k))
            used.add(k)
    return out


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of :func:`update_fe`.

    Attributes
    ----------
    alpha, alpha_std : (p,) arrays
        Updated parameters and their standard deviations (SI units).
    alpha_nominal : (p,) array
    pairs : tuple of (i_measured, k_fe); unpaired : tuple of measured indices
    aliased : tuple of (i_measured, k_fe)
        Measured modes that are sampled images of FE modes above Nyquist
        (:func:`pair_aliases`; only with ``fs``): not in the fit, not unpaired;
        they give those FE modes their damping.
    freq_measured_hz : (n_m,) array
    freq_before_hz, freq_after_hz : (n_fe,) arrays
        FE frequencies at the nominal and updated alpha.
    mac : (n_m, n_fe) array
        MAC after the update.
    damping : (n_d,) array
        Damping of the first ``n_d`` FE modes for the updated file: the measured
        value of a paired mode, the file's value otherwise (a scalar file damping
        is written out for all n modes; a list is lengthened to the last paired mode).
    cost : float
        Final weighted least-squares cost (half the sum of squared whitened residuals).
    n_iter : int
    notes : tuple of str
    """

    alpha: np.ndarray
    alpha_std: np.ndarray
    alpha_nominal: np.ndarray
    pairs: tuple
    unpaired: tuple
    freq_measured_hz: np.ndarray
    freq_before_hz: np.ndarray
    freq_after_hz: np.ndarray
    mac: np.ndarray
    damping: np.ndarray
    cost: float
    n_iter: int
    notes: tuple[str, ...] = field(default=())
    aliased: tuple = ()

    def report(self, parameter_names) -> dict:
        """JSON-ready report: parameters before/after +- std, paired modes, MAC, unpaired."""
        return {
            "parameters": [
                {
                    "name": name,
                    "before": float(a0),
                    "after": float(a1),
                    "std": float(s),
                    "change_rel": float(a1 / a0 - 1),
                }
                for name, a0, a1, s in zip(
                    parameter_names, self.alpha_nominal, self.alpha, self.alpha_std, strict=True
                )
            ],
            "modes": [
                {
                    "measured_index": i,
                    "fe_index": k,
                    "freq_measured_hz": float(self.freq_measured_hz[i]),
                    "freq_before_hz": float(self.freq_before_hz[k]),
                    "freq_after_hz": float(self.freq_after_hz[k]),
                    "mac": float(self.mac[i, k]),
                    "damping": float(self.damping[k]),
                }
                for i, k in self.pairs
            ],
            "unpaired_measured": [
                {"measured_index": i, "freq_hz": float(self.freq_measured_hz[i])}
                for i in self.unpaired
            ],
            "aliased_measured": [
                {
                    "measured_index": i,
                    "freq_hz": float(self.freq_measured_hz[i]),
                    "fe_index": k,
                    "fe_freq_hz": float(self.freq_after_hz[k]),
                    "mac": float(self.mac[i, k]),
                    "damping": float(self.damping[k]),
                }
                for i, k in self.aliased
            ],
            "mac": self.mac.tolist(),
            "cost": self.cost,
            "iterations": self.n_iter,
            "notes": list(self.notes),
        }

    def table_text(self, parameter_names) -> str:
        """Parameters and paired modes before / after, unpaired measured modes (text)."""
        rep = self.report(parameter_names)
        lines = [f"{'parameter':<28}{'before':>14}{'after':>14}{'std':>12}"]
        for p in rep["parameters"]:
            lines.append(f"{p['name']:<28}{p['before']:>14.6g}{p['after']:>14.6g}{p['std']:>12.3g}")
        lines.append(f"{'mode':>4}{'measured Hz':>14}{'before Hz':>12}{'after Hz':>12}{'MAC':>7}")
        for m in rep["modes"]:
            lines.append(
                f"{m['fe_index']:>4}{m['freq_measured_hz']:>14.3f}{m['freq_before_hz']:>12.3f}"
                f"{m['freq_after_hz']:>12.3f}{m['mac']:>7.3f}"
            )
        for u in rep["unpaired_measured"]:
            lines.append(f"unpaired measured mode at {u['freq_hz']:.2f} Hz (no FE partner)")
        for a in rep["aliased_measured"]:
            lines.append(
                f"measured mode at {a['freq_hz']:.2f} Hz = sampled image of FE mode "
                f"{a['fe_index']} at {a['fe_freq_hz']:.2f} Hz (MAC {a['mac']:.3f}; damping "
                f"{a['damping']:.4f} carried)"
            )
        return "\n".join(lines)


def update_fe(
    fe: FEModel,
    meas: MeasuredModes,
    *,
    prior_rel: float = 0.5,
    freq_rel_std: float = 1e-3,
    residue_rel_std: float = 0.05,
    mac_min: float = 0.8,
    freq_window: float = 0.3,
    max_iter: int = 40,
    fs: float | None = None,
) -> UpdateResult:
    """Regularized Gauss-Newton update of alpha on measured modal data.

    Parameters
    ----------
    fe : FEModel
        Its ``alpha`` is the nominal (prior mean).
    meas : MeasuredModes
        Channels matched to ``fe`` by name (a name the file lacks is refused).
    prior_rel : float
        Prior standard deviation of ``log(alpha / alpha_nominal)`` (relative
        spread of each parameter): the regularization toward the nominal.
    freq_rel_std : float
        Relative standard deviation of a measured frequency (when ``meas``
        gives none; floor of the given ones: 1e-2 of this).
    residue_rel_std : float
        Standard deviation of a residue element relative to the mode's RMS
        element (when ``meas`` gives none; floor of the given ones: 1e-2 of this,
        so a tiny element's std does not dominate).
    mac_min, freq_window : float
        Pairing rule of :func:`pair_modes`.
    max_iter : int
        Gauss-Newton iterations.
    fs : float, optional
        Sampling frequency (Hz) of the experiment behind ``meas``: measured
        modes left unpaired are checked for being sampled images of FE modes
        above Nyquist (:func:`pair_aliases`); such a mode gives its FE mode the
        damping of the same decay rate, ``zeta_k = zeta_i f_i / f_k``.
    """
    out_idx = fe.output_index(meas.output_names, "measured modes")
    in_idx = fe.input_index(meas.input_names, "measured modes")
    a0 = np.asarray(fe.alpha, float)
    if np.any(a0 <= 0):
        raise InputError(f"FE model: alpha: expected nominal values > 0 to update, got {a0}")
    n_fe = int(min(fe.n_dof, max(2 * meas.freq_hz.size + 4, 20)))
    Bo, Bi = fe.C[out_idx], fe.B[:, in_idx]

    def evaluate(x, jac: bool):
        alpha = a0 * np.exp(x)
        modes = solve_modes(*fe.matrices(alpha), n_fe)
        f = modes.freq_hz
        Rf = fe_residues(fe, modes.Phi, out_idx, in_idx)
        pairs, unpaired, mac = pair_modes(meas, f, Rf, mac_min=mac_min, freq_window=freq_window)
        if not pairs:
            raise InputError(
                "update: no measured mode pairs with an FE mode (MAC >= "
                f"{mac_min} within {freq_window:.0%} in frequency); nothing to update on"
            )
        im = np.array([i for i, _ in pairs])
        kf = np.array([k for _, k in pairs])
        rms = np.sqrt(np.mean(meas.residues[im] ** 2, axis=(1, 2)))[:, None, None]
        if meas.residue_std is None:
            sR = residue_rel_std * rms * np.ones_like(meas.residues[im])
        else:
            sR = np.maximum(meas.residue_std[im], 1e-2 * residue_rel_std * rms)
        if meas.freq_std_hz is None:
            sf = freq_rel_std * np.ones(im.size)
        else:
            sf = np.maximum(meas.freq_std_hz[im] / meas.freq_hz[im], 1e-2 * freq_rel_std)
        r = [
            (f[kf] / meas.freq_hz[im] - 1.0) / sf,
            ((Rf[kf] - meas.residues[im]) / sR).ravel(),
            x / prior_rel,
        ]
        r = np.concatenate(r)
        J = None
        if jac:
            sub = Modes(modes.lam[kf], modes.Phi[:, kf])
            dlam, dPhi = eigen_sensitivities(fe, sub, alpha)
            # d f / d x_i = alpha_i d f / d alpha_i, f = sqrt(lambda) / 2 pi
            fk = np.maximum(f[kf], 1e-300)
            Jf = dlam / (8 * np.pi**2 * fk[:, None]) * alpha / meas.freq_hz[im, None] / sf[:, None]
            c = (Bo @ sub.Phi).T  # (m, n_y)
            b = (Bi.T @ sub.Phi).T  # (m, n_u)
            dc = np.einsum("yn,ink->iky", Bo, dPhi)  # (p, m, n_y)
            db = np.einsum("nu,ink->iku", Bi, dPhi)
            dR = dc[:, :, :, None] * b[None, :, None, :] + c[None, :, :, None] * db[:, :, None, :]
            JR = (dR / sR[None]).reshape(fe.n_par, -1).T * alpha
            J = np.vstack([Jf, JR, np.eye(fe.n_par) / prior_rel])
        return r, J, (alpha, f, pairs, unpaired, mac)

    x = np.zeros(fe.n_par)
    r, J, info = evaluate(x, True)
    f_before = info[1]
    cost = 0.5 * r @ r
    notes = []
    n_iter = 0
    for n_iter in range(1, max_iter + 1):  # noqa: B007 (count reported)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        t = 1.0
        while t > 1e-4:
            r_new, _, info_new = evaluate(x + t * step, False)
            if 0.5 * r_new @ r_new < cost:
                break
            t /= 2
        else:
            break
        x = x + t * step
        r, J, info = evaluate(x, True)
        new_cost = 0.5 * r @ r
        done = np.max(np.abs(t * step)) < 1e-9 or (cost - new_cost) < 1e-12 * max(cost, 1.0)
        cost = new_cost
        if done:
            break
    else:
        notes.append(f"Gauss-Newton stopped after {max_iter} iterations")
    alpha, f_after, pairs, unpaired, mac = info
    aliased = []
    if fs is not None:
        aliased = pair_aliases(meas, unpaired, f_after, mac, float(fs), mac_min=mac_min)
        unpaired = [i for i in unpaired if i not in {a for a, _ in aliased}]
    # Standard deviations from the Gauss-Newton Hessian, inflated by the
    # a-posteriori variance factor when the residuals exceed the assumed noise.
    dof = max(r.size - fe.n_par, 1)
    s2 = max(1.0, 2 * cost / dof)
    cov = np.linalg.pinv(J.T @ J) * s2
    alpha_std = alpha * np.sqrt(np.clip(np.diag(cov), 0, None))
    # the file's damping list, lengthened to cover every paired mode (a scalar in
    # the file held for every mode: it stays with every unpaired one)
    n_d = max(
        max(k for _, k in pairs + aliased) + 1,
        fe.n_dof if fe.damping_scalar else fe.damping.size,
    )
    damping = fe.mode_damping(n_d)
    fill = fe.damping[-1]
    damping = np.where(np.isnan(damping), fill, damping)
    for i, k in pairs:
        damping[k] = meas.damping[i]
    for i, k in aliased:  # the image decays as the mode does: same zeta * omega
        damping[k] = meas.damping[i] * meas.freq_hz[i] / f_after[k]
    return UpdateResult(
        alpha=readonly(alpha),
        alpha_std=readonly(alpha_std),
        alpha_nominal=readonly(a0),
        pairs=tuple(pairs),
        unpaired=tuple(unpaired),
        freq_measured_hz=readonly(meas.freq_hz),
        freq_before_hz=readonly(f_before),
        freq_after_hz=readonly(f_after),
        mac=readonly(mac),
        damping=readonly(damping),
        cost=float(cost),
        n_iter=n_iter,
        notes=tuple(notes),
        aliased=tuple(aliased),
    )
