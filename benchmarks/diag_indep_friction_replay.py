"""Study: how far a converged simulation can reproduce an indepgen stage friction record.

Run: ``python benchmarks/diag_indep_friction_replay.py [--seed 1]`` (a few minutes).

The diagnosis replays the recorded input open loop through its simulation model and scores
the output against the record (error / noise floor, the floor being the noisy record against
the generator's own noise-free output). This script replays the first stage friction record
of ``bench_diagnose_indep.py --seed S --kinds time --plants stage --effects nonlinearity``
(hard Coulomb friction on the six rigid bodies, tests/indepgen.py) at the TRUE friction levels:

- with the generator's own scheme (its ``time_record`` friction branch: an exact linear
  substep, then each rigid velocity moved toward 0 by at most F_c |b| h; Lie splitting, first
  order), open loop, at its NL_SUBSTEPS = 32 (reproduces its noise-free output exactly, the
  check that this is its scheme) and at 64 ... 512 substeps;
- with the workbench's port kernel (workbench.sim.SubstepZoh: trapezoidal port force, the
  smooth law's end value implicit) at small v0, 8 ... 128 substeps.

Measured (session 28, seed 1, clear; floor 0.00477): the generator's scheme at 64 / 128 / 512
substeps is 3.4 / 4.6 / 5.3 floors from its own 32-substep record, the workbench kernel
(v0 1e-8 m/s) 1.4 / 3.5 / 4.3 floors at 32 / 64 / 128. Both converge to the same motion, ~5
floors from the record: the record's 32-substep splitting error, which its closed loop hides
(the generator measured 5.8e-4 of the rms against 128 substeps in closed loop) and an open-loop
replay of stick-slip on free rigid bodies integrates. A converged simulation cannot reach 2x
the floor on this record; only one on the generator's 32-substep grid can.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

import indepgen  # noqa: E402

from workbench import sim  # noqa: E402
from workbench.core import lti  # noqa: E402


@numba.njit(cache=True)
def _generator_scheme(Ph, Gn, Go, C, D, u, m, ivs, dvs):  # pragma: no cover
    """indepgen.time_record's friction branch, open loop: (N, n_y) noise-free outputs."""
    N, n_u = u.shape
    x = np.zeros(Ph.shape[0])
    y = np.zeros((N, C.shape[0]))
    zero = np.zeros(n_u)
    for k in range(N):
        ua = u[k - m] if k - m >= 0 else zero
        y[k] = C @ x + D @ ua
        ua1 = u[k - m - 1] if k - m - 1 >= 0 else zero
        for j in range(Gn.shape[0]):
            x = Ph @ x + Gn[j] @ ua + Go[j] @ ua1
            for q in range(ivs.shape[0]):
                v = x[ivs[q]]
                x[ivs[q]] = v - np.sign(v) * min(abs(v), dvs[q])
    return y


def _record(seed: int):
    """(truth, u, y, y0, floor) of the first stage friction record the bench draws."""
    rec: dict = {}
    orig = indepgen.time_record

    def capture(truth, nominal, rng, **kw):
        out = orig(truth, nominal, rng, **kw)
        if truth.nl and kw.get("noise_sd", 0) > 0:
            rec.update(truth=truth, u=out[0], y=out[1], y0=out[2])
        return out

    indepgen.time_record = capture
    try:
        rng = np.random.default_rng(seed)
        for size in ("clear", "subtle"):
            case = indepgen.make_case(
                rng, plant="stage", kind="time", effects=("nonlinearity",), size=size,
                case_id=size, periodic=True,
            )  # fmt: skip
            if rec and rec["truth"].nl.get("type") == "friction":
                return rec, case.answer["noise_floor_error"]
            rec.clear()
    finally:
        indepgen.time_record = orig
    raise SystemExit(f"seed {seed}: no stage friction record among its two nonlinearity cases")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    # (the generator's substep matrices are sliced per substep: numba's note on it is noise)
    warnings.filterwarnings("ignore", category=numba.NumbaPerformanceWarning)
    rec, floor = _record(args.seed)
    truth, u, y, y0 = rec["truth"], rec["u"], rec["y"], rec["y0"]
    A, B, C, D = (np.asarray(M, float) for M in truth.ss_mats())
    fs = truth.plant.fs
    off = A.shape[0] - 2 * len(truth.plant.modes) if truth.act_cut is not None else 0
    rig = [i for i, md in enumerate(truth.plant.modes) if md[0] < 30]
    Fc = np.asarray(truth.nl["Fc"], float)
    print(f"seed {args.seed}: fs {fs:g} Hz, F_c {np.round(Fc, 4).tolist()}, floor {floor:.4g}")

    def score(ys, label):
        print(
            f"{label:44s} error {lti.relative_error_time(y, ys) / floor:6.2f} floors, "
            f"against the noise-free record {lti.relative_error_time(y0, ys) / floor:6.2f}",
            flush=True,
        )

    m = int(np.floor(truth.delay_s * fs + 1e-9))
    uc = np.ascontiguousarray(u)
    ivs = np.array([off + 2 * i + 1 for i in rig])
    for n_sub in (32, 64, 128, 512):
        Ph, Gn, Go = indepgen._c2d_substeps(A, B, 1 / fs, truth.delay_s, n_sub)
        h = 1.0 / (fs * n_sub)
        dvs = np.array([Fc[i] * np.linalg.norm(truth.plant.modes[i][2]) * h for i in rig])
        ys = _generator_scheme(Ph, np.ascontiguousarray(Gn), np.ascontiguousarray(Go), C, D,
                               uc, m, ivs, dvs)  # fmt: skip
        score(ys, f"generator's scheme, {n_sub} substeps")
    # the workbench kernel: ports at the rigid bodies (their output rows), the friction force
    # through B (the actuators drive the flexible modes too), the smooth law at small v0
    Cp = np.zeros((6, A.shape[0]))
    for i in rig:
        b = truth.plant.modes[i][2]
        j = int(np.argmax(np.abs(b)))
        Cp[j, off + 2 * i] = b[j]
    for v0 in (1e-7, 1e-8):
        law = sim.PortLaw(Cv=Cp @ A, Cp=Cp, friction_force=Fc, friction_velocity=v0,
                          cubic_stiffness=0.0)  # fmt: skip
        for n_sub in (16, 32, 64, 128):
            prop = sim.substep_zoh(A, B, B, 1 / fs, n_sub, delay_s=truth.delay_s)
            ys = prop.simulate(law, sim.delayed(u, prop.m), sim.delayed(u, prop.m + 1), C, D)[0]
            score(ys, f"workbench kernel, v0 {v0:.0e} m/s, {n_sub} substeps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
