"""Independent oracle cases for ``workbench.diagnosis.diagnose``.

Written from the exchange spec (shared/spec/data-format.md, sections 1 and 3) and the
public data classes only; nothing here uses the diagnosis code or the other generators.

A plant is kept in *structured* form (:class:`Plant`): rigid-body and flexible modes in
modal form (each mode adds ``c b^T / (s^2 + 2 z w s + w^2)``, a rigid mode ``c b^T / s^2``),
first-order lags on inputs / outputs, static input / output coupling matrices and an input
delay.  The true plant is the engineer's nominal with one (or two) physical effects applied;
the FRF is evaluated straight from the modal sum, the time record by a ZOH-exact simulation
(scipy ``cont2discrete`` + ``dlsim``) of the state-space realisation.

Public: :func:`make_case`, :func:`make_suite`, :class:`Case`, :func:`frf_of`,
:func:`to_ss`, :func:`simulate`, :func:`rel_error_frf`, :func:`rel_error_time`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import control
import numpy as np
from scipy import signal

from workbench.io.formats import FrfData, TimeData

TWO_PI = 2.0 * np.pi

PLANTS = ("gantry", "dualstage")
EFFECTS = (
    "time_delay",
    "missing_mode",
    "modal_mismatch",
    "actuator_dynamics",
    "sensor_dynamics",
    "suspension_stiffness",
    "crosstalk",
    "residual_compliance",
    "none",
)
PAIRS = (
    ("time_delay", "missing_mode"),
    ("actuator_dynamics", "modal_mismatch"),
    ("crosstalk", "missing_mode"),
)
MIN_VISIBILITY = 3.0


# ------------------------------------------------------------------ structure
@dataclass
class Mode:
    b: np.ndarray  # (n_u,)
    c: np.ndarray  # (n_y,)
    w: float  # rad/s, 0 for a rigid-body mode
    z: float  # damping ratio


@dataclass
class Plant:
    kind: str
    modes: list  # list[Mode]; rigid ones have w == 0
    n_u: int
    n_y: int
    lag_in: list = None  # per input: cutoff Hz or None
    lag_out: list = None  # per output
    T_in: np.ndarray = None  # (n_u, n_u): G -> G T_in
    T_out: np.ndarray = None  # (n_y, n_y): G -> T_out G
    delay_s: float = 0.0
    rigid_idx: list = field(default_factory=list)  # indices of the rigid modes (nominal)

    def __post_init__(self):
        if self.lag_in is None:
            self.lag_in = [None] * self.n_u
        if self.lag_out is None:
            self.lag_out = [None] * self.n_y
        if self.T_in is None:
            self.T_in = np.eye(self.n_u)
        if self.T_out is None:
            self.T_out = np.eye(self.n_y)

    def flex(self):
        return [m for m in self.modes if m.w > 0]


@dataclass
class Case:
    name: str
    plant: str
    kind: str
    effects: tuple
    nominal: control.StateSpace
    data: object  # TimeData | FrfData
    answer: dict
    band_hz: tuple
    truth: Plant = None
    nominal_plant: Plant = None
    checks: dict = field(default_factory=dict)


# ------------------------------------------------------------------ evaluation
def frf_of(p: Plant, f_hz: np.ndarray, with_delay: bool = True) -> np.ndarray:
    """(n_f, n_y, n_u) response straight from the modal sum (no state space)."""
    s = 1j * TWO_PI * np.asarray(f_hz, float)
    G = np.zeros((s.size, p.n_y, p.n_u), complex)
    for m in p.modes:
        den = s**2 + 2 * m.z * m.w * s + m.w**2
        G += np.outer(m.c, m.b)[None, :, :] / den[:, None, None]
    lin = np.ones((s.size, p.n_u), complex)
    for i, fc in enumerate(p.lag_in):
        if fc is not None:
            lin[:, i] = 1.0 / (1.0 + s / (TWO_PI * fc))
    lout = np.ones((s.size, p.n_y), complex)
    for i, fc in enumerate(p.lag_out):
        if fc is not None:
            lout[:, i] = 1.0 / (1.0 + s / (TWO_PI * fc))
    G = lout[:, :, None] * G * lin[:, None, :]
    G = np.einsum("ij,fjk,kl->fil", p.T_out, G, p.T_in)
    if with_delay and p.delay_s:
        G = G * np.exp(-s * p.delay_s)[:, None, None]
    return G


def to_ss(p: Plant) -> control.StateSpace:
    """Continuous state-space realisation, delay excluded (T_out L_out G_modal L_in T_in)."""
    blocks = []
    for m in p.modes:
        if m.w > 0:  # states [w q, dq/dt]: better conditioned than [q, dq/dt]
            A = np.array([[0.0, m.w], [-m.w, -2 * m.z * m.w]])
            C = np.hstack([m.c[:, None] / m.w, np.zeros((p.n_y, 1))])
        else:
            A = np.array([[0.0, 1.0], [0.0, 0.0]])
            C = np.hstack([m.c[:, None], np.zeros((p.n_y, 1))])
        B = np.vstack([np.zeros((1, p.n_u)), m.b[None, :]])
        blocks.append((A, B, C))
    n = 2 * len(blocks)
    A = np.zeros((n, n))
    B = np.zeros((n, p.n_u))
    C = np.zeros((p.n_y, n))
    for k, (a, b, c) in enumerate(blocks):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = a
        B[2 * k : 2 * k + 2] = b
        C[:, 2 * k : 2 * k + 2] = c
    G = control.ss(A, B, C, np.zeros((p.n_y, p.n_u)))
    # input lags (diagonal), output lags, then static couplings
    if any(fc is not None for fc in p.lag_in):
        G = G * _lag_ss(p.lag_in)
    if any(fc is not None for fc in p.lag_out):
        G = _lag_ss(p.lag_out) * G
    G = control.ss(G.A, G.B @ p.T_in, p.T_out @ G.C, p.T_out @ G.D @ p.T_in)
    return G


def _lag_ss(fcs) -> control.StateSpace:
    idx = [i for i, fc in enumerate(fcs) if fc is not None]
    n, k = len(fcs), len(idx)
    A = np.zeros((k, k))
    B = np.zeros((k, n))
    C = np.zeros((n, k))
    D = np.eye(n)
    for j, i in enumerate(idx):
        wc = TWO_PI * fcs[i]
        A[j, j] = -wc
        B[j, i] = wc
        C[i, j] = 1.0
        D[i, i] = 0.0
    return control.ss(A, B, C, D)


def delay_samples(p: Plant, fs: float) -> int:
    d = p.delay_s * fs
    assert abs(d - round(d)) < 1e-9, "time records take whole-sample delays"
    return int(round(d))


def simulate(p: Plant, u: np.ndarray, fs: float) -> np.ndarray:
    """ZOH-exact response from rest: scipy cont2discrete(zoh) + dlsim, delay as a shift of u."""
    G = to_ss(p)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((G.A, G.B, G.C, G.D), 1.0 / fs, method="zoh")
    d = delay_samples(p, fs)
    ud = np.zeros_like(u)
    ud[d:] = u[: u.shape[0] - d] if d else u
    _, y, _ = signal.dlsim((Ad, Bd, Cd, Dd, 1.0 / fs), ud)
    return y


def rel_error_frf(G_meas, G_model) -> float:
    num = np.linalg.norm(G_meas - G_model, axis=(1, 2))
    den = np.linalg.norm(G_meas, axis=(1, 2))
    return float(np.mean(num / den))


def rel_error_time(Y, Y_model) -> float:
    return float(np.linalg.norm(Y - Y_model) / np.linalg.norm(Y))


# ------------------------------------------------------------------ plants
def _rand_unit(rng, n):
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _flex_mode(rng, f_hz, m_ref, n_u, n_y, zeta=None, gain=None):
    """A flexible mode with a random shape; modal gain |c||b| ~ (0.1..0.6)/m_ref."""
    z = rng.uniform(0.005, 0.03) if zeta is None else zeta
    g = (rng.uniform(0.1, 0.6) if gain is None else gain) / m_ref
    b = _rand_unit(rng, n_u) * np.sqrt(g)
    c = _rand_unit(rng, n_y) * np.sqrt(g)
    return Mode(b=b, c=c, w=TWO_PI * f_hz, z=z)


def _spread_freqs(rng, lo, hi, n, min_ratio=1.15):
    for _ in range(1000):
        f = np.sort(np.exp(rng.uniform(np.log(lo), np.log(hi), n)))
        if n < 2 or np.all(f[1:] / f[:-1] > min_ratio):
            return f
    return np.geomspace(lo, hi, n)


def make_plant(rng, plant: str) -> Plant:
    if plant == "gantry":
        m = rng.uniform(20, 60)  # moving mass, kg
        L = rng.uniform(0.6, 1.5)  # beam length between the motors, m
        # yaw inertia: beam + carriages ~ m L^2 / 12 .. m L^2 / 6
        J = m * L**2 * rng.uniform(1 / 12, 1 / 6)
        h = L / 2
        # inputs: F_left (at +h), F_right (at -h); outputs: x_left, x_right, yaw*h
        trans = Mode(
            b=np.array([1.0, 1.0]) / np.sqrt(m),
            c=np.array([1.0, 1.0, 0.0]) / np.sqrt(m),
            w=0.0,
            z=0.0,
        )
        yaw = Mode(
            b=np.array([h, -h]) / np.sqrt(J), c=np.array([h, -h, h]) / np.sqrt(J), w=0.0, z=0.0
        )
        nf = int(rng.integers(2, 4))
        fr = _spread_freqs(rng, 80, 900, nf)
        flex = [_flex_mode(rng, f, m, 2, 3) for f in fr]
        return Plant("gantry", [trans, yaw] + flex, n_u=2, n_y=3, rigid_idx=[0, 1])
    if plant == "dualstage":
        M = rng.uniform(20, 50)  # long stroke
        ms = rng.uniform(2, 6)  # short stroke (levitated on the long stroke)
        # inputs: F_long (world -> long stroke), F_short (long -> short stroke, reacts on LS)
        # outputs: x_long, x_short (absolute)
        ls = Mode(
            b=np.array([1.0, -1.0]) / np.sqrt(M), c=np.array([1.0, 0.0]) / np.sqrt(M), w=0.0, z=0.0
        )
        ss_ = Mode(
            b=np.array([0.0, 1.0]) / np.sqrt(ms), c=np.array([0.0, 1.0]) / np.sqrt(ms), w=0.0, z=0.0
        )
        fr = _spread_freqs(rng, 150, 1200, 2)
        flex = [_flex_mode(rng, f, np.sqrt(M * ms), 2, 2) for f in fr]
        return Plant("dualstage", [ls, ss_] + flex, n_u=2, n_y=2, rigid_idx=[0, 1])
    raise ValueError(plant)


# ------------------------------------------------------------------ measurements
def _frf_setup(rng):
    fs = float(rng.choice([5000.0, 10000.0]))
    f_lo = rng.uniform(3, 8)
    f_hi = min(rng.uniform(1500, 2200), 0.4 * fs)
    n = int(rng.integers(200, 601))
    if rng.random() < 0.5:
        f = np.geomspace(f_lo, f_hi, n)
    else:
        f = np.linspace(f_lo, f_hi, n)
    return dict(fs=fs, freq=f, band=(float(f[0]), float(f[-1])))


def _time_setup(rng, effects=()):
    fs = float(rng.choice([2000.0, 4000.0, 5000.0]))
    P = int(rng.integers(1000, 4001))
    n_per = int(rng.integers(3, 9))
    f0 = fs / P
    # excite up to 0.4 fs; with residual compliance only up to 0.12 fs, so that the
    # truncated modes (>= 3x the band top) stay below Nyquist: above it, a lightly damped
    # mode aliases into the band as a visible resonance, not a static compliance
    f_hi = (0.12 if "residual_compliance" in effects else 0.4) * fs
    kmax = int(f_hi / f0)
    return dict(fs=fs, P=P, n_per=n_per, f0=f0, kmax=kmax, band=(f0, kmax * f0))


def _multisine(rng, setup, n_u):
    """Zippered random-phase multisines (one disjoint line set per input; lines half
    log-spread, half uniform over the harmonics), force amplitude rising ~f^p with p near 2
    (about flat in position for a free mass), zero mean and no velocity drift of a free mass."""
    P, kmax = setup["P"], setup["kmax"]
    n_lines = int(rng.integers(150, 400))
    k_log = np.round(np.exp(rng.uniform(0, np.log(kmax), n_lines))).astype(int)
    k_lin = rng.integers(1, kmax + 1, n_lines)
    ks = np.unique(np.concatenate([[1, 2], k_log[: n_lines // 2], k_lin[: n_lines // 2]]))
    ks = ks[(ks >= 1) & (ks <= kmax)]
    p = rng.uniform(1.8, 2.2)
    t = np.arange(P)
    u = np.zeros((P, n_u))
    q = np.zeros((P, n_u))  # the same lines in sine phase: the drift correction
    start = int(rng.integers(n_u))
    for j, k in enumerate(ks):
        i = (j + start) % n_u
        amp = (k / kmax) ** p + 1e-3
        wt = TWO_PI * k * t / P
        u[:, i] += amp * np.cos(wt + rng.uniform(0, TWO_PI))
        q[:, i] += amp * np.sin(wt)
    for i in range(n_u):
        u[:, i] -= u[:, i].mean()
        q[:, i] -= q[:, i].mean()
        # a free mass (double integrator, ZOH) drifts unless mean(cumsum(u)) over a period
        # is zero; subtract the multiple of q (same lines, same spectrum shape) that does it
        a = np.mean(np.cumsum(u[:, i])) / np.mean(np.cumsum(q[:, i]))
        u[:, i] -= a * q[:, i]
        u[:, i] *= rng.uniform(5, 30) / np.sqrt(np.mean(u[:, i] ** 2))  # rms 5..30 N
    return np.tile(u, (setup["n_per"], 1)), ks


def _measure(rng, truth: Plant, kind: str, setup):
    """Return (data, noise_floor, clean) for the truth."""
    if kind == "frf":
        f = setup["freq"]
        G0 = frf_of(truth, f)
        r = rng.uniform(0.001, 0.01)
        line_rms = np.linalg.norm(G0, axis=(1, 2)) / np.sqrt(G0.shape[1] * G0.shape[2])
        sig = r * np.maximum(np.abs(G0), 0.05 * line_rms[:, None, None])
        noise = sig / np.sqrt(2) * (rng.normal(size=G0.shape) + 1j * rng.normal(size=G0.shape))
        Gm = G0 + noise
        floor = float(np.mean(np.linalg.norm(noise, axis=(1, 2)) / np.linalg.norm(Gm, axis=(1, 2))))
        data = FrfData(freq=f, G=Gm, G_var=sig**2, fs=setup["fs"])
        return data, floor, dict(G0=G0, noise=noise, noise_rel=r)
    u, lines = setup["u"], setup["lines"]
    y0 = simulate(truth, u, setup["fs"])
    r = rng.uniform(0.0005, 0.005)
    noise = rng.normal(size=y0.shape) * (r * y0.std(axis=0))[None, :]
    y = y0 + noise
    floor = float(np.linalg.norm(noise) / np.linalg.norm(y))
    P = setup["P"]
    data = TimeData(fs=setup["fs"], u=u, y=y, period=P, loop="open")
    return data, floor, dict(y0=y0, noise=noise, noise_rel=r, lines=lines)


def nominal_error(nom: Plant, data, setup) -> float:
    if isinstance(data, FrfData):
        return rel_error_frf(data.G, frf_of(nom, data.freq))
    return rel_error_time(data.y, simulate(nom, np.asarray(data.u), data.fs))


# ------------------------------------------------------------------ effects
def _band_modes_ok(p: Plant, f, rel=0.12):
    return all(abs(m.w / TWO_PI - f) / f > rel for m in p.flex())


def apply_effect(rng, nom: Plant, truth: Plant, effect: str, setup, kind: str):
    """Apply ``effect``: mutates ``truth`` (and ``nom`` for modal_mismatch); returns the
    answer entry {effect, parameters}."""
    f_lo, f_hi = setup["band"]
    fs = setup["fs"]
    if effect == "time_delay":
        if kind == "time":
            d = int(rng.integers(1, 4))
            T = d / fs
        else:
            T = rng.uniform(0.5, 3.0) / fs
        truth.delay_s = T
        return dict(effect=effect, parameters={"delay_s": T})
    if effect == "missing_mode":
        lo = max(4 * f_lo, 30.0)
        for _ in range(200):
            f = float(np.exp(rng.uniform(np.log(lo), np.log(0.8 * f_hi))))
            if _band_modes_ok(truth, f):
                break
        z = float(np.exp(rng.uniform(np.log(0.005), np.log(0.05))))
        m_ref = 1.0 / np.linalg.norm(np.outer(truth.modes[0].c, truth.modes[0].b))
        mode = _flex_mode(rng, f, m_ref, truth.n_u, truth.n_y, zeta=z, gain=rng.uniform(0.2, 0.8))
        truth.modes.append(mode)
        return dict(effect=effect, parameters={"freq_hz": f, "damping": z})
    if effect == "modal_mismatch":
        inband = [i for i, m in enumerate(truth.modes) if 0 < m.w / TWO_PI < 0.85 * f_hi]
        i = int(rng.choice(inband))
        mt = truth.modes[i]
        sign = rng.choice([-1.0, 1.0])
        scale = 1.0 + sign * rng.uniform(0.04, 0.12)
        mn = copy.deepcopy(mt)
        mn.w = mt.w * scale
        if rng.random() < 0.5:
            mn.z = mt.z * float(rng.choice([0.5, 2.0]))
        nom.modes[i] = mn
        return dict(
            effect=effect,
            parameters={
                "freq_hz": mt.w / TWO_PI,
                "damping": mt.z,
                "model_freq_hz": mn.w / TWO_PI,
                "model_damping": mn.z,
            },
        )
    if effect in ("actuator_dynamics", "sensor_dynamics"):
        n = truth.n_u if effect == "actuator_dynamics" else truth.n_y
        fcs = [None] * n
        if rng.random() < 0.5:
            for i in range(n):
                fcs[i] = float(rng.uniform(0.3, 1.5) * f_hi)
        else:
            fcs[int(rng.integers(n))] = float(rng.uniform(0.3, 1.5) * f_hi)
        if effect == "actuator_dynamics":
            truth.lag_in = fcs
        else:
            truth.lag_out = fcs
        return dict(effect=effect, parameters={"cutoff_hz": fcs})
    if effect == "suspension_stiffness":
        # the (first) rigid translation becomes a low suspension mode
        i = truth.rigid_idx[0] if truth.kind == "gantry" else int(rng.choice(truth.rigid_idx))
        f = float(rng.uniform(max(2.0, 1.5 * f_lo), 15.0))
        z = float(np.exp(rng.uniform(np.log(0.01), np.log(0.1))))
        truth.modes[i].w = TWO_PI * f
        truth.modes[i].z = z
        return dict(effect=effect, parameters={"freq_hz": f, "damping": z, "mode_index": i})
    if effect == "crosstalk":
        side = "input" if rng.random() < 0.5 else "output"
        n = truth.n_u if side == "input" else truth.n_y
        E = rng.uniform(0.03, 0.10, (n, n)) * rng.choice([-1.0, 1.0], (n, n))
        np.fill_diagonal(E, 0.0)
        T = np.eye(n) + E
        if side == "input":
            truth.T_in = T
        else:
            truth.T_out = T
        return dict(effect=effect, parameters={"matrix": T.tolist(), "side": side})
    if effect == "residual_compliance":
        k = int(rng.integers(1, 3))
        # band top response (nominal) sets the scale so that the residual is visible
        Gtop = frf_of(truth, [f_hi], with_delay=False)[0]
        target = rng.uniform(0.4, 1.0) * np.linalg.norm(Gtop)
        extra = []
        for _ in range(k):
            top = 10.0 if kind == "frf" else min(10.0, 0.45 * fs / f_hi)
            f = float(rng.uniform(3, top) * f_hi)
            extra.append(_flex_mode(rng, f, 1.0, truth.n_u, truth.n_y, gain=1.0))
        R = sum(np.outer(m.c, m.b) / m.w**2 for m in extra)
        sc = target / np.linalg.norm(R)
        for m in extra:
            m.b = m.b * np.sqrt(sc)
            m.c = m.c * np.sqrt(sc)
        truth.modes.extend(extra)
        R = sum(np.outer(m.c, m.b) / m.w**2 for m in extra)
        return dict(
            effect=effect,
            parameters={"matrix": R.tolist(), "mode_freqs_hz": [m.w / TWO_PI for m in extra]},
        )
    if effect == "none":
        return dict(effect="none", parameters={})
    raise ValueError(effect)


# ------------------------------------------------------------------ cases
def make_case(
    rng, plant: str, kind: str, effects, name: str | None = None, max_tries: int = 25
) -> Case:
    effects = tuple([effects] if isinstance(effects, str) else effects)
    base = make_plant(rng, plant)
    setup = _frf_setup(rng) if kind == "frf" else _time_setup(rng, effects)
    if kind == "time":
        setup["u"], setup["lines"] = _multisine(rng, setup, base.n_u)
    best = None
    for attempt in range(max_tries):
        nom = copy.deepcopy(base)
        truth = copy.deepcopy(base)
        answers = [apply_effect(rng, nom, truth, e, setup, kind) for e in effects]
        data, floor, extra = _measure(rng, truth, kind, setup)
        err0 = nominal_error(nom, data, setup)
        vis = err0 / floor
        cand = (nom, truth, answers, data, floor, extra, err0, vis, attempt)
        if effects == ("none",) or vis >= MIN_VISIBILITY:
            best = cand
            break
        if best is None or vis > best[7]:
            best = cand
    nom, truth, answers, data, floor, extra, err0, vis, attempt = best
    nominal = to_ss(nom)
    answer = dict(
        effects=answers,
        noise_floor_error=floor,
        nominal_error=err0,
        visibility=vis,
        band_hz=list(setup["band"]),
        tries=attempt + 1,
        noise_rel=extra["noise_rel"],
    )
    name = name or f"{plant}-{kind}-{'+'.join(effects)}"
    return Case(
        name=name,
        plant=plant,
        kind=kind,
        effects=effects,
        nominal=nominal,
        data=data,
        answer=answer,
        band_hz=setup["band"],
        truth=truth,
        nominal_plant=nom,
    )


def make_suite(seed: int, kinds=("frf", "time"), pairs: bool = False, plants=PLANTS):
    cases = []
    specs = []
    for plant in plants:
        for kind in kinds:
            for e in EFFECTS:
                specs.append((plant, kind, (e,)))
            if pairs:
                for pr in PAIRS:
                    specs.append((plant, kind, pr))
    for idx, (plant, kind, eff) in enumerate(specs):
        # one independent stream per case: adding kinds/pairs does not move other cases
        key = [int(seed), PLANTS.index(plant), ("frf", "time").index(kind)] + [
            EFFECTS.index(e) for e in eff
        ]
        rng = np.random.default_rng(key)
        cases.append(make_case(rng, plant, kind, eff))
    return cases


# ------------------------------------------------------------------ self checks
def self_check(case: Case) -> dict:
    """Checks of the generator on its own (no workbench.diagnosis):
    - state-space realisation vs the modal-sum FRF of the truth (delay-free)
    - time: scipy dlsim vs python-control forced_response of c2d(truth) (+ delay as z^-d)
    - 'none': the nominal error equals the noise floor."""
    out = {}
    truth = case.truth
    f = np.geomspace(1, 3000, 50)
    G = to_ss(truth)
    n = G.A.shape[0]
    # direct resolvent (python-control 0.10 frequency_response loses ~1e-6 here)
    Gs = np.array(
        [G.C @ np.linalg.solve(1j * TWO_PI * fi * np.eye(n) - G.A, G.B) + G.D for fi in f]
    )
    Gm = frf_of(truth, f, with_delay=False)
    scale = np.abs(Gm).max(axis=(1, 2))[:, None, None]
    out["ss_vs_modal_frf"] = float(np.max(np.abs(Gs - Gm) / scale))
    if case.kind == "time":
        d = case.data
        fs = d.fs
        Gd = control.c2d(to_ss(truth), 1.0 / fs, method="zoh")
        nd = delay_samples(truth, fs)
        if nd:
            zd = control.ss(control.tf([1], [1] + [0] * nd, 1.0 / fs))
            Dl = control.append(*([zd] * truth.n_u))
            Gd = Gd * Dl
        T = np.arange(d.n_samples) / fs
        resp = control.forced_response(Gd, T=T, U=np.asarray(d.u).T)
        y_ct = np.atleast_2d(resp.outputs).T
        y_sp = simulate(truth, np.asarray(d.u), fs)
        out["dlsim_vs_control"] = float(np.linalg.norm(y_ct - y_sp) / np.linalg.norm(y_sp))
        # the same ZOH recursion in extended precision: tells roundoff from a real difference
        G = to_ss(truth)
        Ad, Bd, Cd, _, _ = signal.cont2discrete((G.A, G.B, G.C, G.D), 1.0 / fs, method="zoh")
        A, B, C = (M.astype(np.longdouble) for M in (Ad, Bd, Cd))
        u = np.asarray(d.u)
        ud = np.zeros((u.shape[0], u.shape[1]), np.longdouble)
        ud[nd:] = u[: u.shape[0] - nd] if nd else u
        x = np.zeros(A.shape[0], np.longdouble)
        Y = np.zeros((u.shape[0], C.shape[0]), np.longdouble)
        for k in range(u.shape[0]):
            Y[k] = C @ x
            x = A @ x + B @ ud[k]
        Yf = Y.astype(float)
        out["dlsim_vs_longdouble"] = float(np.linalg.norm(y_sp - Yf) / np.linalg.norm(Yf))
        out["control_vs_longdouble"] = float(np.linalg.norm(y_ct - Yf) / np.linalg.norm(Yf))
    if case.effects == ("none",):
        out["none_err_over_floor"] = case.answer["nominal_error"] / case.answer["noise_floor_error"]
    return out


if __name__ == "__main__":  # quick look
    import sys

    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    for c in make_suite(seed, pairs="--pairs" in sys.argv):
        a = c.answer
        print(
            f"{c.name:45s} vis={a['visibility']:8.1f} floor={a['noise_floor_error']:.2e} "
            f"tries={a['tries']} {self_check(c)}"
        )
