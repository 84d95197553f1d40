"""One parameterized structure per linear effect of the vocabulary.

Each structure maps its nonlinear parameters ``theta`` to an augmented
:class:`~workbench.modal.model.ModalModel` (solving its linear parts by
projection through the problem) and reports physical parameters. Signatures
that the structures encode:

=====================  ===============================================  ==========================
effect                 change to the model                              theta
=====================  ===============================================  ==========================
time_delay             exp(-s tau) on every channel                     tau (ms)
missing_mode           + (N1 s + N0)/(s^2 + 2 z w s + w^2)              ln f, ln z  (N0, N1 linear)
modal_mismatch         one mode's (w, z) moved, residues kept           ln f, ln z
residual_compliance    D + M                                            -           (M linear)
actuator_dynamics      columns times 1/(1 + s tau_j)                    tau_j 2 pi f_max
sensor_dynamics        rows times 1/(1 + s tau_i)                       tau_i 2 pi f_max
suspension_stiffness   rigid-body 1/s^2 -> 1/(s^2 + 2 z w s + w^2)       ln f, ln z
crosstalk              (I + E) G or G (I + E), E off-diagonal            -           (E linear)
=====================  ===============================================  ==========================
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from workbench.diagnosis.fit import FitResult, Realized
from workbench.modal.model import ModalModel, Mode

__all__ = [
    "TimeDelay",
    "MissingMode",
    "ModalMismatch",
    "ResidualCompliance",
    "ActuatorDynamics",
    "SensorDynamics",
    "SuspensionStiffness",
    "Crosstalk",
    "candidate_structures",
]

_LOG_Z = (np.log(1e-4), np.log(0.7))


def _freq_damping(theta) -> tuple[float, float]:
    """(Hz, ratio) of theta = (ln f, ln z)."""
    return float(np.exp(theta[0])), float(np.exp(theta[1]))


def _mode_std(fr: FitResult) -> tuple[float, float, float, float]:
    f, z = np.exp(fr.theta)
    return float(f), float(z), float(f * fr.theta_std[0]), float(z * fr.theta_std[1])


def _rank_one(N: np.ndarray) -> tuple[list[float], list[float]]:
    """c b^T closest to N: (b, c), scaled alike, largest entry of c positive."""
    U, S, Vt = np.linalg.svd(N)
    c = U[:, 0] * np.sqrt(S[0])
    b = Vt[0] * np.sqrt(S[0])
    if c[np.argmax(np.abs(c))] < 0:
        b, c = -b, -c
    return [float(x) for x in b], [float(x) for x in c]


@dataclass(frozen=True)
class TimeDelay:
    effect: str = "time_delay"
    theta_names: tuple[str, ...] = ("delay_ms",)

    def _max_s(self, problem) -> float:
        if problem.kind == "time":
            return 16.0 / problem.fs
        return min(0.05, 10.0 / problem.band_hz[1])

    def grid(self, problem, base):
        tmax = self._max_s(problem)
        if problem.kind == "time":
            samples = np.array([0, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 11, 16])
            return [np.array([k * 1e3 / problem.fs]) for k in samples]
        return [np.array([t * 1e3]) for t in np.linspace(0, tmax, 400)]

    def bounds(self, problem, base):
        return np.array([0.0]), np.array([self._max_s(problem) * 1.2e3])

    def build(self, theta, problem, base):
        return Realized(replace(base, delay_s=base.delay_s + theta[0] * 1e-3))

    def n_linear(self, base):
        return 0

    def report(self, fr, problem, base):
        return {"delay_s": float(fr.theta[0] * 1e-3)}, {"delay_s": float(fr.theta_std[0] * 1e-3)}


@dataclass(frozen=True)
class MissingMode:
    effect: str = "missing_mode"
    theta_names: tuple[str, ...] = ("log_freq_hz", "log_damping")

    def grid(self, problem, base):
        f_lo, f_hi = problem.band_hz
        freqs = list(np.geomspace(f_lo * 1.05, f_hi * 0.98, 70 if problem.kind == "frf" else 40))
        freqs += list(problem.residual_peaks(base))
        zs = (0.004, 0.015, 0.05)
        return [np.log([f, z]) for f in freqs for z in zs]

    def bounds(self, problem, base):
        f_lo, f_hi = problem.band_hz
        return np.array([np.log(0.7 * f_lo), _LOG_Z[0]]), np.array([np.log(1.3 * f_hi), _LOG_Z[1]])

    def build(self, theta, problem, base):
        f, z = _freq_damping(theta)
        mode = Mode("flexible", f, z, np.zeros(base.n_u), np.zeros(base.n_y))
        N0, N1, s0, s1 = problem.fit_new_term(base, mode.denominator())
        # one mode: a residue of rank one across channels (the per-channel fit, projected)
        w = mode.omega
        U, S, Vt = np.linalg.svd(np.vstack([N0, w * N1]), full_matrices=False)
        R = S[0] * np.outer(U[:, 0], Vt[0])
        N0, N1 = R[: base.n_y], R[base.n_y :] / w
        c, b = U[: base.n_y, 0] * np.sqrt(S[0]), Vt[0] * np.sqrt(S[0])  # c b^T = N0
        mode = replace(mode, b=b, c=c, N0=N0, N1=N1, effect="missing_mode")
        return Realized(
            replace(base, modes=base.modes + (mode,)), {"N0": N0, "N1": N1}, {"N0": s0, "N1": s1}
        )

    def n_linear(self, base):
        return 2 * base.n_y * base.n_u

    def report(self, fr, problem, base):
        f, z, sf, sz = _mode_std(fr)
        N0 = fr.realized.linear["N0"]
        b, c = _rank_one(N0)
        return (
            {"freq_hz": f, "damping": z, "b": b, "c": c, "residue_matrix": N0.tolist()},
            {"freq_hz": sf, "damping": sz, "residue_matrix": fr.realized.linear_std["N0"].tolist()},
        )


@dataclass(frozen=True)
class ModalMismatch:
    index: int = 0
    effect: str = "modal_mismatch"
    theta_names: tuple[str, ...] = ("log_freq_hz", "log_damping")

    def grid(self, problem, base):
        t = base.modes[self.index]
        z0 = max(t.damping, 1e-3)
        # a shifted light peak is a narrow valley of the cost: steps of z0/2 near the model mode
        fine = 1 + np.arange(-0.08, 0.0801, max(z0 / 2, 1e-3))
        factors = np.concatenate([np.geomspace(0.7, 1.43, 25), fine])
        freqs = [t.freq_hz * a for a in factors]
        lo, hi = 0.5 * t.freq_hz, 2.0 * t.freq_hz
        freqs += [f for f in problem.residual_peaks(base) if lo < f < hi]
        return [np.log([f, z0 * b]) for f in freqs for b in (0.5, 1.0, 2.0)]

    def bounds(self, problem, base):
        t = base.modes[self.index]
        return np.array([np.log(0.5 * t.freq_hz), _LOG_Z[0]]), np.array(
            [np.log(2.0 * t.freq_hz), _LOG_Z[1]]
        )

    def build(self, theta, problem, base):
        modes = list(base.modes)
        modes[self.index] = modes[self.index].moved(*_freq_damping(theta))
        return Realized(replace(base, modes=tuple(modes)))

    def n_linear(self, base):
        return 0

    def report(self, fr, problem, base):
        f, z, sf, sz = _mode_std(fr)
        t = base.modes[self.index]
        return (
            {"freq_hz": f, "damping": z, "model_freq_hz": t.freq_hz, "model_damping": t.damping},
            {"freq_hz": sf, "damping": sz},
        )


@dataclass(frozen=True)
class SuspensionStiffness:
    effect: str = "suspension_stiffness"
    theta_names: tuple[str, ...] = ("log_freq_hz", "log_damping")

    def _rigid(self, base) -> int:
        return next(i for i, m in enumerate(base.modes) if m.kind == "rigid")

    def _f_max(self, problem, base) -> float:
        flex = [m.freq_hz for m in base.modes if _model_flexible(m) and m.freq_hz > 0]
        return min([problem.band_hz[1]] + [0.7 * f for f in flex])

    def grid(self, problem, base):
        f_lo = problem.band_hz[0]
        hi = self._f_max(problem, base)
        return [
            np.log([f, z])
            for f in np.geomspace(f_lo / 10, min(hi, 30 * f_lo), 30)
            for z in (0.02, 0.1, 0.4)
        ]

    def bounds(self, problem, base):
        f_lo = problem.band_hz[0]
        return (
            np.array([np.log(f_lo / 100), _LOG_Z[0]]),
            np.array([np.log(self._f_max(problem, base)), np.log(2.0)]),
        )

    def build(self, theta, problem, base):
        modes = list(base.modes)
        k = self._rigid(base)
        modes[k] = modes[k].moved(*_freq_damping(theta), effect=self.effect)
        return Realized(replace(base, modes=tuple(modes)))

    def n_linear(self, base):
        return 0

    def report(self, fr, problem, base):
        f, z, sf, sz = _mode_std(fr)
        return {"freq_hz": f, "damping": z}, {"freq_hz": sf, "damping": sz}


class _LinearOnly:
    """An effect whose parameters are all linear, fitted in closed form by the problem:
    no nonlinear parameters, so no start grid and no bounds."""

    def grid(self, problem, base):
        return []

    def bounds(self, problem, base):
        return np.zeros(0), np.zeros(0)


@dataclass(frozen=True)
class ResidualCompliance(_LinearOnly):
    effect: str = "residual_compliance"
    theta_names: tuple[str, ...] = ()

    def build(self, theta, problem, base):
        M, S = problem.fit_feedthrough(base)
        return Realized(replace(base, D=base.D + M), {"matrix": M}, {"matrix": S})

    def n_linear(self, base):
        return base.n_y * base.n_u

    def report(self, fr, problem, base):
        return (
            {"matrix": fr.realized.linear["matrix"].tolist()},
            {"matrix": fr.realized.linear_std["matrix"].tolist()},
        )


@dataclass(frozen=True)
class _Lag:
    side: str = "in"

    def _n(self, base):
        return base.n_u if self.side == "in" else base.n_y

    def _scale(self, problem) -> float:
        return 2 * np.pi * problem.band_hz[1]

    def grid(self, problem, base):
        n = self._n(base)
        levels = (0.03, 0.1, 0.3, 1.0, 3.0)
        points = [np.full(n, a) for a in (0.0,) + levels]
        # lags on some channels only: the best level per channel alone, then combined
        best = np.zeros(n)
        cost0 = problem.cost(base)
        for j in range(n):
            costs = []
            for a in levels[:4]:
                th = np.zeros(n)
                th[j] = a
                costs.append(problem.cost(self.build(th, problem, base).model))
            k = int(np.argmin(costs))
            if costs[k] < cost0:
                best[j] = levels[k]
        points.append(best)
        return points

    def bounds(self, problem, base):
        n = self._n(base)
        f_lo, f_hi = problem.band_hz
        return np.zeros(n), np.full(n, 3 * f_hi / f_lo)

    def build(self, theta, problem, base):
        tau = np.asarray(theta, float) / self._scale(problem)
        if self.side == "in":
            return Realized(replace(base, tau_in=base.lags("in") + tau))
        return Realized(replace(base, tau_out=base.lags("out") + tau))

    def n_linear(self, base):
        return 0

    def report(self, fr, problem, base):
        f_hi = problem.band_hz[1]
        th = np.maximum(fr.theta, 1e-12)
        fc = f_hi / th
        sfc = f_hi * fr.theta_std / th**2
        cut = [float(x) if x < 1e9 else None for x in fc]
        return {"cutoff_hz": cut}, {
            "cutoff_hz": [float(x) if np.isfinite(x) and x < 1e12 else None for x in sfc]
        }


@dataclass(frozen=True)
class ActuatorDynamics(_Lag):
    side: str = "in"
    effect: str = "actuator_dynamics"

    theta_names: tuple[str, ...] = ("cutoff_norm_per_input",)


@dataclass(frozen=True)
class SensorDynamics(_Lag):
    side: str = "out"
    effect: str = "sensor_dynamics"

    theta_names: tuple[str, ...] = ("cutoff_norm_per_output",)


@dataclass(frozen=True)
class Crosstalk(_LinearOnly):
    side: str = "out"
    effect: str = "crosstalk"
    theta_names: tuple[str, ...] = ()

    def build(self, theta, problem, base):
        E, S = problem.fit_crosstalk(base, self.side)
        T = np.eye(E.shape[0]) + E
        if self.side == "out":
            new = replace(base, T_out=T if base.T_out is None else T @ base.T_out)
        else:
            new = replace(base, T_in=T if base.T_in is None else base.T_in @ T)
        return Realized(new, {"matrix": T}, {"matrix": S})

    def n_linear(self, base):
        n = base.n_y if self.side == "out" else base.n_u
        return n * (n - 1)

    def report(self, fr, problem, base):
        return (
            {
                "matrix": fr.realized.linear["matrix"].tolist(),
                "side": "outputs" if self.side == "out" else "inputs",
            },
            {"matrix": fr.realized.linear_std["matrix"].tolist()},
        )


def _model_flexible(m: Mode) -> bool:
    """A flexible mode of the model (moved or not), not one the diagnosis added or suspended."""
    return m.kind == "flexible" and not m.effect


def candidate_structures(base: ModalModel, problem, *, exclude=()) -> list:
    """Every structure that applies to ``base`` and ``problem``, minus the excluded effects.

    ``base`` is in the diagnosis's form (:func:`workbench.diagnosis.modal.decompose`);
    structures index its modes.
    """
    f_lo, f_hi = problem.band_hz
    out: list = [TimeDelay(), MissingMode(), ResidualCompliance()]
    out += [ActuatorDynamics(), SensorDynamics()]
    for k, m in enumerate(base.modes):
        if _model_flexible(m) and f_lo / 1.4 <= m.freq_hz <= f_hi * 1.4:
            out.append(ModalMismatch(index=k))
    if any(m.kind == "rigid" for m in base.modes):
        out.append(SuspensionStiffness())
    if base.n_y > 1:
        out.append(Crosstalk(side="out"))
    if base.n_u > 1:
        out.append(Crosstalk(side="in"))
    return [s for s in out if s.effect not in exclude or s.effect == "missing_mode"]
