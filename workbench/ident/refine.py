"""Maximum-likelihood refinement of a modal model on periodic data, and its Cramer-Rao bound.

Data flow::

    TimeData (periodic; open loop, or closed loop with r)
        -> periodic_spectra   per excited DFT line of r (u in open loop): the mean
                              over the steady-state periods of U and Y, and the
                              period-to-period deviations (the noise)
    ModalModel (e.g. subspace -> d2c -> modal)
        -> theta: rigid gain P, per mode (f_hz, zeta, c, b), D
        -> model on the lines: z^-d ZOH{ sum_k c_k b_k^T / (s^2 + 2 zeta_k w_k s + w_k^2)
                                          + P / s^2 + D }   (exact ZOH, d samples of delay)
        -> scipy.optimize.least_squares on the whitened output error
           sqrt(n_avg) L^-1 (Y_l - G(theta, z_l) U_l),  L L^H the noise covariance
        -> RefineResult(model, freq_std_hz, damping_std, misfit)
    modal_crb(model, spectra, noise_cov) -> CramerRao(freq_std_hz, damping_std)

Why the output error is the likelihood here, open loop and closed loop
alike: the plant satisfies ``y = G u + v`` whatever the controller does, so at
the true parameters the residual ``Y_l - G U_l`` *is* the (averaged) output
noise ``V_l``, with the covariance of the sensor noise. That covariance is
estimated from the spread of the residual over the periods, pooled over
neighbouring lines (it rises at the lowest lines, where the noise-driven,
non-periodic motion of the rigid body leaks into the DFT). In closed loop the
averaged ``U_l`` carries the controller's share of the same noise; the
estimator keeps a bias of relative order ``1 / (n_avg SNR^2)`` from it (the
direct method restricted to the excited lines), far below its standard
deviation at the signal-to-noise ratio of a precision stage. The Fisher
information of ``y`` given the known excitation ``r`` in closed loop equals
the open-loop expression with the noise-free input ``U0 = S_i R`` (derivation
in :func:`modal_crb`), which is what the bound is evaluated with.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.optimize

from workbench.core.arrays import readonly
from workbench.core.errors import InputError
from workbench.io.formats import TimeData
from workbench.modal.model import ModalModel
from workbench.modal.params import ParameterLayout, pack

__all__ = [
    "PeriodicSpectra",
    "periodic_spectra",
    "RefineResult",
    "refine_modal_model",
    "CramerRao",
    "modal_crb",
    "zoh_mode_response",
]


# ----------------------------------------------------------------- the data
@dataclass(frozen=True)
class PeriodicSpectra:
    """Period-averaged spectra of a periodic record on its excited lines.

    Attributes
    ----------
    fs : float
        Sampling frequency, Hz.
    period : int
        Samples per period; the DFT is numpy's unnormalized ``rfft`` of one period.
    freq_hz : (n_l,) array
        Frequency of each excited line, Hz (one entry per line and experiment
        block; a line excited in two blocks appears twice).
    U : (n_l, n_u) complex array
        Mean over the steady-state periods of the input DFT, N (per DFT bin).
    Y : (n_l, n_y) complex array
        Mean of the output DFT, m.
    n_avg : (n_l,) int array
        Periods averaged for each line.
    dev_line : (n_d,) int array
        Line index (into ``freq_hz``) of each period-to-period deviation.
    dU : (n_d, n_u) complex array
        Deviations ``U^(p) - U`` of the single periods from their mean, N.
    dY : (n_d, n_y) complex array
        Deviations ``Y^(p) - Y``, m.
    """

    fs: float
    period: int
    freq_hz: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    n_avg: np.ndarray
    dev_line: np.ndarray
    dU: np.ndarray
    dY: np.ndarray

    def __post_init__(self):
        f = readonly(self.freq_hz, float)
        U, Y = readonly(self.U, complex), readonly(self.Y, complex)
        n_l = f.shape[0]
        if f.ndim != 1 or U.ndim != 2 or Y.ndim != 2 or U.shape[0] != n_l or Y.shape[0] != n_l:
            raise InputError(
                f"PeriodicSpectra: expected freq_hz (n_l,), U (n_l, n_u), Y (n_l, n_y), "
                f"got {f.shape}, {U.shape}, {Y.shape}"
            )
        n_avg = readonly(self.n_avg, int)
        if n_avg.shape != (n_l,) or np.any(n_avg < 1):
            raise InputError(
                f"PeriodicSpectra.n_avg: expected ({n_l},) counts >= 1, got {n_avg.shape}"
            )
        dl = readonly(self.dev_line, int)
        dU = readonly(np.reshape(self.dU, (-1, U.shape[1])), complex)
        dY = readonly(np.reshape(self.dY, (-1, Y.shape[1])), complex)
        if dU.shape[0] != dl.shape[0] or dY.shape[0] != dl.shape[0]:
            raise InputError(
                f"PeriodicSpectra: expected dU, dY with one row per dev_line ({dl.shape[0]}), "
                f"got {dU.shape[0]} and {dY.shape[0]}"
            )
        for name, a in (("freq_hz", f), ("U", U), ("Y", Y), ("n_avg", n_avg)):
            object.__setattr__(self, name, a)
        object.__setattr__(self, "dev_line", dl)
        object.__setattr__(self, "dU", dU)
        object.__setattr__(self, "dY", dY)
        object.__setattr__(self, "fs", float(self.fs))
        object.__setattr__(self, "period", int(self.period))

    @property
    def n_lines(self) -> int:
        return self.freq_hz.shape[0]

    @property
    def n_u(self) -> int:
        return self.U.shape[1]

    @property
    def n_y(self) -> int:
        return self.Y.shape[1]

    @property
    def z(self) -> np.ndarray:
        """(n_l,) ``exp(j 2 pi f / fs)`` of each line."""
        return np.exp(2j * np.pi * self.freq_hz / self.fs)


def periodic_spectra(data: TimeData, *, n_transient: int = 1) -> PeriodicSpectra:
    """Average a periodic record over its steady-state periods, on the excited lines.

    Parameters
    ----------
    data : TimeData
        ``u`` (N, n_u) N, ``y`` (N, n_y) m, ``period`` set, ``N`` a multiple of
        it. The excited lines are those of ``r`` (closed loop) or of ``u``
        (open loop, no ``r``); a record of several experiments (blocks of
        identical periods) gives each block's lines from its own excitation.
    n_transient : int
        Periods dropped at the start of each block (transient), >= 0.

    Returns
    -------
    PeriodicSpectra
        DC and the Nyquist line are left out (their noise is not circular).

    Raises
    ------
    InputError
        Not periodic, or no block with a steady-state period.
    """
    from workbench.signals.periodic import periodic_record

    if not isinstance(data, TimeData):
        raise InputError(f"data: expected periodic TimeData, got {type(data).__name__}")
    P = data.period
    if P is None or data.n_samples < P:
        raise InputError(
            f"data: key 'period': expected a periodic record (period set, at least one period), "
            f"got period {P} for {data.n_samples} samples"
        )
    n_transient = int(n_transient)
    if n_transient < 0:
        raise InputError(f"n_transient: expected an integer >= 0, got {n_transient}")
    f_all, U_all, Y_all, n_all, dl_all, dU_all, dY_all = [], [], [], [], [], [], []
    n_l = 0
    try:
        rec = periodic_record(data, n_transient=n_transient, min_periods=1)
    except InputError:
        rec = None  # no excitation at all: refused below, with this function's message
    for b in range(0 if rec is None else rec.n_blocks):
        lines = np.flatnonzero(rec.excited[b])
        if len(lines) == 0:
            continue
        n = int(rec.n_kept[b])
        f_all.append(lines * data.fs / P)
        U_all.append(rec.U[b, lines])
        Y_all.append(rec.Y[b, lines])
        n_all.append(np.full(len(lines), n))
        if n > 1:
            dl_all.append(np.tile(n_l + np.arange(len(lines)), n))
            for dev, x, width in ((dU_all, "u", data.n_u), (dY_all, "y", data.n_y)):
                D = rec.deviation_spectra(x, b)
                D = np.zeros((n, len(lines), width), complex) if D is None else D[:, lines]
                dev.append(D.reshape(-1, width))
        n_l += len(lines)
    if not f_all:
        raise InputError(
            "data: expected a periodic excitation with excited lines after the transient "
            f"({n_transient} period(s) dropped per block), got none"
        )

    def cat(parts, width):
        return np.concatenate(parts) if parts else np.zeros((0, width), complex)

    return PeriodicSpectra(
        fs=data.fs,
        period=P,
        freq_hz=np.concatenate(f_all),
        U=np.concatenate(U_all),
        Y=np.concatenate(Y_all),
        n_avg=np.concatenate(n_all),
        dev_line=np.concatenate(dl_all) if dl_all else np.zeros(0, int),
        dU=cat(dU_all, data.n_u),
        dY=cat(dY_all, data.n_y),
    )


# ------------------------------------------------- ZOH responses of the modes
def _phi(p: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``E = exp(pT)``, ``phi = (E - 1) / p`` and ``dphi/dp``; series near p = 0."""
    p = np.asarray(p, complex)
    E = np.exp(p * T)
    small = np.abs(p * T) < 1e-6
    ps = np.where(small, 1.0, p)
    phi = np.where(small, T * (1 + p * T / 2), (E - 1) / ps)
    dphi = np.where(small, T * T / 2 * (1 + 2 * p * T / 3), (T * E * ps - (E - 1)) / ps**2)
    return E, phi, dphi


def _h(p, z, T):
    """ZOH response ``phi(p) / (z - exp(pT))`` of ``1 / (s - p)`` and its p-derivative."""
    E, phi, dphi = _phi(p, T)
    den = z - E
    return phi / den, dphi / den + phi * T * E / den**2


def zoh_mode_response(
    omega: float, zeta: float, z: np.ndarray, T: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZOH-sampled response of ``1 / (s^2 + 2 zeta omega s + omega^2)`` and its derivatives.

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s (> 0).
    zeta : float
        Damping ratio, ``0 <= zeta < 1``.
    z : (n_l,) complex array
        Points ``exp(j w T)`` on the unit circle.
    T : float
        Sampling period, s.

    Returns
    -------
    g, g_omega, g_zeta : (n_l,) complex arrays
        The response, its derivative by ``omega`` (per rad/s) and by ``zeta``.

    Notes
    -----
    With poles ``p, q = -zeta omega +- j omega sqrt(1 - zeta^2)``,
    ``1 / ((s - p)(s - q)) = (1/(s - p) - 1/(s - q)) / (p - q)`` and the ZOH maps
    ``1 / (s - p)`` to ``h(p) = (e^{pT} - 1) / (p (z - e^{pT}))`` exactly, so
    ``g = (h(p) - h(q)) / (p - q)``; derivatives by the chain rule through
    ``sigma = -zeta omega`` and ``omega_d = omega sqrt(1 - zeta^2)``.

    Examples
    --------
    >>> import numpy as np, control
    >>> z = np.exp(1j * np.array([0.3, 1.2]))
    >>> g, _, _ = zoh_mode_response(2000.0, 0.05, z, 2e-4)
    >>> sysd = control.c2d(control.tf([1], [1, 200.0, 4e6]), 2e-4)
    >>> bool(np.allclose(g, sysd(z)))
    True
    """
    z = np.asarray(z, complex)
    sq = np.sqrt(complex(1 - zeta * zeta))
    sigma, wd = -zeta * omega, omega * sq
    p, q = sigma + 1j * wd, sigma - 1j * wd
    hp, dhp = _h(p, z, T)
    hq, dhq = _h(q, z, T)
    d = p - q
    g = (hp - hq) / d
    g_p = dhp / d - (hp - hq) / d**2
    g_q = -dhq / d + (hp - hq) / d**2
    g_sigma = g_p + g_q
    g_wd = 1j * (g_p - g_q)
    g_omega = -zeta * g_sigma + sq * g_wd
    g_zeta = -omega * g_sigma - omega * zeta / sq * g_wd
    return g, g_omega, g_zeta


def _zoh_rigid(z: np.ndarray, T: float) -> np.ndarray:
    """ZOH of ``1 / s^2``: ``T^2 (z + 1) / (2 (z - 1)^2)``."""
    return T * T * (z + 1) / (2 * (z - 1) ** 2)


# ------------------------------------------------------ the model on the lines
def _model_jacobian(lay: ParameterLayout, theta, z, U, T, delay):
    """``G(theta, z_l) U_l`` (n_l, n_y) and its Jacobian (n_l, n_y, n_par), with z^-delay."""
    n_l = z.shape[0]
    n_y, n_u = lay.n_y, lay.n_u
    GU = np.zeros((n_l, n_y), complex)
    J = np.zeros((n_l, n_y, lay.n_par), complex)
    rows = np.arange(n_y)
    for kind, sl in zip(lay.kinds, lay.slices):
        if kind == "rigid_full":
            P = theta[sl["P"]].reshape(n_y, n_u)
            g = _zoh_rigid(z, T)
            GU += g[:, None] * (U @ P.T)
            idx = np.arange(sl["P"].start, sl["P"].stop).reshape(n_y, n_u)
            for i in range(n_y):
                J[:, i, idx[i]] = g[:, None] * U
            continue
        c, b = theta[sl["c"]], theta[sl["b"]]
        beta = U @ b  # (n_l,)
        if kind == "rigid":
            g = _zoh_rigid(z, T)
        elif kind == "flexible":
            f, zeta = theta[sl["f"]][0], theta[sl["zeta"]][0]
            g, g_w, g_z = zoh_mode_response(2 * np.pi * f, zeta, z, T)
            J[:, :, sl["f"].start] = np.outer(beta * g_w * 2 * np.pi, c)
            J[:, :, sl["zeta"].start] = np.outer(beta * g_z, c)
        else:
            s = theta[sl["s"]][0]
            g, g_s = _h(np.full(z.shape, s, complex), z, T)
            J[:, :, sl["s"].start] = np.outer(beta * g_s, c)
        GU += np.outer(beta * g, c)
        ci = np.arange(sl["c"].start, sl["c"].stop)
        J[:, rows, ci] = (beta * g)[:, None]
        J[:, :, sl["b"]] = c[None, :, None] * (U * g[:, None])[:, None, :]
    if lay.d_slice is not None:
        Dm = theta[lay.d_slice].reshape(n_y, n_u)
        GU += U @ Dm.T
        idx = np.arange(lay.d_slice.start, lay.d_slice.stop).reshape(n_y, n_u)
        for i in range(n_y):
            J[:, i, idx[i]] = U
    zd = z ** (-int(delay))
    return GU * zd[:, None], J * zd[:, None, None]


def _covariance(Jr: np.ndarray) -> np.ndarray:
    """``(2 Jr^T Jr)^+`` with column scaling; the b/c scale of each mode is a null direction."""
    F = 2.0 * Jr.T @ Jr
    d = np.sqrt(np.clip(np.diag(F), 1e-300, None))
    Fs = F / np.outer(d, d)
    return np.linalg.pinv(Fs, rcond=1e-10, hermitian=True) / np.outer(d, d)


def _whiteners(C: np.ndarray) -> np.ndarray:
    """Inverse Cholesky factors (n_l, n_y, n_y) of Hermitian covariances C (n_l, n_y, n_y).

    A covariance that is zero (noise-free data) gives the identity; a
    singular one is lifted to ``1e-12`` of its largest eigenvalue.
    """
    C = 0.5 * (C + np.conj(np.swapaxes(C, 1, 2)))
    n_y = C.shape[1]
    lam = np.linalg.eigvalsh(C)  # (n_l, n_y), ascending
    top = lam[:, -1]
    zero = ~(top > 0)
    lift = np.where(zero, 1.0, np.maximum(0.0, 1e-12 * top - lam[:, 0]))
    C = np.where(zero[:, None, None], 0.0, C) + lift[:, None, None] * np.eye(n_y)
    L = np.linalg.cholesky(C)
    return np.linalg.inv(L)


def _local_noise(
    spec: PeriodicSpectra, G_lines: np.ndarray, n_window: int, level_dof: int = 24
) -> tuple[np.ndarray, np.ndarray] | None:
    """Covariance (n_l, n_y, n_y) of one period's output error ``dY - G dU`` near each line.

    The sample covariance over the periods, pooled over the ``n_window``
    lines nearest in frequency (a window widened until it holds at least
    ``3 n_y`` degrees of freedom), then scaled per line to the level
    ``tr(C^-1 S) / (n_y dof)`` of the fewest nearest lines that hold
    ``level_dof`` complex samples (``n_y`` per degree of freedom), so that the weights
    follow a noise level that changes with frequency: coloured noise in open
    loop, and the leakage of the noise-driven, non-periodic motion through the
    rigid-body modes at the lowest lines in closed loop.

    Also returns ``kappa`` (n_l,), the bias of the estimate's inverse,
    ``E[C_hat^-1] ~= kappa C^-1``: the pooled sample covariance is complex
    Wishart with ``nu`` degrees of freedom (``E[W^-1] = Sigma^-1 / (nu - n_y)``,
    so its inverse is biased by ``nu / (nu - n_y)`` in shape), and the level
    is a mean of ``m = n_y dof`` unit exponentials (Gamma, ``E[1/level] =
    m / (m - 1)``); ``kappa`` is their product. With 5 periods (4 steady, 3
    degrees of freedom per line) it is about 1.06 on the stage, with 4 periods
    about 1.10.
    """
    if spec.dev_line.size == 0:
        return None
    G_dev = G_lines[spec.dev_line]
    dE = spec.dY - np.einsum("dij,dj->di", G_dev, spec.dU)
    n_l, n_y = spec.n_lines, spec.n_y
    S = np.zeros((n_l, n_y, n_y), complex)
    np.add.at(S, spec.dev_line, dE[:, :, None] * dE[:, None, :].conj())
    dof = np.zeros(n_l)
    np.add.at(dof, spec.dev_line, 1.0)
    dof = np.maximum(dof - (dof > 0), 0.0)  # n_avg - 1 per line with deviations
    order = np.argsort(spec.freq_hz, kind="stable")
    cS = np.concatenate([np.zeros((1, n_y, n_y), complex), np.cumsum(S[order], axis=0)])
    cd = np.concatenate([[0.0], np.cumsum(dof[order])])
    if cd[-1] <= 0:
        return None
    per_line = cd[-1] / n_l
    w = int(min(n_l, max(n_window, np.ceil(3 * n_y / max(per_line, 1e-12)))))
    lo = np.clip(np.arange(n_l) - w // 2, 0, n_l - w)
    hi = lo + w
    nu = cd[hi] - cd[lo]  # complex degrees of freedom of each pooled covariance
    C_sorted = (cS[hi] - cS[lo]) / np.maximum(nu, 1.0)[:, None, None]
    # the level of each line relative to its window's shape, over a few lines:
    # the noise rises steeply at the lowest lines, faster than a wide window follows
    Winv = _whiteners(C_sorted)
    q = np.real(np.einsum("lij,ljk,lik->l", Winv, S[order], Winv.conj()))  # tr(C^-1 S_l)
    cq = np.concatenate([[0.0], np.cumsum(q)])
    v = int(min(n_l, max(1, np.ceil(level_dof / (n_y * max(per_line, 1e-12))))))
    lo = np.clip(np.arange(n_l) - v // 2, 0, n_l - v)
    hi = lo + v
    m = n_y * (cd[hi] - cd[lo])  # unit exponentials behind each level
    level = np.where(m > 0, (cq[hi] - cq[lo]) / np.maximum(m, 1.0), 1.0)
    C = np.empty_like(C_sorted)
    C[order] = C_sorted * np.maximum(level, 1e-12)[:, None, None]
    kappa = np.empty(n_l)
    kappa[order] = np.where(nu > n_y + 1, nu / np.maximum(nu - n_y, 1.0), 1.0) * np.where(
        m > 2, m / np.maximum(m - 1, 1.0), 1.0
    )
    return C, kappa


def _frf_on(lay: ParameterLayout, theta, z, T, delay, n_u) -> np.ndarray:
    """The model's discrete FRF (n, n_y, n_u) at z, delay included."""
    cols = []
    for j in range(n_u):
        e = np.zeros((z.shape[0], n_u))
        e[:, j] = 1.0
        cols.append(_model_jacobian(lay, theta, z, e, T, delay)[0])
    return np.stack(cols, axis=2)


def _check_model(model, spec: PeriodicSpectra):
    if not isinstance(model, ModalModel):
        raise InputError(f"model: expected a ModalModel, got {type(model).__name__}")
    if model.n_u != spec.n_u or model.n_y != spec.n_y:
        raise InputError(
            f"model: expected {spec.n_y} outputs x {spec.n_u} inputs like the data, "
            f"got {model.n_y} x {model.n_u}"
        )
    for k, m in enumerate(model.modes):
        if m.kind == "flexible" and not 0 <= m.damping < 1:
            raise InputError(
                f"model: mode {k + 1}: expected a damping ratio in [0, 1) for a flexible "
                f"mode, got {m.damping}"
            )


#: z-score above which the first steady period is taken to hold a transient
TRANSIENT_Z = 5.0


def _transient_excess(spec: PeriodicSpectra, G_lines: np.ndarray, n_band: int) -> float:
    """How far the first steady period's deviations exceed the others', in standard errors.

    Stationary noise gives every period's deviation from the mean the same
    expected whitened power; a start transient that has not died out by the
    first kept period makes that period's larger. Per band of ``n_band``
    lines nearest in frequency, the ratio of the first period's whitened
    power to the mean over all periods, as ``(ratio - 1) sqrt(n_y k)`` (``k``
    lines in the band; the ratio of a Gamma(``n_y k``) variable to its mean
    has a standard deviation of about ``1 / sqrt(n_y k)``); the largest over
    the bands. 0 without deviations.
    """
    est = _local_noise(spec, G_lines, n_band)
    if est is None:
        return 0.0
    dl = spec.dev_line
    dE = spec.dY - np.einsum("dij,dj->di", G_lines[dl], spec.dU)
    W = _whiteners(est[0])
    power = np.sum(np.abs(np.einsum("dij,dj->di", W[dl], dE)) ** 2, axis=1)
    # rows of one line come period by period (periodic_spectra): rank = period index
    order = np.argsort(dl, kind="stable")
    first_row = np.r_[True, dl[order][1:] != dl[order][:-1]]
    n_l = spec.n_lines
    p_first, p_all, count = np.zeros(n_l), np.zeros(n_l), np.zeros(n_l)
    np.add.at(p_first, dl[order][first_row], power[order][first_row])
    np.add.at(p_all, dl, power)
    np.add.at(count, dl, 1.0)
    has = count > 1
    lines = np.flatnonzero(has)[np.argsort(spec.freq_hz[has], kind="stable")]
    worst = 0.0
    for b in range(0, len(lines), max(int(n_band), 1)):
        k = lines[b : b + max(int(n_band), 1)]
        mean_all = np.sum(p_all[k] / count[k])
        if mean_all > 0:
            ratio = np.sum(p_first[k]) / mean_all
            worst = max(worst, (ratio - 1.0) * np.sqrt(spec.n_y * len(k)))
    return float(worst)


def _drop_transient(spec, data, lay, theta, input_delay, n_transient, n_band, notes):
    """Drop further start periods while the first steady one holds a transient.

    Only for TimeData (spectra cannot be recomputed) and while at least two
    steady periods remain; what was done, or could not be, goes to ``notes``.
    """
    T = 1.0 / spec.fs

    def excess(sp):
        return _transient_excess(sp, _frf_on(lay, theta, sp.z, T, input_delay, sp.n_u), n_band)

    z0 = zt = excess(spec)
    n_drop = n_transient
    while zt > TRANSIENT_Z and isinstance(data, TimeData) and spec.n_avg.min() >= 3:
        n_drop += 1
        spec = periodic_spectra(data, n_transient=n_drop)
        zt = excess(spec)
    if n_drop > n_transient:
        notes.append(
            f"a start transient leaked into the first steady period (its deviations "
            f"{z0:.1f} standard errors above the others'): {n_drop} periods dropped per "
            f"block instead of {n_transient}"
        )
    if zt > TRANSIENT_Z:
        notes.append(
            f"a transient leaks into the first steady period ({zt:.1f} standard errors): "
            "the standard deviations may be optimistic; record more periods or raise "
            "n_transient"
        )
    return spec


def _as_spectra(data, n_transient) -> PeriodicSpectra:
    if isinstance(data, PeriodicSpectra):
        return data
    return periodic_spectra(data, n_transient=n_transient)


def _line_cov(spec: PeriodicSpectra, noise_cov) -> np.ndarray:
    """Single-period DFT covariance (n_y, n_y) from a per-sample covariance of white noise."""
    S = np.asarray(noise_cov, float)
    if S.ndim == 1:
        S = np.diag(S)
    if S.shape != (spec.n_y, spec.n_y):
        raise InputError(
            f"noise_cov: expected ({spec.n_y}, {spec.n_y}) (or ({spec.n_y},) variances), "
            f"got {S.shape}"
        )
    return spec.period * S.astype(complex)


# ------------------------------------------------------------ the estimator
@dataclass(frozen=True)
class RefineResult:
    """A modal model refined by maximum likelihood on periodic data.

    Attributes
    ----------
    model : ModalModel
        The refined continuous modal model (rigid, flexible by frequency,
        real); ``transform`` is None (no source realization).
    start : ModalModel
        The model it started from.
    freq_std_hz : (n_modes,) array
        Standard deviation of each mode's frequency, Hz (NaN for rigid
        modes): the inverse Fisher information at the estimate with the
        estimated noise, times ``variance_factor``.
    damping_std : (n_modes,) array
        Same for the damping ratio, - (NaN for rigid modes).
    misfit : float
        Weighted cost over its expected value under the noise alone,
        ``sum |w|^2 / (n_l n_y - n_par / 2)``; about 1 when the model explains
        the data to the noise level.
    n_lines : int
        Excited lines (and experiment blocks) used.
    noise_cov : (n_l, n_y, n_y) array
        Noise covariance behind the weights of each line, as the per-sample
        covariance of a white noise of the same level (one period's DFT
        covariance / period), m^2; estimated from the period-to-period spread
        unless given (the sample estimate; the weights use ``kappa`` times it,
        see :func:`refine_modal_model`).
    input_delay : int
        Samples of delay of the model.
    success : bool
        The optimizer's convergence flag.
    message : str
        The optimizer's message.
    nfev : int
        Function evaluations.
    notes : tuple of str
    variance_factor : float
        What the inverse Fisher information was multiplied by for the
        standard deviations: ``kappa max(1, misfit)``, ``kappa`` the bias of
        the inverse of a noise covariance estimated from few periods
        (1 for a given ``noise_cov``; see :func:`refine_modal_model`).
    """

    model: ModalModel
    start: ModalModel
    freq_std_hz: np.ndarray
    damping_std: np.ndarray
    misfit: float
    n_lines: int
    noise_cov: np.ndarray
    input_delay: int
    success: bool
    message: str
    nfev: int
    notes: tuple[str, ...] = field(default=())
    variance_factor: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "freq_std_hz", readonly(self.freq_std_hz, float))
        object.__setattr__(self, "damping_std", readonly(self.damping_std, float))
        object.__setattr__(self, "noise_cov", readonly(np.real(self.noise_cov), float))


def refine_modal_model(
    model: ModalModel,
    data: TimeData | PeriodicSpectra,
    *,
    input_delay: int = 0,
    feedthrough: bool = True,
    noise_cov: np.ndarray | None = None,
    n_transient: int = 1,
    noise_lines: int = 61,
    reweight: int = 1,
    max_nfev: int = 200,
) -> RefineResult:
    """Maximum-likelihood refinement of a modal model on a periodic record.

    Parameters
    ----------
    model : ModalModel
        Start, e.g. ``ModalModel.from_statespace(identify_subspace(...).model)``;
        its modes (kinds and count) are kept, their parameters refined.
    data : TimeData or PeriodicSpectra
        Periodic record, open or closed loop (``period`` set; ``r`` for
        closed loop); or its :func:`periodic_spectra`.
    input_delay : int
        Samples of pure delay between ``u`` and ``y`` not in ``model``
        (``SubspaceResult.input_delay``), >= 0.
    feedthrough : bool
        Estimate ``D`` (n_y, n_u); else keep the start's ``D``.
    noise_cov : (n_y, n_y) or (n_y,) array, optional
        Per-sample covariance (or variances) of the white output noise, m^2.
        Default: estimated from the spread of the output error over the
        steady-state periods, pooled over the ``noise_lines`` lines nearest in
        frequency (needs >= 2 steady periods).
    noise_lines : int
        Lines pooled for each local noise covariance (widened to at least
        ``3 n_y`` degrees of freedom).
    n_transient : int
        Periods dropped per block when ``data`` is TimeData; one more at a
        time while the first steady period still holds a start transient
        (Notes), as long as two steady periods remain.
    reweight : int
        Times the noise covariance is re-estimated at the new estimate and the
        fit repeated (0: weights from the start model only).
    max_nfev : int
        Function evaluations per fit.

    Returns
    -------
    RefineResult

    Raises
    ------
    InputError
        Mismatched dimensions, non-periodic data, no noise covariance
        available (a single steady period and no ``noise_cov``).

    Notes
    -----
    Per excited line ``l`` (frequency ``f_l``, ``z_l = exp(j 2 pi f_l / fs)``)
    the model is ``G(theta, z) = z^-d [P g_r(z) + sum_k c_k b_k^T g_k(z) + D]``
    with ``g_r`` the ZOH of ``1/s^2`` and ``g_k`` that of
    ``1/(s^2 + 2 zeta_k w_k s + w_k^2)`` (:func:`zoh_mode_response`), so the
    continuous modal parameters are estimated directly from sampled data. The
    cost is the negative log-likelihood of circular complex Gaussian noise,

    ``V(theta) = sum_l n_l e_l^H C^-1 e_l``,  ``e_l = Y_l - G(theta, z_l) U_l``,

    minimized by Levenberg-Marquardt (``scipy.optimize.least_squares``,
    ``method="lm"``) with the analytic Jacobian. ``C`` is the covariance of
    one period's DFT of the output noise. Rigid modes enter through their
    total gain ``P`` (n_y, n_u), linear, when there are at least
    ``min(n_u, n_y)`` of them (then split back per output DOF, as
    :meth:`ModalModel.from_statespace` does); otherwise each has its own
    ``c_k, b_k``. The scale split between ``c_k`` and ``b_k`` is a null
    direction of the Jacobian; the result is normalized to ``|b_k| = |c_k|``.

    Noise estimated from few periods (the default, no ``noise_cov``): the
    sample covariance ``C_hat`` of ``M`` steady periods is unbiased, but its
    inverse is not, ``E[C_hat^-1] = kappa C^-1`` with ``kappa > 1`` (complex
    inverse Wishart; about 1.06 for the stage's 4 steady periods pooled over
    61 lines, :func:`_local_noise`), and weights ``C_hat^-1`` made the
    weighted misfit read about ``kappa`` and the inverse Fisher information
    too small by ``1 / kappa``. The weights are ``(kappa C_hat)^-1``
    (unbiased), and since the weights' own scatter costs efficiency (the
    sample maximum likelihood estimator of Schoukens, Pintelon & Rolain 1997
    loses efficiency with the periods' degrees of freedom; to first order by
    the relative variance of the weights, which is again about ``kappa - 1``),
    the reported variances are the inverse Fisher information times
    ``kappa``, checked by Monte Carlo in ``tests/test_refine_coverage.py``
    and ``benchmarks/bench_refine_mc.py``; times the misfit as well
    when it exceeds 1 (residuals larger than the noise model, the
    a-posteriori variance factor), so that the standard deviations are never
    narrowed by it. ``RefineResult.variance_factor`` holds the product.

    Start transient: stationary noise gives each steady period's deviation
    from the mean the same expected whitened power. When the first kept
    period's exceeds the others' by more than ``TRANSIENT_Z`` standard errors
    in some band of ``noise_lines`` lines (a loop pole slow against the
    period leaves a transient there, which biases the mean spectra beyond the
    reported std), that period is dropped too and the fact noted; with
    ``PeriodicSpectra`` given, or too few periods, only noted.

    Examples
    --------
    A 100 Hz mode measured over 5 periods (the first dropped), from a start
    1 Hz and 50 % off:

    >>> import numpy as np
    >>> from workbench.modal.model import ModalModel, Mode
    >>> P, fs, rng = 200, 1000.0, np.random.default_rng(0)
    >>> k = np.arange(10, 31)  # lines 50 .. 150 Hz
    >>> U = np.zeros(P // 2 + 1, complex)
    >>> U[k] = P / 2 * np.exp(2j * np.pi * rng.uniform(size=k.size))
    >>> g, _, _ = zoh_mode_response(2 * np.pi * 100.0, 0.02, np.exp(2j * np.pi * k / P), 1 / fs)
    >>> Y = np.zeros_like(U)
    >>> Y[k] = g * U[k]
    >>> u = np.tile(np.fft.irfft(U, P), 5)[:, None]
    >>> y = np.tile(np.fft.irfft(Y, P), 5)[:, None] + 1e-6 * rng.standard_normal((5 * P, 1))
    >>> mode = Mode(kind="flexible", freq_hz=101.0, damping=0.03, b=[1.0], c=[1.0])
    >>> start = ModalModel(modes=(mode,), D=np.zeros((1, 1)))
    >>> res = refine_modal_model(start, TimeData(fs=fs, u=u, y=y, period=P), feedthrough=False)
    >>> m = res.model.modes[0]
    >>> round(m.freq_hz, 1), round(m.damping, 3), bool(res.freq_std_hz[0] < 0.01)
    (100.0, 0.02, True)

    References
    ----------
    R. Pintelon, J. Schoukens, System Identification: A Frequency Domain
    Approach, 2nd ed., Wiley-IEEE 2012, ch. 9-10 (ML on periodic data, the
    sample noise covariance). L. Ljung, System Identification, 2nd ed., 1999,
    sec. 13.4 (the direct method in closed loop). J. Schoukens, R. Pintelon,
    Y. Rolain, "Frequency domain system identification using non-parametric
    noise models estimated from a small number of data sets", Automatica
    33(6), 1997, pp. 1073-1086 (sample ML: the bias of the weighted cost and
    the loss of efficiency with noise estimated from few periods).
    D. Maiwald, D. Kraus, "Calculation of moments of complex Wishart and
    complex inverse Wishart distributed matrices", IEE Proc. Radar, Sonar
    Navig. 147(4), 2000 (``E[W^-1] = Sigma^-1 / (nu - p)``).
    """
    spec = _as_spectra(data, n_transient)
    _check_model(model, spec)
    input_delay = int(input_delay)
    if input_delay < 0:
        raise InputError(f"input_delay: expected an integer >= 0 samples, got {input_delay}")
    lay, theta0 = pack(model, feedthrough=feedthrough)
    notes: list[str] = []
    if noise_cov is None:
        spec = _drop_transient(
            spec, data, lay, theta0, input_delay, int(n_transient), int(noise_lines), notes
        )
    T = 1.0 / spec.fs
    z = spec.z
    sw = np.sqrt(spec.n_avg)[:, None]

    def noise(theta) -> tuple[np.ndarray, np.ndarray]:
        if noise_cov is not None:
            C = _line_cov(spec, noise_cov)
            return np.broadcast_to(C, (spec.n_lines, spec.n_y, spec.n_y)), np.ones(spec.n_lines)
        G = _frf_on(lay, theta, z, T, input_delay, spec.n_u)
        est = _local_noise(spec, G, int(noise_lines))
        if est is None:
            raise InputError(
                "data: expected at least 2 steady-state periods to estimate the noise, "
                "got 1; pass noise_cov"
            )
        return est

    def fit(theta, Winv):
        cache = {}

        def evaluate(x):
            key = x.tobytes()
            if key not in cache:
                cache.clear()
                GU, J = _model_jacobian(lay, x, z, spec.U, T, input_delay)
                e = sw * np.einsum("lij,lj->li", Winv, spec.Y - GU)
                Jw = -sw[:, :, None] * np.einsum("lij,ljp->lip", Winv, J)
                cache[key] = (
                    np.concatenate([e.real.ravel(), e.imag.ravel()]),
                    np.concatenate(
                        [Jw.real.reshape(-1, lay.n_par), Jw.imag.reshape(-1, lay.n_par)]
                    ),
                )
            return cache[key]

        sol = scipy.optimize.least_squares(
            lambda x: evaluate(x)[0].copy(),
            theta,
            jac=lambda x: evaluate(x)[1].copy(),
            method="lm",
            x_scale="jac",
            max_nfev=max_nfev,
        )
        return sol, evaluate(sol.x)

    n_res = 2 * spec.n_lines * spec.n_y
    if n_res < lay.n_par:
        raise InputError(
            f"data: expected at least {lay.n_par} real equations for {lay.n_par} parameters, "
            f"got {n_res} ({spec.n_lines} lines x {spec.n_y} outputs); use a richer excitation "
            "or fewer modes"
        )
    C1, kappa = noise(theta0)
    theta = theta0
    for it in range(max(0, int(reweight)) + 1):
        # weights from kappa C_hat: an unbiased estimate of C^-1 (see _local_noise)
        sol, (r, Jr) = fit(theta, _whiteners(kappa[:, None, None] * C1))
        theta = sol.x
        if it < reweight and noise_cov is None:
            C1, kappa = noise(theta)
        else:
            break
    dof = max(n_res / 2 - lay.n_par / 2, 1.0)
    misfit = float(np.sum(r**2) / dof)
    # the weights' own scatter costs efficiency: the variance exceeds the inverse
    # Fisher information by about kappa (sample ML); and residuals larger than
    # the noise model says (misfit > 1) widen it by the misfit, never narrow it
    variance_factor = float(np.median(kappa)) * max(1.0, misfit)
    cov = _covariance(Jr) * variance_factor
    f_std, z_std = lay.mode_std(cov)
    perm = lay.mode_order(theta)
    f_std, z_std = f_std[perm], z_std[perm]
    refined = lay.unpack(theta, model)
    if not sol.success:
        notes.append(f"the optimizer stopped without convergence: {sol.message}")
    for m in refined.modes:
        if m.kind == "flexible" and not 0 <= m.damping < 1:
            notes.append(f"a flexible mode at {m.freq_hz:.4g} Hz left the range 0 <= zeta < 1")
    return RefineResult(
        model=refined,
        start=model,
        freq_std_hz=f_std,
        damping_std=z_std,
        misfit=misfit,
        n_lines=spec.n_lines,
        noise_cov=np.real(C1) / spec.period,  # per-sample equivalent, m^2
        input_delay=input_delay,
        success=bool(sol.success),
        message=str(sol.message),
        nfev=int(sol.nfev),
        notes=tuple(notes),
        variance_factor=variance_factor,
    )


# ------------------------------------------------------------------ the bound
@dataclass(frozen=True)
class CramerRao:
    """Cramer-Rao lower bound of a modal model's parameters for one experiment.

    Attributes
    ----------
    freq_std_hz : (n_modes,) array
        Lower bound of the standard deviation of each mode's frequency, Hz
        (NaN for rigid modes), in the order of ``model.modes``.
    damping_std : (n_modes,) array
        Same for the damping ratio, -.
    fisher : (n_par, n_par) array
        Fisher information of theta (see ``param_names``).
    covariance : (n_par, n_par) array
        Its pseudo-inverse (the ``c_k`` / ``b_k`` scale is a null direction).
    param_names : tuple of str
    """

    freq_std_hz: np.ndarray
    damping_std: np.ndarray
    fisher: np.ndarray
    covariance: np.ndarray
    param_names: tuple[str, ...]

    def __post_init__(self):
        for name in ("freq_std_hz", "damping_std", "fisher", "covariance"):
            object.__setattr__(self, name, readonly(getattr(self, name), float))


def modal_crb(
    model: ModalModel,
    spectra: PeriodicSpectra,
    *,
    noise_cov: np.ndarray,
    input_delay: int = 0,
    feedthrough: bool = True,
) -> CramerRao:
    """Cramer-Rao bound of the modal parameters for a periodic experiment.

    Parameters
    ----------
    model : ModalModel
        The true model (the bound is evaluated at its parameters), in the
        parametrization of :func:`refine_modal_model`.
    spectra : PeriodicSpectra
        The experiment: lines, the noise-free input spectra ``U`` (n_l, n_u)
        (for a noisy record its period means are a close substitute) and the
        periods averaged per line ``n_avg``; ``Y`` is not used.
    noise_cov : (n_y, n_y) or (n_y,) array
        Per-sample covariance (or variances) of the white output noise, m^2.
    input_delay : int
        Samples of pure delay, as in :func:`refine_modal_model`.
    feedthrough : bool
        Whether ``D`` is a free parameter (as in the estimator).

    Returns
    -------
    CramerRao

    Notes
    -----
    Per line ``Y_l = G(theta, z_l) U0_l + V_l``, ``V_l`` circular complex
    Gaussian with covariance ``C / n_l`` (``C = period * noise_cov``), so

    ``F = 2 Re sum_l n_l J_l^H C^-1 J_l``,  ``J_l = dG(theta, z_l)/dtheta U0_l``.

    Closed loop, ``u = r - K y``: ``Y = T R + S_o V`` with ``T = S_o G``,
    ``S_o = (I + G K)^-1``; ``dT = S_o dG S_i`` with ``S_i = (I + K G)^-1``, so
    the mean's derivative is ``S_o dG U0`` (``U0 = S_i R``, the noise-free
    input) and the noise covariance ``S_o (C / n_l) S_o^H``: ``S_o`` cancels
    and the bound is the open-loop one with ``U0``. The information in the
    covariance's dependence on theta is of order one per line against the
    mean's ``SNR^2`` and is left out. ``CRB = F^+`` (Pintelon & Schoukens
    2012, sec. 17.5; S.M. Kay, Fundamentals of Statistical Signal Processing:
    Estimation Theory, 1993, sec. 15.7).
    """
    if not isinstance(spectra, PeriodicSpectra):
        raise InputError(
            f"spectra: expected PeriodicSpectra (periodic_spectra(data)), "
            f"got {type(spectra).__name__}"
        )
    _check_model(model, spectra)
    lay, theta = pack(model, feedthrough=feedthrough)
    C1 = _line_cov(spectra, noise_cov)
    _, J = _model_jacobian(lay, theta, spectra.z, spectra.U, 1.0 / spectra.fs, int(input_delay))
    Winv = _whiteners(C1[None])[0]
    Jw = np.sqrt(spectra.n_avg)[:, None, None] * np.einsum("ij,ljp->lip", Winv, J)
    Jr = np.concatenate([Jw.real.reshape(-1, lay.n_par), Jw.imag.reshape(-1, lay.n_par)])
    cov = _covariance(Jr)
    f_std, z_std = lay.mode_std(cov)
    # layout order: the model's, except that a shared rigid gain P puts every rigid mode first
    kinds = [m.kind for m in model.modes]
    where = list(range(len(kinds)))
    if "rigid_full" in lay.kinds:
        where = [k for k in where if kinds[k] == "rigid"] + [
            k for k in where if kinds[k] != "rigid"
        ]
    f_out, z_out = np.empty(len(kinds)), np.empty(len(kinds))
    f_out[where], z_out[where] = f_std, z_std
    return CramerRao(
        freq_std_hz=f_out,
        damping_std=z_out,
        fisher=2.0 * Jr.T @ Jr,
        covariance=cov,
        param_names=lay.names,
    )
