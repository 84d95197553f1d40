"""Synthetic diagnosis cases: a known plant, one physical effect, noise.

Independent of the diagnosis code: the true plant is built with python-control
state-space algebra and ``workbench.core.lti`` only (no modal decomposition), the
effect is applied in its physical form, and the nominal model is the plant
without it. Two plant templates:

- ``stage``: 6x6 wafer stage, six rigid-body double integrators (masses 20 kg,
  inertias 0.38/0.46/0.58 kg m^2, like the shared example) plus two flexible
  modes at 914 and 1032 Hz, measured 2-2500 Hz;
- ``beam``: 3 actuators x 5 sensors on a free-free-ish suspended beam, no
  rigid body, seven modes between 3 and 950 Hz, measured 0.5-1000 Hz, with a
  feedthrough for the truncated modes.

FRF noise is complex Gaussian with standard deviation
``rel * (|G_ij| + 0.1 ||G||_F / sqrt(n_y n_u))`` per element and ``G_var`` its
variance; time noise is white on y. ``visibility`` = nominal error / noise
floor, as in the shared examples' answer files.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

from workbench import sim
from workbench.core import lti
from workbench.io.formats import FrfData, TimeData

# ------------------------------------------------------------------ templates
_STAGE_B = np.array(
    [[0.012, -0.018, 0.085, 0.62, -0.48, 0.09], [0.06, 0.045, -0.03, 0.2, 0.28, 0.55]]
)
_STAGE_C = np.array([[0.1, -0.05, 0.3, 0.6, -0.4, 0.05], [0.08, 0.1, -0.05, 0.25, 0.3, 0.5]])


def _mode_ss(f_hz, zeta, b, c):
    """Modal coordinate q'' + 2 z w q' + w^2 q = b u, y = c q (as a 2-state ss)."""
    w = 2 * np.pi * f_hz
    A = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
    B = np.vstack([np.zeros_like(b), b])[:, :]
    C = np.column_stack([c, np.zeros_like(c)])
    return A, B, C


@dataclass
class Plant:
    """Parameters of a template plant; ``build`` gives the StateSpace."""

    name: str
    rigid_inv_mass: np.ndarray  # (n_rigid,) 1/m per rigid DOF, or empty
    modes: list  # (f_hz, zeta, b (n_u,), c (n_y,))
    D: np.ndarray
    n_u: int
    n_y: int
    susp: tuple | None = None  # (f_hz, zeta) applied to the rigid-body DOFs

    def build(self):
        blocks_A, blocks_B, blocks_C = [], [], []
        for k, g in enumerate(self.rigid_inv_mass):
            b = np.zeros(self.n_u)
            b[k] = np.sqrt(g)
            c = np.zeros(self.n_y)
            c[k] = np.sqrt(g)
            if self.susp is None:
                A = np.array([[0.0, 1.0], [0.0, 0.0]])
                B = np.vstack([np.zeros(self.n_u), b])
                C = np.column_stack([c, np.zeros(self.n_y)])
            else:
                A, B, C = _mode_ss(self.susp[0], self.susp[1], b, c)
            blocks_A.append(A)
            blocks_B.append(B)
            blocks_C.append(C)
        for f, z, b, c in self.modes:
            A, B, C = _mode_ss(f, z, np.asarray(b, float), np.asarray(c, float))
            blocks_A.append(A)
            blocks_B.append(B)
            blocks_C.append(C)
        import scipy.linalg

        A = scipy.linalg.block_diag(*blocks_A)
        return control.ss(A, np.vstack(blocks_B), np.hstack(blocks_C), self.D)

    def copy(self, **kw):
        d = dict(self.__dict__)
        d["modes"] = list(self.modes)
        d.update(kw)
        return Plant(**d)


def stage() -> Plant:
    inv_m = np.array([1 / 20, 1 / 20, 1 / 20, 1 / 0.38, 1 / 0.46, 1 / 0.58])
    modes = [
        (913.8, 0.0091, _STAGE_B[0], _STAGE_C[0]),
        (1032.0, 0.0095, _STAGE_B[1], _STAGE_C[1]),
    ]
    return Plant("stage", inv_m, modes, np.zeros((6, 6)), 6, 6)


def beam() -> Plant:
    rng = np.random.default_rng(7)  # fixed template, not a random case
    freqs = [2.8, 36.0, 110.9, 230.0, 410.0, 650.0, 940.0]
    modes = []
    x_act = np.array([0.15, 0.5, 0.85])
    x_sen = np.array([0.05, 0.3, 0.5, 0.7, 0.95])
    for k, f in enumerate(freqs):
        shape = lambda x: np.cos((k + 1) * np.pi * x)  # noqa: E731
        z = 0.03 if k == 0 else 0.005 + 0.0005 * k
        modes.append((f, z, 0.6 * shape(x_act), 0.6 * shape(x_sen)))
    D = 1e-9 * rng.standard_normal((5, 3))
    return Plant("beam", np.zeros(0), modes, D, 3, 5)


def freq_grid(plant: Plant) -> np.ndarray:
    return np.arange(2.0, 2500.0, 2.0) if plant.name == "stage" else np.arange(0.5, 1000.01, 1.0)


# ------------------------------------------------------------------- effects
@dataclass
class Case:
    nominal: object  # control.StateSpace
    data: object  # FrfData | TimeData
    effect: str
    truth: dict
    noise_floor: float
    visibility: float


def _lag_ss(tau):
    n = len(tau)
    return control.ss(
        -np.diag(1 / np.asarray(tau)), np.diag(1 / np.asarray(tau)), np.eye(n), np.zeros((n, n))
    )


def true_plant(plant: Plant, effect: str, p: dict):
    """(nominal StateSpace, true StateSpace, delay_s) for an effect with parameters p."""
    nominal = plant.build()
    delay = 0.0
    if effect == "none":
        return nominal, nominal, 0.0
    if effect == "time_delay":
        return nominal, nominal, p["delay_s"]
    if effect == "missing_mode":
        true = plant.copy(
            modes=plant.modes + [(p["freq_hz"], p["damping"], p["b"], p["c"])]
        ).build()
        return nominal, true, delay
    if effect == "modal_mismatch":
        k = p["index"]
        f, z, b, c = plant.modes[k]
        modes = list(plant.modes)
        modes[k] = (p["model_freq_hz"], z, b, c)
        nominal = plant.copy(modes=modes).build()
        modes[k] = (f, p.get("damping", z), b, c)
        return nominal, plant.copy(modes=modes).build(), delay
    if effect == "residual_compliance":
        # modes far above the band: their static part is what the nominal lacks
        extra = [(p["freq_hz"], 0.02, p["b"], p["c"])]
        return nominal, plant.copy(modes=plant.modes + extra).build(), delay
    if effect == "actuator_dynamics":
        tau = np.array([1 / (2 * np.pi * fc) if fc else 1e-12 for fc in p["cutoff_hz"]])
        return nominal, control.series(_lag_ss(tau), nominal), delay
    if effect == "sensor_dynamics":
        tau = np.array([1 / (2 * np.pi * fc) if fc else 1e-12 for fc in p["cutoff_hz"]])
        return nominal, control.series(nominal, _lag_ss(tau)), delay
    if effect == "suspension_stiffness":
        return nominal, plant.copy(susp=(p["freq_hz"], p["damping"])).build(), delay
    if effect == "crosstalk":
        T = np.asarray(p["matrix"])
        true = control.ss(nominal.A, nominal.B, T @ nominal.C, T @ nominal.D)
        return nominal, true, delay
    raise ValueError(effect)


def frf_case(plant: Plant, effect: str, p: dict, *, rel: float, rng: np.random.Generator) -> Case:
    nominal, true, delay = true_plant(plant, effect, p)
    f = freq_grid(plant)
    G = lti.frf(true, f, delay_s=delay)
    nrm = np.linalg.norm(G, axis=(1, 2))[:, None, None]
    sd = rel * (np.abs(G) + 0.1 * nrm / np.sqrt(G.shape[1] * G.shape[2]))
    noise = sd / np.sqrt(2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    Gm = G + noise
    data = FrfData(freq=f, G=Gm, G_var=sd**2, fs=5000.0)
    floor = lti.relative_error_frf(Gm, G)
    nom_err = lti.relative_error_frf(Gm, lti.frf(nominal, f))
    return Case(nominal, data, effect, p, floor, nom_err / floor)


def multisine(
    n_u: int,
    period: int,
    fs: float,
    f_max: float,
    rng: np.random.Generator,
    *,
    k_min: int = 1,
    tilt: float = 0.0,
) -> np.ndarray:
    """Odd random-phase multisines, one per input, random phases per input, (period, n_u).

    Lines from k_min; amplitude proportional to (k / k_min)^tilt (tilt = 2 makes the
    position of a mass about flat over frequency).
    """
    k = np.arange(k_min | 1, int(f_max * period / fs), 2)
    k = k[rng.random(k.size) > 0.2]  # random odd lines left empty (nonlinearity detection)
    amp = (k / k[0]) ** tilt
    t = np.arange(period)
    u = np.zeros((period, n_u))
    for j in range(n_u):
        ph = rng.uniform(0, 2 * np.pi, k.size)
        u[:, j] = (amp * np.cos(2 * np.pi * np.outer(t, k) / period + ph)).sum(axis=1)
        u[:, j] /= u[:, j].std()
    return u


def time_case(
    plant: Plant,
    effect: str,
    p: dict,
    *,
    rel: float,
    rng: np.random.Generator,
    fs: float = 5000.0,
    period: int = 2000,
    n_periods: int = 4,
) -> Case:
    """Periodic record from rest with white output noise (rel x output rms).

    Plants with rigid-body modes are measured in closed loop (a PD controller per
    axis with a 10 Hz bandwidth, as a stage is), others in open loop.
    """
    nominal, true, delay = true_plant(plant, effect, p)
    closed = len(plant.rigid_inv_mass) > 0
    # stage: force rising with frequency (flatter position); beam: lines above its first mode
    shape = {"tilt": 1.5} if closed else {"k_min": 5}
    r = np.tile(multisine(plant.n_u, period, fs, 0.3 * fs, rng, **shape), (n_periods, 1))
    N = r.shape[0]
    Ad, B0, B1, m = sim.c2d_zoh(true.A, true.B, 1 / fs, delay_s=delay)
    C, D = np.asarray(true.C), np.asarray(true.D)
    noise = rng.standard_normal((N, plant.n_y))
    w = 2 * np.pi * 10.0
    inv_m = np.asarray(plant.rigid_inv_mass)
    kp, kd = (w**2 / inv_m, 2 * 0.7 * w / inv_m) if closed else (0.0, 0.0)

    def run(sd):
        y0 = np.zeros((N, plant.n_y))
        y = np.zeros((N, plant.n_y))
        u = np.zeros((N, plant.n_u))
        x = np.zeros(true.A.shape[0])
        zero = np.zeros(plant.n_u)
        y_prev = np.zeros(plant.n_y)
        for k in range(N):
            um1 = u[k - m - 1] if k - m - 1 >= 0 else zero
            # with m = 0 the feedthrough sees u[k], computed below; D = 0 in closed loop here
            y0[k] = C @ x + (D @ u[k - m] if (k - m >= 0 and m > 0) else 0.0)
            y[k] = y0[k] + sd * noise[k]
            u[k] = r[k] - kp * y[k] - kd * (y[k] - y_prev) * fs if closed else r[k]
            if m == 0:
                y0[k] += D @ u[k]
                y[k] += D @ u[k]
            y_prev = y[k]
            x = Ad @ x + B0 @ (u[k - m] if k - m >= 0 else zero) + B1 @ um1
        return y0, y, u

    y0, _, _ = run(np.zeros(plant.n_y))
    y0, y, u = run(rel * y0.std(axis=0))
    data = TimeData(
        fs=fs, u=u, y=y, r=r if closed else None, loop="closed" if closed else "open", period=period
    )
    floor = lti.relative_error_time(y, y0)
    nom_err = lti.relative_error_time(y, sim.simulate_zoh(nominal, u, fs))
    return Case(nominal, data, effect, p, floor, nom_err / floor)


# --------------------------------------------------------- parameter library
def stage_params(effect: str, size: str) -> dict:
    """Effect parameters for the stage; 'clear' is obvious, 'subtle' near 2-5x the noise error."""
    s = size == "subtle"
    b = np.array([0.0, 0.0, 0.5, -0.3, 0.2, 0.0])
    c = np.array([0.0, 0.0, 0.45, -0.35, 0.25, 0.0])
    return {
        "none": {},
        "time_delay": {"delay_s": 4e-6 if s else 2e-4},
        "missing_mode": {"freq_hz": 1320.0, "damping": 0.012, "b": b * (0.06 if s else 1), "c": c},
        "modal_mismatch": {"index": 0, "model_freq_hz": 913.8 * (1.004 if s else 1.06)},
        "residual_compliance": {
            "freq_hz": 20000.0,
            "b": np.array([0.3, 0.1, 0.6, 0.4, 0.2, 0.5]) * (3.5 if s else 8),
            "c": np.array([0.2, 0.5, 0.4, 0.3, 0.6, 0.1]) * (3.5 if s else 8),
        },
        "actuator_dynamics": {"cutoff_hz": [5000.0 if s else 800.0] * 3 + [None] * 3},
        "sensor_dynamics": {"cutoff_hz": [None] * 3 + [20000.0 if s else 800.0] * 3},
        "suspension_stiffness": {"freq_hz": 4.0 if s else 8.0, "damping": 0.05},
        "crosstalk": {
            "matrix": np.eye(6)
            + (0.01 if s else 0.04)
            * np.array(
                [
                    [0, 1, 0, 0, 0, 0],
                    [-1, 0, 0, 0, 0, 0],
                    [0, 0, 0, 0, 0, 0],
                    [0, 0, 0, 0, 1, 0],
                    [0, 0, 0, -1, 0, 0],
                    [0, 0, 0, 0, 0, 0],
                ]
            )
        },
    }[effect]


def beam_params(effect: str, size: str) -> dict:
    s = size == "subtle"
    return {
        "none": {},
        "time_delay": {"delay_s": 1e-5 if s else 3e-4},
        "missing_mode": {
            "freq_hz": 530.0,
            "damping": 0.008,
            "b": np.array([0.5, -0.2, 0.4]) * (0.08 if s else 1),
            "c": np.array([0.3, 0.5, -0.2, 0.4, 0.1]),
        },
        "modal_mismatch": {"index": 3, "model_freq_hz": 230.0 * (1.006 if s else 1.08)},
        "residual_compliance": {
            "freq_hz": 20000.0,
            "b": np.array([0.6, 0.5, 0.6]) * (12 if s else 30),
            "c": np.array([0.5, 0.4, 0.3, 0.4, 0.5]) * (12 if s else 30),
        },
        "actuator_dynamics": {"cutoff_hz": [8000.0 if s else 300.0, None, None]},
        "sensor_dynamics": {"cutoff_hz": [None, None, 8000.0 if s else 300.0, None, None]},
        "crosstalk": {"matrix": np.eye(5) + (0.012 if s else 0.03) * np.diag(np.ones(4), 1)},
    }[effect]


def test_generator_noise_floor_matches_g_var():
    # the noise floor estimate from G_var (sqrt of summed variances per line) is what the
    # spec's measure gives for the true model, within 10 % (oracle: E||n||_F ~ sqrt(sum var))
    rng = np.random.default_rng(1)
    case = frf_case(stage(), "none", {}, rel=0.005, rng=rng)
    est = np.mean(
        np.sqrt(case.data.G_var.sum(axis=(1, 2))) / np.linalg.norm(case.data.G, axis=(1, 2))
    )
    assert abs(est / case.noise_floor - 1) < 0.1
    assert case.visibility == 1.0
