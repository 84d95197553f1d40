"""Diagnosis cases made with plants/: a true plant with hidden effects, the nominal
model an engineer has, and a measurement (FRF or time) of the true plant.

Used by tests/test_diagnosis_suite.py (a CI subset) and
benchmarks/bench_diagnosis_suite.py (the whole suite with its confusion table).
The nominal model is the same plant with every effect off; the truth differs
from it only by the effects named in the case, so the right answer is known.
Sizes: "clear" (the effect's error is many times the noise-induced error) and
"subtle" (2-5x); the visibility actually reached is measured and reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numba
import numpy as np
import scipy.linalg

import plants
from plants.effects import ExtraMode
from workbench import sim
from workbench.core import lti
from workbench.io.formats import FrfData, TimeData

# (plant, effect) -> size -> Effects fields. Values are physical: a one-sample
# computation delay, an amplifier lag at a few kHz, a 3 % too stiff mode ...
STAGE_EFFECTS: dict[str, dict[str, dict[str, Any]]] = {
    "time_delay": {"clear": {"delay_s": 2e-4}, "subtle": {"delay_s": 4e-5}},
    "missing_mode": {
        "clear": {
            "extra_modes": (
                ExtraMode(1320.0, 0.012, (0, 0, 0.5, -0.3, 0.2, 0), (0, 0, 0.45, -0.35, 0.25, 0)),
            )
        },
        "subtle": {
            "extra_modes": (
                ExtraMode(640.0, 0.02, (0.05, 0, 0.1, 0.3, 0, 0), (0.04, 0, 0.08, 0.25, 0, 0)),
            )
        },
    },
    "modal_mismatch": {
        "clear": {"mode_freq_error": (0.04, 0.0)},
        "subtle": {"mode_freq_error": (0.0, 0.015)},
    },
    "residual_compliance": {"clear": {"residual_max_hz": 8000.0}},
    "actuator_dynamics": {
        # per-channel cutoffs: one equal cutoff on every channel of a square plant
        # is indistinguishable from the same sensor lag (diag(l) G = G diag(l))
        "clear": {"actuator_cutoff_hz": (1200.0, 1500.0, 1000.0, 1800.0, 1300.0, 1100.0)},
        "subtle": {"actuator_cutoff_hz": (np.inf, np.inf, 4000.0, 4000.0, 4000.0, np.inf)},
    },
    "sensor_dynamics": {
        "clear": {"sensor_cutoff_hz": (1500.0, 1200.0, 1800.0, 1000.0, 1400.0, 1600.0)},
        "subtle": {"sensor_cutoff_hz": (np.inf, 2500.0, np.inf, np.inf, np.inf, np.inf)},
    },
    "suspension_stiffness": {
        "clear": {"suspension_freq_hz": 15.0, "suspension_damping": 0.05},
        "subtle": {"suspension_freq_hz": 6.0, "suspension_damping": 0.05},
    },
    "crosstalk": {"clear": {"_crosstalk": 0.02}, "subtle": {"_crosstalk": 0.008}},
    "none": {"-": {}},
}

BEAM_EFFECTS: dict[str, dict[str, dict[str, Any]]] = {
    "time_delay": {"clear": {"delay_s": 4.9e-4}, "subtle": {"delay_s": 1e-4}},
    "missing_mode": {
        "clear": {
            "extra_modes": (ExtraMode(610.0, 0.01, (2.4, -1.2, 1.8), (1.8, 0.6, -1.2, 1.5, -1.8)),)
        }
    },
    "modal_mismatch": {"clear": {"mode_freq_error": (0, 0.03, 0, 0, 0, 0, 0)}},
    "residual_compliance": {"clear": {"residual_max_hz": 6000.0}},
    "actuator_dynamics": {"clear": {"actuator_cutoff_hz": 500.0}},
    "sensor_dynamics": {"clear": {"sensor_cutoff_hz": (np.inf, np.inf, 400.0, np.inf, np.inf)}},
    "crosstalk": {"clear": {"_crosstalk": 0.03}},
    "none": {"-": {}},
}


# Effects a time record of that plant cannot show (measured visibility ~1):
# the stage's truncated modes are static compliance far below its rigid-body
# motion; the open-loop beam record is dominated by its suspension modes.
TIME_INVISIBLE = {
    ("wafer_stage", "residual_compliance"),
    ("beam", "residual_compliance"),
    ("beam", "missing_mode"),
}


@dataclass(frozen=True)
class Case:
    """One diagnosis case and its answer."""

    case_id: str
    plant: str
    data_kind: str  # "frf" or "time"
    effects: tuple[str, ...]
    size: str
    model: Any  # control.StateSpace, continuous, the nominal model
    data: FrfData | TimeData
    truth: dict[str, Any] = field(default_factory=dict)  # effect -> key parameters
    noise_floor: float = 0.0  # spec error of the noise-free truth (its friction included)
    nominal_error: float = 0.0  # spec error of the nominal model
    # effect -> the effect that explains the data identically (one lag on every input is the
    # same lag on every output: l G = G l for a scalar l), accepted in its place
    equivalent: dict[str, str] = field(default_factory=dict)

    @property
    def visibility(self) -> float:
        return self.nominal_error / max(self.noise_floor, 1e-300)


def _crosstalk(n: int, level: float, rng: np.random.Generator) -> np.ndarray:
    X = level * rng.standard_normal((n, n))
    np.fill_diagonal(X, 0.0)
    return X


def _fields(plant: str, effect: str, size: str, rng) -> dict[str, Any]:
    table = STAGE_EFFECTS if plant == "wafer_stage" else BEAM_EFFECTS
    spec = dict(table[effect][size])
    if "_crosstalk" in spec:
        n_y = 6 if plant == "wafer_stage" else 5
        spec = {"crosstalk_output": _crosstalk(n_y, spec.pop("_crosstalk"), rng)}
    return spec


def _truth(fields: dict[str, Any]) -> dict[str, Any]:
    t: dict[str, Any] = {}
    if "delay_s" in fields:
        t["delay_s"] = fields["delay_s"]
    if "extra_modes" in fields:
        m = fields["extra_modes"][0]
        t.update(freq_hz=m.freq_hz, damping=m.damping)
    if "actuator_cutoff_hz" in fields or "sensor_cutoff_hz" in fields:
        c = np.atleast_1d(fields.get("actuator_cutoff_hz", fields.get("sensor_cutoff_hz")))
        t["cutoff_hz"] = float(np.min(c))
    if "suspension_freq_hz" in fields:
        t["freq_hz"] = float(np.atleast_1d(fields["suspension_freq_hz"])[0])
    if "friction_force" in fields:  # the same level at every port, N
        t.update(element="coulomb_friction", friction_force=float(fields["friction_force"]))
    return t


def _frf_data(true_plant, nominal, freq, rel_noise, rng):
    """Analytic FRF of the truth plus complex Gaussian noise with a known G_var."""
    G = true_plant.frf(freq)
    scale = np.linalg.norm(G, axis=(1, 2), keepdims=True) / np.sqrt(G.shape[1] * G.shape[2])
    sigma = rel_noise * (np.abs(G) + 0.05 * scale)
    noise = sigma * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape)) / np.sqrt(2)
    data = FrfData(
        freq=freq,
        G=G + noise,
        G_var=sigma**2,
        fs=true_plant.fs,
        input_names=true_plant.input_names,
        output_names=true_plant.output_names,
    )
    floor = lti.relative_error_frf(data.G, G)
    return data, floor


# ---------------------------------------------------------------- friction, casegen's own truth
# The plants' nonlinear path and the diagnosis' simulation models share one port-force
# substep (workbench._port_kernel); a record made with it would reward a model that copies its
# scheme. casegen integrates the friction with its own, different scheme instead: the port
# force taken at the END of each substep (implicit Euler in the force, the linear part exact),
# run with n and 2n substeps from every sample's state and extrapolated, x = 2 x_2n - x_n
# (Richardson: the first-order error cancels, second order). n per plant below: the
# extrapolated record is within a few hundredths of its noise of the converged response
# (tests/test_port_substeps.py checks it against the plants' simulation at 4x its substeps).
FRICTION_SUBSTEPS = {"beam": 64, "wafer_stage": 128}


@numba.njit(cache=True)
def _implicit_euler_substeps(x, Phi, Gu, Gf, Cv, Mv, Fc, v0, u, n):  # pragma: no cover
    """x after n substeps of x+ = Phi x + Gu u + Gf f+, f+ = -Fc tanh(Cv x+ / v0) (N).

    f+ solves f + Fc tanh((Cv xp + Mv f) / v0) = 0, Mv = Cv Gf: Newton (Gauss-Jordan on the
    small port system), each step halved until the residual's norm falls. Loops written out:
    small matrices, called for every sample.
    """
    n_x = x.shape[0]
    n_u = u.shape[0]
    n_p = Fc.shape[0]
    scale = 1e-300
    for i in range(n_p):
        scale = max(scale, Fc[i])
    f = np.zeros(n_p)
    x = x.copy()
    xp = np.empty(n_x)
    a = np.empty(n_p)
    t = np.empty(n_p)
    g = np.empty(n_p)
    d = np.empty(n_p)
    fn = np.empty(n_p)
    J = np.empty((n_p, n_p + 1))
    for _ in range(n):
        for i in range(n_x):
            acc = 0.0
            for k in range(n_x):
                acc += Phi[i, k] * x[k]
            for k in range(n_u):
                acc += Gu[i, k] * u[k]
            xp[i] = acc
        for i in range(n_p):
            acc = 0.0
            for k in range(n_x):
                acc += Cv[i, k] * xp[k]
            a[i] = acc
        for _it in range(200):
            norm = 0.0
            gmax = 0.0
            for i in range(n_p):
                w = a[i]
                for k in range(n_p):
                    w += Mv[i, k] * f[k]
                t[i] = np.tanh(w / v0)
                g[i] = f[i] + Fc[i] * t[i]
                norm += g[i] * g[i]
                gmax = max(gmax, abs(g[i]))
            if gmax <= 1e-13 * scale:
                break
            for i in range(n_p):  # [J | -g], J = I + diag(Fc sech^2 / v0) Mv
                s = Fc[i] * (1.0 - t[i] * t[i]) / v0
                for k in range(n_p):
                    J[i, k] = s * Mv[i, k] + (1.0 if i == k else 0.0)
                J[i, n_p] = -g[i]
            for c in range(n_p):  # Gauss-Jordan with partial pivoting
                piv = c
                for i in range(c + 1, n_p):
                    if abs(J[i, c]) > abs(J[piv, c]):
                        piv = i
                for k in range(n_p + 1):
                    J[c, k], J[piv, k] = J[piv, k], J[c, k]
                for i in range(n_p):
                    if i != c:
                        r = J[i, c] / J[c, c]
                        for k in range(c, n_p + 1):
                            J[i, k] -= r * J[c, k]
            dmax = 0.0
            for i in range(n_p):
                d[i] = J[i, n_p] / J[i, i]
                dmax = max(dmax, abs(d[i]))
            step = 1.0
            while True:
                for i in range(n_p):
                    fn[i] = f[i] + step * d[i]
                nn = 0.0
                for i in range(n_p):
                    w = a[i]
                    for k in range(n_p):
                        w += Mv[i, k] * fn[k]
                    gi = fn[i] + Fc[i] * np.tanh(w / v0)
                    nn += gi * gi
                if nn < norm or step < 1e-8:
                    break
                step *= 0.5
            for i in range(n_p):
                f[i] = fn[i]
            if step * dmax <= 1e-13 * scale:
                break
        for i in range(n_x):
            acc = xp[i]
            for k in range(n_p):
                acc += Gf[i, k] * f[k]
            x[i] = acc
    return x


@dataclass(frozen=True)
class FrictionTruth:
    """A plant with Coulomb friction, its friction integrated by casegen's own scheme.

    Everything but the simulation is the plant's (``__getattr__``): its linear model, its
    measurement (noise, quantization), its names. A closed loop steps it sample by sample
    (``init``/``step``); ``sampled_step`` is None (no compiled linear loop).

    Parameters
    ----------
    plant : plants.mechanical.MechanicalPlant
        The true plant, friction on (``effects.friction_force``), no saturation, a delay
        of whole samples.
    substeps : int
        n of the module's scheme (the extrapolation also runs 2n).
    """

    plant: Any
    substeps: int

    def __getattr__(self, name):
        return getattr(self.plant, name)

    @cached_property
    def _matrices(self):
        p = self.plant
        e = p.chain.effects
        if e.saturation is not None or e.cubic_stiffness is not None:
            raise ValueError("FrictionTruth: friction only (no saturation, no cubic spring)")
        m = int(round(p.delay_s * p.fs))
        if abs(p.delay_s * p.fs - m) > 1e-9:
            raise ValueError(f"FrictionTruth: a delay of whole samples, got {p.delay_s} s")
        mats = p.chain.matrices
        A, B, Bp, Cv = mats["A"], mats["B"], mats["Bp"], mats["Cv"]
        n, n_u, n_p = A.shape[0], B.shape[1], Bp.shape[1]
        fc = np.broadcast_to(np.asarray(e.friction_force, float), (n_p,)).copy()
        out = []
        for n_sub in (self.substeps, 2 * self.substeps):
            h = 1.0 / (p.fs * n_sub)
            M = np.zeros((n + n_u + n_p, n + n_u + n_p))
            M[:n, :n] = A * h
            M[:n, n : n + n_u] = B * h
            M[:n, n + n_u :] = Bp * h
            E = scipy.linalg.expm(M)
            Phi, Gu, Gf = E[:n, :n], E[:n, n : n + n_u], E[:n, n + n_u :]
            c = np.ascontiguousarray
            out.append((c(Phi), c(Gu), c(Gf), c(Cv), c(Cv @ Gf), fc, float(e.friction_velocity)))
        return m, mats["C"], mats["D"], out

    def _advance(self, x, u):
        """The state one sample on from x with u (n_u,) applied (held)."""
        (_, _, _, coarse_fine) = self._matrices
        coarse, fine = coarse_fine
        u = np.ascontiguousarray(u, dtype=float)
        x_n = _implicit_euler_substeps(x, *coarse, u, self.substeps)
        x_2n = _implicit_euler_substeps(x, *fine, u, 2 * self.substeps)
        return 2.0 * x_2n - x_n

    def simulate_noise_free(self, u: np.ndarray) -> np.ndarray:
        """Output (N, n_y) from rest for u (N, n_u), y[k] at k / fs."""
        m, C, D, _ = self._matrices
        u = np.asarray(u, float)
        ud = np.zeros_like(u)
        ud[m:] = u[: u.shape[0] - m]
        x = np.zeros(C.shape[1])
        y = np.empty((u.shape[0], C.shape[0]))
        for k in range(u.shape[0]):
            y[k] = C @ x + D @ ud[k]
            x = self._advance(x, ud[k])
        return y

    def simulate(self, u: np.ndarray, *, rng: np.random.Generator) -> np.ndarray:
        return self.plant.measure(self.simulate_noise_free(u), rng)

    def init(self, rng: np.random.Generator):
        m, C, _, _ = self._matrices
        return (np.zeros(C.shape[1]), np.zeros((m + 1, self.plant.n_u)), rng)

    def step(self, state, u_k):
        """Measured y[k], then one sample on with u[k] (through the delay line)."""
        m, C, D, _ = self._matrices
        x, hist, rng = state
        hist = np.vstack([np.asarray(u_k, float).reshape(1, -1), hist[:-1]])  # u[k], u[k-1]..
        y = self.plant.measure((C @ x + D @ hist[m])[None, :], rng)[0]
        return y, (self._advance(x, hist[m]), hist, rng)

    def sampled_step(self):
        return None


def _time_data(true_plant, rng):
    """(record, noise floor): the floor is the record's error against its noise-free truth
    driven by the recorded u, the friction included (a FrictionTruth simulated by its own
    scheme): the linear truth's error would be the friction's share, not the noise's."""
    from workbench.experiments import ExperimentConfig, run_experiment

    if true_plant.n_u == true_plant.n_y:
        cfg = ExperimentConfig(kind="closed_loop_multisine", period=2000, periods=5)
    else:
        cfg = ExperimentConfig(kind="open_loop_multisine", n_exp=1, period=2048, periods=5)
    data = run_experiment(true_plant, cfg, rng=rng)
    if isinstance(true_plant, FrictionTruth):
        y_true = true_plant.simulate_noise_free(data.u)
    else:
        y_true = sim.simulate_zoh(
            true_plant.linear_model(), data.u, data.fs, delay_s=true_plant.delay_s
        )
    return data, lti.relative_error_time(data.y, y_true)


def make_case(
    plant: str,
    data_kind: str,
    effects: tuple[tuple[str, str], ...],
    *,
    seed: int,
    rel_noise: float = 0.005,
) -> Case:
    """Build one case: ``effects`` is ((effect, size), ...); () or (("none", "-"),) is clean."""
    rng = np.random.default_rng(seed)
    fields: dict[str, Any] = {"delay_s": 0.0}
    truth: dict[str, Any] = {}
    equivalent: dict[str, str] = {}
    names = []
    for effect, size in effects:
        if effect == "nonlinearity":
            # Coulomb friction, N; v0 well below the motion's velocities (stage ~1e-4 m/s,
            # beam ~1e-3 m/s), else the smooth law is a viscous damper, a linear effect
            level = {"clear": 0.2, "subtle": 0.05}[size]
            f = {
                "friction_force": level if plant == "wafer_stage" else 2e-3 * level,
                "friction_velocity": 1e-6 if plant == "wafer_stage" else 1e-5,
            }
        else:
            f = _fields(plant, effect, size, rng)
        fields.update(f)
        truth[effect] = _truth(f)
        names.append(effect)
        lag = f.get("actuator_cutoff_hz", f.get("sensor_cutoff_hz"))
        if lag is not None and np.unique(np.atleast_1d(lag)).size == 1:
            equivalent[effect] = (
                "sensor_dynamics" if effect == "actuator_dynamics" else "actuator_dynamics"
            )
    make = plants.get_plant
    true_plant = make(plant, **fields)
    if "friction_force" in fields:  # casegen's own friction integrator (see FrictionTruth)
        true_plant = FrictionTruth(true_plant, FRICTION_SUBSTEPS[plant])
    nominal = make(plant, delay_s=0.0).linear_model()
    if data_kind == "frf":
        fs = true_plant.fs
        df = 1.0 if plant == "wafer_stage" else 0.5
        freq = np.arange(1, int(0.5 * fs / df)) * df
        freq = freq[freq >= (2.0 if plant == "wafer_stage" else 1.0)]
        data, floor = _frf_data(true_plant, nominal, freq, rel_noise, rng)
        nominal_error = lti.relative_error_frf(data.G, lti.frf(nominal, data.freq))
    else:
        data, floor = _time_data(true_plant, rng)
        nominal_error = lti.relative_error_time(data.y, sim.simulate_zoh(nominal, data.u, data.fs))
    size = "+".join(s for _, s in effects) or "-"
    return Case(
        case_id=f"{plant}_{data_kind}_{'+'.join(names) or 'none'}_{size}_{seed}",
        plant=plant,
        data_kind=data_kind,
        effects=tuple(names) or ("none",),
        size=size,
        model=nominal,
        data=data,
        truth=truth,
        noise_floor=floor,
        nominal_error=nominal_error,
        equivalent=equivalent,
    )


def suite(*, full: bool = True, seed: int = 1000) -> list[tuple[str, str, tuple]]:
    """The list of (plant, data_kind, effects) of the suite; ``full=False`` is the CI subset."""
    out: list[tuple[str, str, tuple]] = []
    for plant, table in (("wafer_stage", STAGE_EFFECTS), ("beam", BEAM_EFFECTS)):
        kinds = ("frf", "time") if full or plant == "wafer_stage" else ("frf",)
        for kind in kinds:
            for effect, sizes in table.items():
                if kind == "time" and (plant, effect) in TIME_INVISIBLE:
                    continue
                for size in sizes if full else list(sizes)[:1]:
                    out.append((plant, kind, ((effect, size),)))
            if kind == "time":
                out.append((plant, kind, (("nonlinearity", "clear"),)))
                if full:
                    out.append((plant, kind, (("nonlinearity", "subtle"),)))
    two = [
        ("wafer_stage", "frf", (("time_delay", "clear"), ("missing_mode", "clear"))),
        ("wafer_stage", "time", (("time_delay", "clear"), ("sensor_dynamics", "clear"))),
        ("beam", "frf", (("actuator_dynamics", "clear"), ("missing_mode", "clear"))),
    ]
    out += two if full else two[:1]
    return out


# Tolerances of the issue: delay 10 %, frequencies 1 %, damping 30 %, cutoffs
# 20 %, suspension frequency 10 %.
TOLERANCES = {
    "delay_s": 0.10,
    "freq_hz": 0.01,
    "damping": 0.30,
    "cutoff_hz": 0.20,
    "friction_force": 0.10,  # every port's level (a nonlinearity's fitted element)
}


def _first_finite(value) -> float | None:
    v = np.atleast_1d(np.asarray(value, float)).ravel()
    v = v[np.isfinite(v)]
    return float(v.min()) if v.size else None


def score(case: Case, result: dict) -> dict[str, Any]:
    """Score a findings JSON (spec section 3) against the case's answer."""
    ranked = [f["effect"] for f in result.get("findings", [])]
    expected = list(case.effects)
    top = ranked[: len(expected)]
    named = (
        all(e in top or case.equivalent.get(e) in top for e in expected)
        if expected != ["none"]
        else (ranked[:1] == ["none"])
    )
    as_truth = {v: k for k, v in case.equivalent.items() if v not in case.truth}
    param_ok = True
    param_err: dict[str, float] = {}
    for f in result.get("findings", []):
        truth = case.truth.get(f["effect"], case.truth.get(as_truth.get(f["effect"], "")))
        if not truth:
            continue
        for key, true_value in truth.items():
            if key == "element":  # the fitted port element is named, or not
                got_element = f.get("parameters", {}).get("element")
                param_err[f"{f['effect']}.element"] = 0.0 if got_element == true_value else np.inf
                param_ok &= got_element == true_value
                continue
            tol = TOLERANCES[key]
            if f["effect"] == "suspension_stiffness" and key == "freq_hz":
                tol = 0.10
            got = _first_finite(f.get("parameters", {}).get(key, np.nan))
            err = np.inf if got is None else abs(got - true_value) / abs(true_value)
            if key == "friction_force":  # every port where the element acts, not the first
                lv = np.asarray(f.get("parameters", {}).get(key, np.nan), float).ravel()
                lv = lv[np.isfinite(lv) & (lv > 0)]
                err = float(np.max(np.abs(lv - true_value))) / true_value if lv.size else np.inf
            param_err[f"{f['effect']}.{key}"] = err
            param_ok &= bool(err <= tol)
    after = [f.get("error_after") for f in result.get("findings", []) if f["effect"] != "none"]
    final = min([a for a in after if a is not None], default=result.get("error_before", np.inf))
    return {
        "top": ranked[0] if ranked else None,
        "named": bool(named),
        "params_ok": bool(param_ok),
        "param_errors": param_err,
        "error_after_ratio": float(final / case.noise_floor) if case.noise_floor else np.inf,
    }


def confusion_table(rows: list[tuple[str, str]]) -> str:
    """Rows of (expected, top finding) as a text table."""
    labels = sorted({e for e, _ in rows} | {t or "-" for _, t in rows})
    width = max(len(s) for s in labels) + 1
    head = " " * width + " ".join(f"{s[:6]:>6}" for s in labels)
    lines = ["expected \\ top finding", head]
    for e in labels:
        if not any(r[0] == e for r in rows):
            continue
        counts = [sum(1 for r in rows if r[0] == e and (r[1] or "-") == t) for t in labels]
        lines.append(f"{e:<{width}}" + " ".join(f"{c:>6}" for c in counts))
    return "\n".join(lines)
