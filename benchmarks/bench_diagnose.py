"""Timing and accuracy of ``workbench.diagnosis.diagnose`` on synthetic cases.

Run: ``python benchmarks/bench_diagnose.py [--quick]``. Cases come from
tests/test_diagnose_gen.py (a 6x6 stage with ~1250 FRF lines or an
8000-sample closed-loop record; a 3x5 beam), one effect each, 'clear' and
'subtle' sizes, plus the shared examples when present. Prints per case: the
found effect, the key parameter vs truth, error before/after vs the noise
floor and the wall time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from test_diagnose_gen import (  # noqa: E402
    beam,
    beam_params,
    frf_case,
    stage,
    stage_params,
    time_case,
)

from workbench.diagnosis import LINEAR_EFFECTS, diagnose  # noqa: E402

EFFECTS = ["none", *LINEAR_EFFECTS]
KEY = {
    "time_delay": "delay_s",
    "missing_mode": "freq_hz",
    "modal_mismatch": "freq_hz",
    "suspension_stiffness": "freq_hz",
    "actuator_dynamics": "cutoff_hz",
    "sensor_dynamics": "cutoff_hz",
}


def _truth_value(effect, truth, plant):
    if effect == "modal_mismatch":
        return plant.modes[truth["index"]][0]
    k = KEY.get(effect)
    if k is None:
        return None
    v = truth[k]
    if isinstance(v, list):
        return next(x for x in v if x is not None)
    return v


def _found_value(effect, params):
    k = KEY.get(effect)
    if k is None or k not in params:
        return None
    v = params[k]
    if isinstance(v, list):
        vals = [x for x in v if x is not None]
        return min(vals) if vals else None
    return v


def run_case(plant_name, kind, effect, size, seed):
    plant = stage() if plant_name == "stage" else beam()
    params = stage_params if plant_name == "stage" else beam_params
    truth = params(effect, size)
    make = frf_case if kind == "frf" else time_case
    case = make(
        plant, effect, truth, rel=0.005 if kind == "frf" else 0.01, rng=np.random.default_rng(seed)
    )
    t0 = time.perf_counter()
    res = diagnose(case.nominal, case.data)
    dt = time.perf_counter() - t0
    top = res.top
    tv, fv = _truth_value(effect, truth, plant), _found_value(top.effect, top.parameters)
    perr = (
        f"{100 * (fv / tv - 1):+.2f} %"
        if tv is not None and fv is not None and top.effect == effect
        else "-"
    )
    ok = "ok  " if top.effect == effect else "MISS"
    if case.visibility < 1.3 and effect != "none":
        ok = "n/a "  # the generator's effect hides in the noise: no right answer to expect
    print(
        f"{ok} {plant_name:5s} {kind:4s} {effect:21s} {size:6s} vis {case.visibility:7.2f} -> "
        f"{top.effect:21s} param {perr:>9s}  err {res.error_before:.4f} -> {top.error_after:.4f} "
        f"(floor {case.noise_floor:.4f}, {top.error_after / case.noise_floor:.2f}x)  {dt:5.1f} s",
        flush=True,
    )
    return ok.strip(), dt


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="stage FRF and time, clear only")
    ap.add_argument("--seed", type=int, default=21)
    args = ap.parse_args(argv)
    runs = []
    kinds = (
        [("stage", "frf"), ("stage", "time")]
        if args.quick
        else [("stage", "frf"), ("beam", "frf"), ("stage", "time"), ("beam", "time")]
    )
    sizes = ["clear"] if args.quick else ["clear", "subtle"]
    for plant, kind in kinds:
        for effect in EFFECTS:
            if plant == "beam" and effect == "suspension_stiffness":
                continue
            for size in sizes:
                if effect == "none" and size == "subtle":
                    continue
                runs.append(run_case(plant, kind, effect, size, args.seed))
    hits = sum(r[0] == "ok" for r in runs)
    scored = sum(r[0] != "n/a" for r in runs)
    times = np.array([r[1] for r in runs])
    print(
        f"\n{hits}/{scored} top findings right ({len(runs) - scored} invisible cases not "
        f"scored); time median {np.median(times):.1f} s, max {times.max():.1f} s"
    )
    ex = Path(__file__).resolve().parents[2] / "shared" / "examples"
    if ex.is_dir():
        from workbench.io.formats import load_measurement, load_model

        for folder in sorted(p for p in ex.iterdir() if p.is_dir()):
            t0 = time.perf_counter()
            r = diagnose(
                load_model(folder / "nominal_model.npz"),
                load_measurement(folder / "measurement.npz"),
            )
            print(f"{folder.name:28s} -> {r.top.effect:14s} {time.perf_counter() - t0:5.1f} s")


if __name__ == "__main__":
    main()
