"""Diagnose on the third independent generator (tests/indepgen3.py): confusion table.

Run: ``python benchmarks/bench_diagnose_indep3.py [--seed S] [--kinds frf,time]
[--plants shaft,planar,beam] [--effects a,b] [--n-frf 2] [--start any|rest|moving]
[--save DIR] [--json OUT]``.

Per case: truth, top finding, key parameter check, error_after / noise floor,
the effect's visibility (its share of the response over the noise floor) and
the wall time. Then the confusion table (truth x top finding) and the score:
a case passes when the top finding names the effect, its key parameter is
within tolerance, and the error after every finding is within 2x the noise
floor (the spec error of the TRUE system against its own noisy measurement).
Cases whose effect stays below 2x the noise floor ("invisible") are counted
apart.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from indepgen3 import EFFECTS, PLANTS, make_case, make_suite, save_case  # noqa: E402

#: tolerances of the task: delay 10 %, frequencies 1 %, cutoffs 20 %, suspension 10 %;
#: residual compliance: the static matrix of the truncated modes within 30 % (Frobenius),
#: less those a missing-mode finding names where they ring (a sampled record folds a mode
#: above Nyquist into the band); such a mode named as the top finding is right too
TOL = {
    "time_delay": 0.10,
    "missing_mode": 0.01,
    "modal_mismatch": 0.01,
    "actuator_dynamics": 0.20,
    "sensor_dynamics": 0.20,
    "suspension_stiffness": 0.10,
    "residual_compliance": 0.30,
}
ERROR_FACTOR = 2.0
LAG = {"actuator_dynamics", "sensor_dynamics"}
INVISIBLE = 2.0


def _as_list(v):
    if v is None:
        return []
    if isinstance(v, list | tuple | np.ndarray):
        return [x for x in np.asarray(v, dtype=object).ravel().tolist() if x is not None]
    return [v]


def _nearest_rel(found, truth) -> float:
    """Largest over found values of the relative distance to the nearest true value."""
    f, t = [float(x) for x in _as_list(found)], [float(x) for x in _as_list(truth)]
    if not f or not t:
        return float("inf")
    return max(min(abs(a / b - 1) for b in t) for a in f)


def _folded_hz(f: float, z: float, fs: float | None) -> float:
    """Where a mode (Hz, damping) rings in a record sampled at ``fs`` (None: an FRF, where
    it is ``f``): its damped frequency folded into 0 .. fs/2 (every mode at k fs +- f_d
    has the same sampled poles)."""
    if not fs:
        return float(f)
    fd = f * np.sqrt(max(1.0 - z * z, 0.0))
    return float(abs(fd - fs * np.round(fd / fs)))


def _truncated_distance(truth: dict, found: dict, fs: float | None) -> list[float]:
    """Per truncated mode of a residual-compliance truth, the relative distance from where
    it rings to where the ``found`` missing-mode finding (or its reported image) does."""
    f, z = found.get("freq_hz"), found.get("damping")
    if f is None or z is None:
        return [float("inf")] * len(truth.get("modes", []))
    got = [_folded_hz(f, z, fs)]
    if found.get("image_freq_hz") is not None:
        got.append(_folded_hz(found["image_freq_hz"], found.get("image_damping", 0.0), fs))
    rings = [_folded_hz(m["freq_hz"], m["damping"], fs) for m in truth.get("modes", [])]
    return [min(abs(g / r - 1) for g in got) if r > 0 else float("inf") for r in rings]


def _named_truncated(truth: dict, found: dict, fs: float | None) -> list[int]:
    """The truncated modes the ``found`` missing mode names (within the 1 % tolerance)."""
    dist = _truncated_distance(truth, found, fs)
    return [i for i, d in enumerate(dist) if d <= TOL["missing_mode"]]


def param_error(
    effect: str, truth: dict, found: dict, others=(), fs: float | None = None
) -> float | None:
    """Relative error of the effect's key parameter; None when there is none to check.

    Residual compliance: the truncated modes that another finding (``others``: parameter
    dicts of missing modes) names where they ring on the record (``fs`` Hz; None for an
    FRF) are that finding's; the matrix is compared with the static part of the rest.
    """
    if effect == "time_delay":
        return abs(found.get("delay_s", np.inf) / truth["delay_s"] - 1)
    if effect == "missing_mode" and "freq_hz" not in truth:  # a truncated mode, named
        return min(_truncated_distance(truth, found, fs), default=float("inf"))
    if effect == "missing_mode":
        return _nearest_rel(found.get("freq_hz"), truth["freq_hz"])
    if effect == "modal_mismatch":
        scale = (found.get("pattern") or {}).get("freq_scale")
        if scale is not None:
            return abs(scale / truth["pattern"]["freq_scale"] - 1)
        modes = found.get("modes") or [found]
        return _nearest_rel([m.get("freq_hz") for m in modes], truth["freq_hz"])
    if effect in LAG:
        f, t = found.get("cutoff_hz"), truth["cutoff_hz"]
        if found.get("common"):  # one factor on the response: every true cutoff against it
            f = [(_as_list(f) or [None])[0]] * len(t)
        elif not isinstance(f, list):
            f = [f] * len(t)
        pairs = [(a, b) for a, b in zip(f, t) if a is not None]
        if len(pairs) < len(t):
            return float("inf")
        return max(abs(float(a) / b - 1) for a, b in pairs)
    if effect == "suspension_stiffness":
        modes = found.get("modes") or [found]
        return _nearest_rel([m.get("freq_hz") for m in modes], truth["freq_hz"])
    if effect == "residual_compliance":
        if "matrix" not in found:
            return float("inf")
        R, Rt = np.asarray(found["matrix"], float), np.asarray(truth["matrix"], float)
        named = {i for o in others for i in _named_truncated(truth, o, fs)}
        if named and len(named) < len(truth["modes"]):
            rest = [m for i, m in enumerate(truth["modes"]) if i not in named]
            Rt = np.sum([np.asarray(m["matrix"], float) for m in rest], axis=0)
        if R.shape != Rt.shape:
            return float("inf")
        return float(np.linalg.norm(R - Rt) / np.linalg.norm(Rt))
    return None


def to_measurement(case):
    """The case's spec dict as the workbench's FrfData / TimeData."""
    from workbench.io.formats import FrfData, TimeData

    d = dict(case.data)
    names = {
        "input_names": tuple(d.pop("input_names")),
        "output_names": tuple(d.pop("output_names")),
    }
    kind = d.pop("kind")
    if kind == "frf":
        return FrfData(freq=d["freq"], G=d["G"], G_var=d["G_var"], **names)
    return TimeData(
        fs=d["fs"], u=d["u"], y=d["y"], r=d["r"], loop=d["loop"], period=d.get("period"), **names
    )


def score(case, res) -> dict:
    """The checks of one case against its answer."""
    a = case.answer
    top = res.top
    others = [f.parameters for f in res.findings if f.effect == "missing_mode"]
    fs = a["fs"] if a["kind"] == "time" else None
    right = (
        top.effect == a["effect"]
        or (
            # a common lag is one scalar factor on the response (l G = G l): the same lag on
            # every channel of the other side
            {top.effect, a["effect"]} <= LAG and bool(top.parameters.get("common"))
        )
        or (
            # a truncated mode that rings in the sampled record, named as a missing mode
            a["effect"] == "residual_compliance"
            and top.effect == "missing_mode"
            and bool(_named_truncated(a["parameters"], top.parameters, fs))
        )
    )
    perr = param_error(top.effect, a["parameters"], top.parameters, others, fs) if right else None
    p_ok = right and (perr is None or perr <= TOL[top.effect])
    err_final = min([res.error_before] + [f.error_after for f in res.findings])
    ratio = err_final / a["noise_floor_error"]
    visible = a["effect"] == "none" or a["visibility"] >= INVISIBLE
    return {
        "case": case.name,
        "plant": a["plant"],
        "kind": a["kind"],
        "truth": a["effect"],
        "top": top.effect,
        "findings": [f.effect for f in res.findings],
        "right": right,
        "param_err": perr,
        "param_ok": bool(p_ok),
        "error_before": res.error_before,
        "error_after": err_final,
        "floor": a["noise_floor_error"],
        "ratio": ratio,
        "error_ok": bool(ratio <= ERROR_FACTOR),
        "pass": bool(right and p_ok and ratio <= ERROR_FACTOR),
        "visibility": a["visibility"],
        "visible": bool(visible),
        "at_rest": a.get("at_rest"),
        "periodic": a.get("periodic"),
    }


def confusion(rows) -> str:
    truths = [e for e in EFFECTS if any(r["truth"] == e for r in rows)]
    tops = sorted({r["top"] for r in rows}, key=lambda e: (e not in EFFECTS, e))
    short = {e: e.replace("_", "")[:8] for e in tops}
    head = f"{'truth / top':22s}" + "".join(f"{short[e]:>9s}" for e in tops) + "   right  pass"
    lines = [head]
    for t in truths:
        sub = [r for r in rows if r["truth"] == t]
        c = Counter(r["top"] for r in sub)
        lines.append(
            f"{t:22s}"
            + "".join(f"{c.get(e, 0) or '.':>9}" for e in tops)
            + f"   {sum(r['right'] for r in sub):2d}/{len(sub):<2d}"
            + f" {sum(r['pass'] for r in sub):2d}/{len(sub)}"
        )
    return "\n".join(lines)


def summary(rows) -> str:
    vis = [r for r in rows if r["visible"]]
    out = []
    for label, sub in (("all", rows), ("visible", vis)):
        if not sub:
            continue
        n = len(sub)
        out.append(
            f"{label:8s} {n:3d} cases: right effect {sum(r['right'] for r in sub) / n:6.1%}, "
            f"+ parameters {sum(r['param_ok'] for r in sub) / n:6.1%}, "
            f"error_after <= {ERROR_FACTOR:g}x floor {sum(r['error_ok'] for r in sub) / n:6.1%}, "
            f"all three {sum(r['pass'] for r in sub) / n:6.1%}"
        )
    by = defaultdict(list)
    for r in vis:
        by[(r["kind"], r["plant"])].append(r)
    for (kind, plant), sub in sorted(by.items()):
        out.append(
            f"  {kind:4s} {plant:7s} {len(sub):3d}: right {sum(r['right'] for r in sub):3d}, "
            f"pass {sum(r['pass'] for r in sub):3d}"
        )
    return "\n".join(out)


def _time_nonlinear_fits():
    """Count the CPU seconds diagnose spends in its port-element fits
    (``_nonlinearity_finding``); returns ``take()``: the seconds since the last take."""
    import importlib

    mod = importlib.import_module("workbench.diagnosis.diagnose")
    inner = mod._nonlinearity_finding
    acc = [0.0]

    def timed(*args, **kwargs):
        c0 = time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            acc[0] += time.process_time() - c0

    def take() -> float:
        v, acc[0] = acc[0], 0.0
        return v

    mod._nonlinearity_finding = timed
    return take


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default="frf,time")
    ap.add_argument("--plants", default=",".join(PLANTS))
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--n-frf", type=int, default=2, help="FRF cases per plant x effect")
    ap.add_argument("--save", metavar="DIR", help="write every case (model, measurement, answer)")
    ap.add_argument("--json", metavar="OUT", help="write the per-case rows as JSON")
    ap.add_argument(
        "--start",
        choices=("any", "rest", "moving"),
        default="any",
        help="time records: only those starting at rest, or only those starting mid-motion",
    )
    ap.add_argument(
        "--domain",
        choices=("auto", "time", "frequency"),
        default="auto",
        help="time records: the problem diagnose fits (make_problem's domain)",
    )
    args = ap.parse_args(argv)
    from workbench.diagnosis import diagnose

    take_nonlinear_cpu = _time_nonlinear_fits()

    kinds = tuple(args.kinds.split(","))
    suite = make_suite(
        args.seed,
        kinds=kinds,
        plants=tuple(args.plants.split(",")),
        effects=tuple(args.effects.split(",")),
        n_frf=args.n_frf,
    )
    rows = []
    t_all = time.perf_counter()
    for k, (plant, effect, kind, rng) in enumerate(suite):
        case = make_case(effect, plant, kind, rng)
        if kind == "time" and args.start != "any":
            if case.answer["at_rest"] != (args.start == "rest"):
                continue
        if args.save:
            save_case(case, Path(args.save) / f"{k:03d}-{case.name}")
        data = to_measurement(case)
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            res = diagnose(case.nominal, data, domain=args.domain)
        except Exception as exc:  # a crash is a failed case, reported, not the end of the run
            take_nonlinear_cpu()
            print(f"{k:3d} {case.name:38s} CRASH {type(exc).__name__}: {exc}", flush=True)
            rows.append(
                {
                    "case": case.name,
                    "plant": plant,
                    "kind": kind,
                    "truth": effect,
                    "top": "crash",
                    "findings": [],
                    "right": False,
                    "param_err": None,
                    "param_ok": False,
                    "ratio": float("inf"),
                    "error_ok": False,
                    "pass": False,
                    "visibility": case.answer["visibility"],
                    "visible": True,
                    "seconds": 0.0,
                }
            )
            continue
        dt = time.perf_counter() - t0
        r = score(case, res)
        r["seconds"] = dt
        # CPU of this process (the machine is shared: wall time depends on the neighbours)
        r["cpu_seconds"] = time.process_time() - c0
        r["cpu_nonlinear"] = take_nonlinear_cpu()  # of it, the port elements' fits
        r["parameters"] = {k2: v for k2, v in res.top.parameters.items() if k2 not in ("matrix",)}
        rows.append(r)
        pe = "-" if r["param_err"] is None else f"{r['param_err']:.3g}"
        print(
            f"{k:3d} {case.name:38s} top {r['top']:20s} {'ok ' if r['right'] else 'BAD'} "
            f"perr {pe:>8s} err/floor {r['ratio']:8.3g} vis {r['visibility']:8.3g} "
            f"{'PASS' if r['pass'] else 'fail'} {dt:6.2f} s ({r['cpu_seconds']:6.2f} s CPU, "
            f"{r['cpu_nonlinear']:6.2f} nonlinear)  "
            f"{'+'.join(r['findings'][1:])}",
            flush=True,
        )
    print()
    print(confusion(rows))
    print()
    print(summary(rows))
    secs = [r["seconds"] for r in rows]
    for kind in kinds:
        s = [r["seconds"] for r in rows if r["kind"] == kind]
        c = [r["cpu_seconds"] for r in rows if r["kind"] == kind and "cpu_seconds" in r]
        if s:
            print(f"diagnose time {kind}: median {np.median(s):.2f} s, max {np.max(s):.2f} s")
        if c:
            print(f"diagnose CPU {kind}: median {np.median(c):.2f} s, max {np.max(c):.2f} s")
            lin = [
                r["cpu_seconds"] - r["cpu_nonlinear"]
                for r in rows
                if r["kind"] == kind and "cpu_seconds" in r
            ]
            print(
                f"  without the port-element fits: median {np.median(lin):.2f} s, "
                f"max {np.max(lin):.2f} s"
            )
    print(
        f"total {time.perf_counter() - t_all:.0f} s for {len(rows)} cases "
        f"({sum(secs):.0f} s in diagnose)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
