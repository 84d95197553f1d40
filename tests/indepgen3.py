"""A third, independent generator of diagnosis cases (issue 13, item 7).

Written from the exchange spec (shared/spec/data-format.md) and textbook
mechanics only, with numpy, scipy and python-control: it uses nothing of
``workbench`` and was written without reading ``tests/casegen.py`` or
``tests/indepgen.py``. Its plants are not the project's:

- ``shaft``: a two-mass drive with a flexible shaft (motor inertia, load
  inertia, the shaft lumped into ``n_seg`` torsional springs with its own
  inertia between them), torques at motor and load, encoder angles at both;
  one rigid-body mode and ``n_seg`` torsional modes;
- ``planar``: a planar 3-DOF stage (x, y, Rz): a mover body with 4 force
  actuators (two along x, two along y) carrying a chuck on flexures, with 3 or
  4 position sensors on the chuck; 3 rigid-body modes and 3 flexure modes;
- ``beam``: a free-free aluminium beam on air bearings (Euler-Bernoulli,
  analytic modes, random length and section), forces and sensors at random
  points; 2 rigid-body modes (heave, pitch) and its bending modes.

Every plant is a set of mass-normalized modes (Craig, *Fundamentals of
Structural Dynamics*, ch. 10): ``G(s) = sum_k c_k b_k^T / (s^2 + 2 zeta_k
omega_k s + omega_k^2)``, outputs per input in m/N (rad/(N m) for the shaft).

Effects put into the truth (the nominal model lacks them): ``time_delay``,
``missing_mode`` (a structural mode dropped from the nominal),
``actuator_dynamics`` and ``sensor_dynamics`` (first-order lags, one cutoff
per channel), ``suspension_stiffness`` (springs to the world, the eigenproblem
solved again), ``crosstalk`` (a near-identity static matrix at the sensors or
actuators), ``modal_mismatch`` (a wrong Young's modulus: every stiffness scaled,
every flexible frequency by one factor), ``residual_compliance`` (modes far
above the band that the nominal truncates) and ``none``.

Measurements: FRF (spec 1b, with ``G_var`` from a simulated number of
averages) on random log or linear grids, or closed-loop time records (spec 1a
with ``r``; a low-bandwidth rigid-body controller, ZOH with an exact fractional
delay, sensor noise; some start at rest, some mid-motion after a run-in,
periodic multisine or random excitation).

Each case carries its answer: the effect and its parameters, and the noise
floor (the spec error of the true system against its own noisy measurement).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import control
import numpy as np
import scipy.linalg
import scipy.signal

__all__ = ["EFFECTS", "PLANTS", "Case", "make_case", "make_suite", "save_case", "modal_frf"]

EFFECTS = (
    "time_delay",
    "missing_mode",
    "modal_mismatch",
    "residual_compliance",
    "actuator_dynamics",
    "sensor_dynamics",
    "suspension_stiffness",
    "crosstalk",
    "none",
)
PLANTS = ("shaft", "planar", "beam")


# ----------------------------------------------------------------- modal plants
@dataclass(frozen=True)
class Modes:
    """Mass-normalized modes of a mechanical plant.

    freq_hz (n_m,) natural frequencies (0 for rigid-body modes), zeta (n_m,)
    modal damping, b (n_m, n_u) modal participation of the inputs, c (n_y, n_m)
    modal displacement at the sensors.
    """

    freq_hz: np.ndarray
    zeta: np.ndarray
    b: np.ndarray
    c: np.ndarray

    def select(self, keep) -> Modes:
        keep = np.asarray(keep)
        return Modes(self.freq_hz[keep], self.zeta[keep], self.b[keep], self.c[:, keep])

    @property
    def flexible(self) -> np.ndarray:
        return np.flatnonzero(self.freq_hz > 0)


def modes_from_mk(M, K, Bf, Cd, zeta, *, rigid_tol=1e-6) -> Modes:
    """Modes of ``M q'' + K q = Bf u``, ``y = Cd q`` (scipy's generalized eigh)."""
    lam, phi = scipy.linalg.eigh(K, M)  # phi^T M phi = I
    lam = np.where(lam < rigid_tol * max(lam.max(), 1.0), 0.0, lam)
    f = np.sqrt(lam) / (2 * np.pi)
    z = np.where(f > 0, zeta, 0.0)
    return Modes(f, z, phi.T @ Bf, Cd @ phi)


def modal_frf(modes: Modes, freq_hz: np.ndarray) -> np.ndarray:
    """(n_f, n_y, n_u) response of the modes at ``freq_hz``."""
    s = 2j * np.pi * np.asarray(freq_hz)[:, None]
    w = 2 * np.pi * modes.freq_hz
    den = s**2 + 2 * modes.zeta * w * s + w**2  # (n_f, n_m)
    return np.einsum("ym,fm,mu->fyu", modes.c, 1.0 / den, modes.b)


def modal_ss(modes: Modes) -> control.StateSpace:
    """A real modal realization, states (q_k, q_k') per mode."""
    n_m = modes.freq_hz.size
    n_u, n_y = modes.b.shape[1], modes.c.shape[0]
    A = np.zeros((2 * n_m, 2 * n_m))
    B = np.zeros((2 * n_m, n_u))
    C = np.zeros((n_y, 2 * n_m))
    for k in range(n_m):
        w = 2 * np.pi * modes.freq_hz[k]
        A[2 * k, 2 * k + 1] = 1.0
        A[2 * k + 1, 2 * k] = -(w**2)
        A[2 * k + 1, 2 * k + 1] = -2 * modes.zeta[k] * w
        B[2 * k + 1] = modes.b[k]
        C[:, 2 * k] = modes.c[:, k]
    return control.ss(A, B, C, np.zeros((n_y, n_u)))


@dataclass(frozen=True)
class Mechanics:
    """A plant as M, K (q-space), force map, sensor map and damping; or as modes (beam)."""

    name: str
    M: np.ndarray | None
    K: np.ndarray | None
    Bf: np.ndarray | None
    Cd: np.ndarray | None
    zeta: np.ndarray
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    beam: dict | None = None  # analytic beam description

    def modes(self, *, k_scale=1.0, springs=None, n_extra=0) -> Modes:
        """The modes; ``k_scale`` scales every stiffness, ``springs`` adds springs to the world.

        ``n_extra`` (beam only) asks for that many more bending modes than the base set.
        """
        if self.beam is not None:
            return _beam_modes(self.beam, k_scale=k_scale, springs=springs, n_extra=n_extra)
        K = self.K * k_scale
        if springs is not None:
            K = K + springs
        n_m = self.M.shape[0]
        return modes_from_mk(self.M, K, self.Bf, self.Cd, self.zeta[:n_m])


def _shaft(rng) -> Mechanics:
    """Motor J1 - shaft (n_seg springs, inertia lumped between them) - load J2."""
    n_seg = int(rng.integers(2, 4))
    J1 = rng.uniform(0.5, 2.0) * 1e-3  # kg m^2
    J2 = rng.uniform(1.0, 5.0) * 1e-3
    Js = rng.uniform(0.1, 0.4) * J2  # shaft inertia
    f1 = rng.uniform(120.0, 500.0)  # first torsional mode, Hz (sets the shaft stiffness)
    J = np.r_[J1, np.full(n_seg - 1, Js / (n_seg - 1)), J2]
    n = J.size
    Kunit = np.zeros((n, n))
    for i in range(n - 1):
        Kunit[i : i + 2, i : i + 2] += [[1, -1], [-1, 1]]
    M = np.diag(J)
    lam1 = scipy.linalg.eigh(Kunit, M, eigvals_only=True)[1]
    K = Kunit * (2 * np.pi * f1) ** 2 / lam1
    Bf = np.zeros((n, 2))
    Bf[0, 0] = Bf[-1, 1] = 1.0
    Cd = np.zeros((2, n))
    Cd[0, 0] = Cd[1, -1] = 1.0
    zeta = rng.uniform(0.005, 0.03, n)
    return Mechanics("shaft", M, K, Bf, Cd, zeta, ("T_motor", "T_load"), ("phi_motor", "phi_load"))


def _planar(rng) -> Mechanics:
    """Mover (4 actuators) + chuck on flexures (3 or 4 sensors); q = [xA yA tA xB yB tB]."""
    mA, mB = rng.uniform(8.0, 20.0), rng.uniform(2.0, 6.0)  # kg
    IA, IB = mA * rng.uniform(0.01, 0.03), mB * rng.uniform(0.01, 0.03)  # kg m^2
    # flexure stiffness: modes of the chuck on the mover in 250-1500 Hz
    mu = mA * mB / (mA + mB)
    Iu = IA * IB / (IA + IB)
    fx, fy, ft = rng.uniform(250.0, 1500.0, 3)
    kx, ky, kt = mu * (2 * np.pi * fx) ** 2, mu * (2 * np.pi * fy) ** 2, Iu * (2 * np.pi * ft) ** 2
    # a flexure off-centre couples translation and rotation
    ex, ey = rng.uniform(-0.02, 0.02, 2)
    Kc = np.array(
        [[kx, 0.0, -ey * kx], [0.0, ky, ex * ky], [-ey * kx, ex * ky, kt + ey**2 * kx + ex**2 * ky]]
    )
    M = np.diag([mA, mA, IA, mB, mB, IB])
    K = np.block([[Kc, -Kc], [-Kc, Kc]])
    lx, ly = rng.uniform(0.1, 0.25, 2)  # actuator lever arms, m
    # generalized force of a force (Fx, Fy) at (px, py): [Fx, Fy, px Fy - py Fx]
    Bf = np.zeros((6, 4))
    Bf[:3, 0] = [1.0, 0.0, -ly]
    Bf[:3, 1] = [1.0, 0.0, ly]
    Bf[:3, 2] = [0.0, 1.0, lx]
    Bf[:3, 3] = [0.0, 1.0, -lx]
    n_s = int(rng.integers(3, 5))
    sx, sy = rng.uniform(0.05, 0.2, 2)
    # displacement along x at (0, py): xB - py tB; along y at (px, 0): yB + px tB
    rows = [[1.0, 0.0, -sy], [0.0, 1.0, sx], [0.0, 1.0, -sx], [1.0, 0.0, sy]][:n_s]
    Cd = np.zeros((n_s, 6))
    Cd[:, 3:] = rows
    zeta = rng.uniform(0.005, 0.03, 6)
    outs = ("x1", "y1", "y2", "x2")[:n_s]
    return Mechanics("planar", M, K, Bf, Cd, zeta, ("Fx1", "Fx2", "Fy1", "Fy2"), outs)


# free-free beam: roots of cos(bL) cosh(bL) = 1 (Blevins, Formulas for natural frequency, 8.1)
def _free_free_roots(n: int) -> np.ndarray:
    import scipy.optimize

    out = []
    for k in range(1, n + 1):
        g = (2 * k + 1) * np.pi / 2
        out.append(scipy.optimize.brentq(lambda x: np.cos(x) * np.cosh(x) - 1, g - 0.3, g + 0.3))
    return np.array(out)


def _beam_shape(bl: float, xi: np.ndarray) -> np.ndarray:
    """Free-free bending shape at xi = x / L (unnormalized)."""
    sig = (np.cosh(bl) - np.cos(bl)) / (np.sinh(bl) - np.sin(bl))
    t = bl * xi
    # cosh t - sig sinh t overflows less as a sum of exponentials for big t
    return np.cos(t) - sig * np.sin(t) + 0.5 * ((1 - sig) * np.exp(t) + (1 + sig) * np.exp(-t))


def _beam(rng) -> Mechanics:
    """Free-free aluminium beam, forces and sensors at random points (vertical bending)."""
    E, rho = 70e9, 2700.0  # aluminium, Pa, kg/m^3
    L = rng.uniform(0.5, 1.2)
    h, w = rng.uniform(0.012, 0.03), rng.uniform(0.03, 0.08)
    A, I = w * h, w * h**3 / 12
    n_u = int(rng.integers(2, 4))
    n_y = 3
    xa = np.sort(rng.uniform(0.0, 1.0, n_u))
    xs = np.sort(rng.uniform(0.0, 1.0, n_y))
    beam = {
        "E": E,
        "rho": rho,
        "L": L,
        "A": A,
        "I": I,
        "xa": xa,
        "xs": xs,
        "n_bend": int(rng.integers(3, 5)),
        "zeta": rng.uniform(0.003, 0.02, 12),
    }
    ins = tuple(f"F{k + 1}" for k in range(n_u))
    outs = tuple(f"z{k + 1}" for k in range(n_y))
    return Mechanics("beam", None, None, None, None, beam["zeta"], ins, outs, beam)


def _beam_modes(beam, *, k_scale=1.0, springs=None, n_extra=0) -> Modes:
    """Rigid heave + pitch and n_bend bending modes, mass-normalized (m = rho A L).

    ``springs``: (stiffness N/m, position xi) pairs to the world; the spring
    problem is solved by Rayleigh-Ritz on the free-free modes (24 of them).
    """
    L, rho, A = beam["L"], beam["rho"], beam["A"]
    m = rho * A * L
    n_b = beam["n_bend"] + n_extra
    n_ritz = max(24, n_b) if springs else n_b
    roots = _free_free_roots(n_ritz)
    xq = np.linspace(0.0, 1.0, 4001)

    def shapes(xi):
        rig = np.stack([np.full_like(xi, 1 / np.sqrt(m)), (xi - 0.5) / np.sqrt(m / 12)], 1)
        bend = []
        for bl in roots:
            phi_q = _beam_shape(bl, xq)
            norm = np.sqrt(rho * A * L * np.trapezoid(phi_q**2, xq))
            bend.append(_beam_shape(bl, xi) / norm)
        return np.concatenate([rig, np.stack(bend, 1)], 1)

    w2 = np.r_[0.0, 0.0, (roots / L) ** 4 * k_scale * beam["E"] * beam["I"] / (rho * A)]
    Pa, Ps = shapes(beam["xa"]), shapes(beam["xs"])
    zeta = np.r_[0.0, 0.0, beam["zeta"][: roots.size], np.full(max(0, roots.size - 12), 0.01)]
    if springs:
        Kr = np.diag(w2)
        for k_n, xi in springs:
            p = shapes(np.array([xi]))[0]
            Kr = Kr + k_n * np.outer(p, p)
        lam, V = np.linalg.eigh(Kr)  # Ritz vectors, M = I in modal coordinates
        Pa, Ps, w2 = Pa @ V, Ps @ V, np.maximum(lam, 0.0)
        # each Ritz mode keeps the damping of the free-free mode it mostly is
        zeta = zeta[np.argmax(np.abs(V), axis=0)]
    keep = np.arange(2 + n_b)
    f = np.sqrt(w2[keep]) / (2 * np.pi)
    return Modes(f, zeta[keep], Pa[:, keep].T, Ps[:, keep])


def make_plant(name: str, rng) -> Mechanics:
    return {"shaft": _shaft, "planar": _planar, "beam": _beam}[name](rng)


# ---------------------------------------------------------------- the truth
@dataclass(frozen=True)
class Truth:
    """The true system: modes, then lags, crosstalk and a delay (all optional)."""

    modes: Modes
    delay_s: float = 0.0
    act_cut_hz: np.ndarray | None = None
    sen_cut_hz: np.ndarray | None = None
    T_y: np.ndarray | None = None  # (n_y, n_y) sensor crosstalk
    T_u: np.ndarray | None = None  # (n_u, n_u) actuator crosstalk

    def frf(self, freq_hz) -> np.ndarray:
        f = np.asarray(freq_hz)
        G = modal_frf(self.modes, f)
        s = 2j * np.pi * f
        if self.act_cut_hz is not None:
            G = G / (1 + s[:, None, None] / (2 * np.pi * self.act_cut_hz)[None, None, :])
        if self.sen_cut_hz is not None:
            G = G / (1 + s[:, None, None] / (2 * np.pi * self.sen_cut_hz)[None, :, None])
        if self.T_y is not None:
            G = np.einsum("ij,fjk->fik", self.T_y, G)
        if self.T_u is not None:
            G = np.einsum("fij,jk->fik", G, self.T_u)
        return G * np.exp(-s * self.delay_s)[:, None, None]

    def ss(self) -> control.StateSpace:
        """The rational part (no delay) as a python-control system."""
        sys = modal_ss(self.modes)
        n_u, n_y = self.modes.b.shape[1], self.modes.c.shape[0]
        if self.T_u is not None:
            sys = sys * control.ss([], [], [], self.T_u)
        if self.act_cut_hz is not None:
            w = 2 * np.pi * self.act_cut_hz
            sys = sys * control.ss(-np.diag(w), np.diag(w), np.eye(n_u), np.zeros((n_u, n_u)))
        if self.sen_cut_hz is not None:
            w = 2 * np.pi * self.sen_cut_hz
            sys = control.ss(-np.diag(w), np.diag(w), np.eye(n_y), np.zeros((n_y, n_y))) * sys
        if self.T_y is not None:
            sys = control.ss([], [], [], self.T_y) * sys
        return sys


@dataclass(frozen=True)
class Case:
    """One diagnosis case: the nominal model, the measurement, the answer."""

    name: str
    nominal: control.StateSpace
    data: object  # a workbench-free dict of spec keys; see ``as_measurement``
    answer: dict
    truth: Truth = field(repr=False)

    @property
    def kind(self) -> str:
        return str(self.data["kind"])


# ---------------------------------------------------------------- measurement
def _grid(rng, f_lo, f_hi) -> np.ndarray:
    n_f = int(rng.integers(200, 500))
    if rng.random() < 0.6:
        return np.geomspace(f_lo, f_hi, n_f)
    return np.linspace(f_lo, f_hi, n_f)


def _frf_measurement(truth: Truth, freq, noise_rel, rng, n_avg) -> dict:
    """G with complex noise of variance noise_rel^2 (|G_ij| + 0.1 ||G||_F / sqrt(n))^2 / n_avg.

    G_var is the sample variance of the mean over n_avg averages (a scaled
    chi^2 with 2 (n_avg - 1) degrees of freedom around the true variance).
    """
    G = truth.frf(freq)
    n_el = G.shape[1] * G.shape[2]
    scale = np.abs(G) + 0.1 * np.linalg.norm(G, axis=(1, 2))[:, None, None] / np.sqrt(n_el)
    var = (noise_rel * scale) ** 2 / n_avg
    noise = np.sqrt(var / 2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    dof = 2 * (n_avg - 1)
    var_hat = var * rng.chisquare(dof, G.shape) / dof
    return {"kind": "frf", "freq": freq, "G": G + noise, "G_var": var_hat}


def _frf_error(Gm, G) -> float:
    """The spec FRF error: mean over lines of ||G - Gm||_F / ||G||_F."""
    return float(np.mean(np.linalg.norm(G - Gm, axis=(1, 2)) / np.linalg.norm(G, axis=(1, 2))))


def _zoh_delay(A, B, T, delay_s):
    """x[k+1] = Ad x[k] + G0 u[k - m] + G1 u[k - m - 1], delay = m T + d (Franklin-Powell 4.3)."""
    n, n_u = B.shape
    m = int(np.floor(delay_s / T + 1e-12))
    d = delay_s - m * T

    def phi_gamma(t):
        E = np.zeros((n + n_u, n + n_u))
        E[:n, :n], E[:n, n:] = A * t, B * t
        X = scipy.linalg.expm(E)
        return X[:n, :n], X[:n, n:]

    Ad, _ = phi_gamma(T)
    P1, G1a = phi_gamma(T - d)  # the part of the sample after the delayed step
    _, Gd = phi_gamma(d)
    return Ad, G1a, P1 @ Gd, m


def _controller(nominal_modes: Modes, fc_hz: float, fs: float):
    """Rigid-body PD + lead + low-pass in modal coordinates, Tustin at fs: u_c = K(-y)."""
    rig = np.flatnonzero(nominal_modes.freq_hz == 0)
    Cr = nominal_modes.c[:, rig]  # (n_y, n_r)
    Br = nominal_modes.b[rig]  # (n_r, n_u)
    wc = 2 * np.pi * fc_hz
    s = control.tf("s")
    wl = 6 * wc
    c1 = (
        (wc**2 / 3)
        * (1 + s / (wc / 3))
        / (1 + s / (3 * wc))
        * wl**2
        / (s**2 + 1.4 * wl * s + wl**2)
    )
    c1 = control.ss(c1)
    n_r = rig.size
    K = control.append(*([c1] * n_r)) if n_r > 1 else c1
    K = control.ss([], [], [], np.linalg.pinv(Br)) * K * control.ss([], [], [], np.linalg.pinv(Cr))
    return control.c2d(K, 1.0 / fs, method="tustin")


def _closed_loop_record(
    truth, nominal_modes, fs, n_periods, period, noise_rel, rng, *, at_rest, periodic, band_hz
):
    """Closed-loop record (u = r + K(-y_meas)), ZOH plant with the exact delay."""
    sysc = truth.ss()
    A, B, C = (np.asarray(X, float) for X in (sysc.A, sysc.B, sysc.C))
    n_u, n_y = B.shape[1], C.shape[0]
    Ad, G0, G1, m = _zoh_delay(A, B, 1.0 / fs, truth.delay_s)
    flex = nominal_modes.freq_hz[nominal_modes.freq_hz > 0]
    fc = min(flex.min() / 12, 40.0)
    for _ in range(6):  # lower the bandwidth until the loop is stable
        K = _controller(nominal_modes, fc, fs)
        Ka, Kb, Kc, Kd = (np.asarray(X, float) for X in (K.A, K.B, K.C, K.D))
        if _loop_stable(Ad, G0, G1, m, C, Ka, Kb, Kc, Kd):
            break
        fc /= 1.6
    N = n_periods * period
    n_run = 0 if at_rest else 3 * period
    # excitation
    if periodic:
        k = np.arange(1, period // 2)
        f = k * fs / period
        lines = k[(f >= band_hz[0]) & (f <= band_hz[1])]
        one = np.zeros((period, n_u))
        for j in range(n_u):  # each input on its own lines (zippered), random phases
            mine = lines[j::n_u]
            X = np.zeros(period // 2 + 1, complex)
            X[mine] = np.exp(2j * np.pi * rng.random(mine.size))
            one[:, j] = np.fft.irfft(X, period)
        one /= one.std(axis=0)
        r = np.tile(one, (n_periods + n_run // period, 1))
    else:
        bb, aa = scipy.signal.butter(4, min(band_hz[1] / (fs / 2), 0.95))
        r = scipy.signal.lfilter(bb, aa, rng.standard_normal((N + n_run, n_u)), axis=0)
        r /= r.std(axis=0)
    n_tot = N + n_run
    x = np.zeros(Ad.shape[0])
    xk = np.zeros(Ka.shape[0])
    u = np.zeros((n_tot, n_u))
    y0 = np.zeros((n_tot, n_y))
    # sensor noise: set from a noise-free run's rms afterwards; draw a unit sequence now
    e_unit = rng.standard_normal((n_tot, n_y))
    # first pass noise-free to set the noise scale, then the real run (linear: scale known)
    ys = _run_loop(Ad, G0, G1, m, C, Ka, Kb, Kc, Kd, r, np.zeros_like(e_unit), x, xk)[1]
    sig = noise_rel * np.sqrt(np.mean(ys[n_run:] ** 2, axis=0))
    v = e_unit * sig
    u, y0 = _run_loop(Ad, G0, G1, m, C, Ka, Kb, Kc, Kd, r, v, x, xk)
    sl = slice(n_run, n_tot)
    y = y0[sl] + v[sl]
    floor = float(np.linalg.norm(v[sl]) / np.linalg.norm(y))
    rec = {"kind": "time", "fs": float(fs), "u": u[sl], "y": y, "r": r[sl], "loop": "closed"}
    if periodic:
        rec["period"] = int(period)
    return rec, floor, fc


def _loop_stable(Ad, G0, G1, m, C, Ka, Kb, Kc, Kd) -> bool:
    """Spectral radius < 1 of the sampled loop (plant, delay line, controller)."""
    n, n_u = G0.shape
    n_y = C.shape[0]
    nk = Ka.shape[0]
    L = m + 1  # u[k-1] ... u[k-m-1]
    N = n + nk + L * n_u
    F = np.zeros((N, N))
    # u[k] = Kc xk - Kd C x (r = 0, no noise)
    Ux = -Kd @ C
    Uk = Kc
    iu = n + nk
    # plant: x+ = Ad x + G0 u[k-m] + G1 u[k-m-1]
    F[:n, :n] = Ad

    def add_u(rows, coef, lag):  # coef @ u[k - lag]
        if lag == 0:
            F[rows, :n] += coef @ Ux
            F[rows, n : n + nk] += coef @ Uk
        else:
            c0 = iu + (lag - 1) * n_u
            F[rows, c0 : c0 + n_u] += coef

    add_u(slice(0, n), G0, m)
    add_u(slice(0, n), G1, m + 1)
    # controller: xk+ = Ka xk + Kb (-C x)
    F[n : n + nk, :n] = -Kb @ C
    F[n : n + nk, n : n + nk] = Ka
    # delay line: u[k] -> slot 1, slot i -> slot i+1
    F[iu : iu + n_u, :n] = Ux
    F[iu : iu + n_u, n : n + nk] = Uk
    for i in range(1, L):
        F[iu + i * n_u : iu + (i + 1) * n_u, iu + (i - 1) * n_u : iu + i * n_u] = np.eye(n_u)
    rho = np.max(np.abs(np.linalg.eigvals(F)))
    del n_y
    return bool(rho < 1 - 1e-9)


def _run_loop(Ad, G0, G1, m, C, Ka, Kb, Kc, Kd, r, v, x, xk):
    n_tot, n_u = r.shape
    u = np.zeros((n_tot, n_u))
    y = np.zeros((n_tot, C.shape[0]))
    x, xk = x.copy(), xk.copy()
    zero = np.zeros(n_u)
    for k in range(n_tot):
        y[k] = C @ x
        e = -(y[k] + v[k])
        u[k] = r[k] + Kc @ xk + Kd @ e
        xk = Ka @ xk + Kb @ e
        ua = u[k - m] if k - m >= 0 else zero
        ub = u[k - m - 1] if k - m - 1 >= 0 else zero
        x = Ad @ x + G0 @ ua + G1 @ ub
    return u, y


# ---------------------------------------------------------------- effects
def _apply_effect(effect, plant: Mechanics, rng, f_hi):
    """(nominal modes, truth, answer parameters) for one effect."""
    base = plant.modes()
    flex = base.flexible
    n_u, n_y = base.b.shape[1], base.c.shape[0]
    nominal, truth, params = base, Truth(base), {}
    if effect == "time_delay":
        tau = rng.uniform(0.05, 0.25) / f_hi  # 18-90 deg of phase at the top line
        truth = Truth(base, delay_s=tau)
        params = {"delay_s": tau}
    elif effect == "missing_mode":
        k = int(rng.choice(flex[base.freq_hz[flex] < 0.8 * f_hi]))
        nominal = base.select([i for i in range(base.freq_hz.size) if i != k])
        params = {"freq_hz": float(base.freq_hz[k]), "damping": float(base.zeta[k])}
    elif effect == "modal_mismatch":
        scale = rng.choice([-1, 1]) * rng.uniform(0.03, 0.09) + 1.0  # true / model frequency
        tm = plant.modes(k_scale=scale**2)
        truth = Truth(tm)
        params = {
            "pattern": {"freq_scale": float(scale)},
            "freq_hz": [float(v) for v in tm.freq_hz[flex]],
            "model_freq_hz": [float(v) for v in base.freq_hz[flex]],
        }
    elif effect == "residual_compliance":
        # the truth has modes far above the band the nominal lacks
        if plant.beam is not None:
            n_extra = 10
            full = plant.modes(n_extra=n_extra)
            high = np.flatnonzero(full.freq_hz > 2.5 * f_hi)
            keep = np.r_[np.arange(base.freq_hz.size), high]
            tm = full.select(keep)
            high = np.arange(base.freq_hz.size, tm.freq_hz.size)
        else:
            # a stiff local mode of the structure: a random mode shape at 3-8 x f_hi
            n_h = 2
            fh = rng.uniform(3.0, 8.0, n_h) * f_hi
            mass = rng.uniform(0.3, 1.0, n_h) * _modal_mass_scale(base)
            bh = rng.standard_normal((n_h, n_u)) / np.sqrt(mass)[:, None]
            ch = rng.standard_normal((n_y, n_h)) / np.sqrt(mass)[None, :]
            tm = Modes(
                np.r_[base.freq_hz, fh],
                np.r_[base.zeta, [0.02] * n_h],
                np.vstack([base.b, bh]),
                np.hstack([base.c, ch]),
            )
            high = np.arange(base.freq_hz.size, tm.freq_hz.size)
        truth = Truth(tm)
        w2 = (2 * np.pi * tm.freq_hz[high]) ** 2
        R = np.einsum("ym,m,mu->yu", tm.c[:, high], 1 / w2, tm.b[high])
        # each truncated mode too (its static part): on a sampled record a mode above
        # Nyquist rings in the band at its folded frequency, and may be named there
        modes = [
            {
                "freq_hz": float(tm.freq_hz[h]),
                "damping": float(tm.zeta[h]),
                "matrix": (np.outer(tm.c[:, h], tm.b[h]) / w).tolist(),
            }
            for h, w in zip(high, w2)
        ]
        params = {"matrix": R.tolist(), "modes": modes}
    elif effect == "actuator_dynamics":
        cut = rng.uniform(1.0, 3.0, n_u) * f_hi / 4
        truth = Truth(base, act_cut_hz=cut)
        params = {"cutoff_hz": [float(c) for c in cut]}
    elif effect == "sensor_dynamics":
        cut = rng.uniform(1.0, 3.0, n_y) * f_hi / 4
        truth = Truth(base, sen_cut_hz=cut)
        params = {"cutoff_hz": [float(c) for c in cut]}
    elif effect == "suspension_stiffness":
        f_s = rng.uniform(4.0, 20.0)  # target lowest suspension frequency, Hz
        tm = _suspended(plant, base, f_s, rng)
        truth = Truth(tm)
        rig = np.flatnonzero(base.freq_hz == 0)
        params = {
            "freq_hz": [float(v) for v in np.sort(tm.freq_hz)[: rig.size]],
            "damping": [float(v) for v in tm.zeta[np.argsort(tm.freq_hz)[: rig.size]]],
        }
    elif effect == "crosstalk":
        if rng.random() < 0.5:
            T = np.eye(n_y) + rng.uniform(0.01, 0.05, (n_y, n_y)) * rng.choice([-1, 1], (n_y, n_y))
            np.fill_diagonal(T, 1.0)
            truth, side = Truth(base, T_y=T), "sensors"
        else:
            T = np.eye(n_u) + rng.uniform(0.01, 0.05, (n_u, n_u)) * rng.choice([-1, 1], (n_u, n_u))
            np.fill_diagonal(T, 1.0)
            truth, side = Truth(base, T_u=T), "actuators"
        params = {"side": side, "matrix": T.tolist()}
    elif effect != "none":
        raise ValueError(f"effect: expected one of {EFFECTS}, got {effect!r}")
    return nominal, truth, params


def _modal_mass_scale(modes: Modes) -> float:
    """A mass of the plant from its rigid-body participation (kg or kg m^2)."""
    rig = np.flatnonzero(modes.freq_hz == 0)
    bb = np.mean(modes.b[rig] ** 2) if rig.size else np.mean(modes.b**2)
    return float(1.0 / max(bb, 1e-30))


def _suspended(plant: Mechanics, base: Modes, f_s: float, rng) -> Modes:
    """Springs to the world on every rigid-body DOF, lowest suspension mode near f_s."""
    zs = rng.uniform(0.02, 0.1)
    if plant.beam is not None:
        m = plant.beam["rho"] * plant.beam["A"] * plant.beam["L"]
        k_each = m * (2 * np.pi * f_s) ** 2 / 2
        tm = plant.modes(springs=[(k_each, 0.05), (k_each * rng.uniform(0.7, 1.4), 0.95)])
    else:
        n = plant.M.shape[0]
        Ks = np.zeros((n, n))
        dofs = [0] if plant.name == "shaft" else [0, 1, 2]
        for d in dofs:  # a spring on the first body, stiffness from its share of the mass
            mass_total = plant.M[d, d] + (plant.M[d + 3, d + 3] if plant.name == "planar" else 0)
            if plant.name == "shaft":
                mass_total = np.trace(plant.M)
            Ks[d, d] = mass_total * (2 * np.pi * f_s * rng.uniform(0.8, 1.5)) ** 2
        tm = plant.modes(springs=Ks)
    z = np.where(tm.freq_hz < 0.2 * np.min(base.freq_hz[base.freq_hz > 0]), zs, tm.zeta)
    return Modes(tm.freq_hz, z, tm.b, tm.c)


# ---------------------------------------------------------------- cases
def make_case(
    effect: str,
    plant_name: str,
    kind: str,
    rng: np.random.Generator,
    *,
    min_visibility: float = 4.0,
) -> Case:
    """One random case.

    The noise level is drawn (0.2-3 % FRF, 0.1-2 % time) and halved (at most
    10 times) while the effect would sit within ``min_visibility`` x the noise
    floor (the effect must be visible for its name to be the right answer;
    ``none`` keeps its draw). ``answer["visibility"]`` says what was reached.
    """
    plant = make_plant(plant_name, rng)
    base = plant.modes()
    f_flex = base.freq_hz[base.flexible]
    f_hi = float(rng.uniform(1.3, 2.2) * f_flex.max())
    f_lo = float(rng.uniform(0.5, 3.0))
    nominal, truth, params = _apply_effect(effect, plant, rng, f_hi)
    if effect == "suspension_stiffness":
        f_lo = min(f_lo, 0.3 * min(params["freq_hz"]))
    names = {"input_names": plant.input_names, "output_names": plant.output_names}
    info = {"plant": plant_name, "kind": kind, "f_band_hz": [f_lo, f_hi]}
    if kind == "frf":
        freq = _grid(rng, f_lo, f_hi)
        noise = float(np.exp(rng.uniform(np.log(0.002), np.log(0.03))))
        G_true = truth.frf(freq)
        effect_err = _frf_error(modal_frf(nominal, freq), G_true)
        n_avg = int(rng.integers(6, 20))
        for _ in range(10):
            data = _frf_measurement(truth, freq, noise, rng, n_avg)
            floor = _frf_error(G_true, data["G"])
            if effect == "none" or effect_err >= min_visibility * floor:
                break
            noise /= 2
        data.update(names)
        info.update({"n_f": int(freq.size), "n_avg": n_avg, "grid": _grid_kind(freq)})
    elif kind == "time":
        fs = float(np.ceil(max(2.6 * f_hi, rng.uniform(4e3, 8e3)) / 100) * 100)
        period = int(2 ** rng.integers(10, 12))
        n_periods = int(max(4, 16384 // period))
        periodic = bool(rng.random() < 0.5)
        at_rest = bool(rng.random() < 0.5)
        noise = float(np.exp(rng.uniform(np.log(0.001), np.log(0.02))))
        band = (max(f_lo, fs / period), min(f_hi, 0.4 * fs))
        effect_err = None
        for _ in range(10):
            data, floor, fc = _closed_loop_record(
                truth,
                nominal,
                fs,
                n_periods,
                period,
                noise,
                rng,
                at_rest=at_rest,
                periodic=periodic,
                band_hz=band,
            )
            if effect_err is None:
                effect_err = _time_effect_error(truth, nominal, data)
            if effect == "none" or effect_err >= min_visibility * floor:
                break
            noise /= 2
        data.update(names)
        info.update(
            {
                "fs": fs,
                "n_samples": int(data["u"].shape[0]),
                "periodic": periodic,
                "at_rest": at_rest,
                "controller_crossover_hz": fc,
            }
        )
    else:
        raise ValueError(f"kind: expected 'frf' or 'time', got {kind!r}")
    info.update(
        {
            "noise_rel": noise,
            "noise_floor_error": floor,
            "effect_error": effect_err,
            "visibility": effect_err / floor,
        }
    )
    answer = {"effect": effect, "parameters": params, **info}
    name = f"{plant_name}-{kind}-{effect}"
    return Case(name, modal_ss(nominal), data, answer, truth)


def _grid_kind(freq) -> str:
    d = np.diff(freq)
    return "linear" if np.allclose(d, d[0], rtol=1e-6) else "log"


def _time_effect_error(truth: Truth, nominal: Modes, data: dict) -> float:
    """||y_truth - y_nominal|| / ||y||: both simulated from rest with the recorded u.

    The effect's share of the output, free of noise and of the record's initial
    state (which both simulations lack alike).
    """
    fs, u = data["fs"], data["u"]
    out = []
    for sysc, delay in ((truth.ss(), truth.delay_s), (modal_ss(nominal), 0.0)):
        A, B, C = (np.asarray(X, float) for X in (sysc.A, sysc.B, sysc.C))
        Ad, G0, G1, m = _zoh_delay(A, B, 1.0 / fs, delay)
        N = u.shape[0]
        ua = np.zeros_like(u)
        ua[m:] = u[: N - m]
        ub = np.zeros_like(u)
        ub[m + 1 :] = u[: N - m - 1]
        drive = ua @ G0.T + ub @ G1.T
        x = np.zeros(A.shape[0])
        y = np.empty((N, C.shape[0]))
        for k in range(N):
            y[k] = C @ x
            x = Ad @ x + drive[k]
        out.append(y)
    return float(np.linalg.norm(out[0] - out[1]) / np.linalg.norm(data["y"]))


def make_suite(seed: int, *, kinds=("frf", "time"), plants=PLANTS, effects=EFFECTS, n_frf=2):
    """Every effect x plant, ``n_frf`` FRF cases and one time record each, seeded.

    A case's generator is seeded by (seed, plant, effect, kind, repetition) as
    their indices in PLANTS, EFFECTS and ("frf", "time"): a subset of the suite
    holds the very cases of the whole suite.
    """
    out = []
    for plant in plants:
        for effect in effects:
            for kind in kinds:
                reps = n_frf if kind == "frf" else 1
                for rep in range(reps):
                    key = [PLANTS.index(plant), EFFECTS.index(effect), ("frf", "time").index(kind)]
                    rng = np.random.default_rng([seed, *key, rep])
                    out.append((plant, effect, kind, rng))
    return out


def save_case(case: Case, folder) -> Path:
    """Write ``model.npz`` (spec 2), ``measurement.npz`` (spec 1a/1b), ``answer.json``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n = case.nominal
    np.savez(
        folder / "model.npz",
        A=n.A,
        B=n.B,
        C=n.C,
        D=n.D,
        dt=0.0,
        input_names=np.array(case.data["input_names"]),
        output_names=np.array(case.data["output_names"]),
    )
    data = {k: (np.array(v) if isinstance(v, tuple) else v) for k, v in case.data.items()}
    np.savez(folder / "measurement.npz", **data)
    (folder / "answer.json").write_text(json.dumps(case.answer, indent=2, default=float) + "\n")
    return folder
