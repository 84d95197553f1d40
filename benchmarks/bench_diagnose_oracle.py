"""Benchmark ``workbench.diagnosis.diagnose`` on the independent oracle cases of
``tests/oraclegen.py`` (gantry 2x3 and dual-stage 2x2 plants, FRF and time records).

    OMP_NUM_THREADS=1 python benchmarks/bench_diagnose_oracle.py --seed 1 --kinds frf,time \
        [--pairs] [--json out.json] [--only SUBSTRING] [--selfcheck]

Per case: top finding's effect (for "none": no finding or only "none"; for a pair: both
effects among the findings), parameters within tolerance (delay 5 %, frequency 1 %,
damping 30 %, cutoff 20 %, crosstalk off-diagonals 0.01 absolute, residual compliance
matrix 25 % relative Frobenius, suspension frequency 5 %), and the final error (last
finding's error_after, else error_before) within 2x the noise floor.
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
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import oraclegen as og  # noqa: E402

from workbench.core.atomic import write_text  # noqa: E402
from workbench.core.jsonutil import jsonable  # noqa: E402

TOL = dict(
    delay=0.05,
    freq=0.01,
    damping=0.30,
    cutoff=0.20,
    xtalk_abs=0.01,
    resid_rel=0.25,
    susp_freq=0.05,
    error_ratio=2.0,
)


def _num(v):
    if isinstance(v, dict) and "value" in v:
        v = v["value"]
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def _rel(a, b):
    return abs(a - b) / abs(b)


def _pick_mode(params, f_true):
    """The (freq, damping, model_freq) entry of a finding closest to f_true; handles a
    ``modes`` list or scalar / list-valued freq_hz."""
    cands = []
    for m in params.get("modes", []) or []:
        if isinstance(m, dict) and _num(m.get("freq_hz")) is not None:
            cands.append(m)
    f = params.get("freq_hz")
    if isinstance(f, (list, tuple, np.ndarray)):
        d = params.get("damping")
        mf = params.get("model_freq_hz")
        for j, fj in enumerate(f):
            seq = (list, tuple, np.ndarray)
            cands.append(
                {
                    "freq_hz": fj,
                    "damping": d[j] if isinstance(d, seq) else d,
                    "model_freq_hz": mf[j] if isinstance(mf, seq) else mf,
                }
            )
    elif _num(f) is not None:
        cands.append(params)
    if not cands:
        return None
    return min(cands, key=lambda m: abs(_num(m["freq_hz"]) - f_true))


def _found_matrix(found_p, shape):
    """(the finding's matrix, "") or (None, why not): missing, or not of ``shape``."""
    M = found_p.get("matrix")
    if M is None:
        return None, "no matrix"
    M = np.asarray(M, float)
    if M.shape != shape:
        return None, f"matrix shape {M.shape} vs true {shape}"
    return M, ""


def check_params(effect, truth_p, found_p, band_hz):
    """-> (ok, notes list)"""
    notes = []
    ok = True

    def cmp(label, got, want, tol):
        nonlocal ok
        if got is None:
            ok = False
            notes.append(f"{label}: missing (true {want:.4g})")
            return
        r = _rel(got, want)
        good = r <= tol
        ok &= good
        notes.append(f"{label} {got:.4g} vs {want:.4g} ({100 * r:.1f}%{'' if good else ' FAIL'})")

    if effect == "time_delay":
        cmp("delay_s", _num(found_p.get("delay_s")), truth_p["delay_s"], TOL["delay"])
    elif effect in ("missing_mode", "modal_mismatch"):
        m = _pick_mode(found_p, truth_p["freq_hz"])
        if m is None:
            return False, ["no freq_hz"]
        cmp("freq", _num(m.get("freq_hz")), truth_p["freq_hz"], TOL["freq"])
        cmp("damping", _num(m.get("damping")), truth_p["damping"], TOL["damping"])
        if effect == "modal_mismatch":
            cmp("model_freq", _num(m.get("model_freq_hz")), truth_p["model_freq_hz"], TOL["freq"])
    elif effect == "suspension_stiffness":
        # a finding may list several suspended rigid modes ("modes"); score the one
        # closest to the true suspension, and note the headline freq_hz when it differs
        m = _pick_mode(found_p, truth_p["freq_hz"])
        if m is None:
            return False, ["no freq_hz"]
        cmp("freq", _num(m.get("freq_hz")), truth_p["freq_hz"], TOL["susp_freq"])
        cmp("damping", _num(m.get("damping")), truth_p["damping"], TOL["damping"])
        head = _num(found_p.get("freq_hz"))
        if head is not None and _rel(head, truth_p["freq_hz"]) > TOL["susp_freq"]:
            notes.append(f"NOTE headline freq_hz {head:.4g} (not the true suspension)")
    elif effect in ("actuator_dynamics", "sensor_dynamics"):
        want = truth_p["cutoff_hz"]
        got = found_p.get("cutoff_hz")
        if not isinstance(got, (list, tuple, np.ndarray)):
            got = [got] * len(want)
        if len(got) != len(want):
            return False, [f"cutoff_hz length {len(got)} vs {len(want)}"]
        for i, (g, w) in enumerate(zip(got, want)):
            g = _num(g)
            if w is None:  # no lag on this channel: none reported, or far above the band
                good = g is None or not np.isfinite(g) or g >= 3 * band_hz[1]
                ok &= good
                notes.append(
                    f"fc[{i}] {g if g is None else f'{g:.4g}'} vs none{'' if good else ' FAIL'}"
                )
            else:
                cmp(f"fc[{i}]", g, w, TOL["cutoff"])
    elif effect == "crosstalk":
        T = np.asarray(truth_p["matrix"], float)
        M, why = _found_matrix(found_p, T.shape)
        if M is None:
            return False, [why + f" ({truth_p['side']} side)"]
        off = ~np.eye(T.shape[0], dtype=bool)
        err = float(np.max(np.abs(M[off] - T[off])))
        ok = err <= TOL["xtalk_abs"]
        notes.append(f"offdiag max err {err:.4f} ({truth_p['side']} side){'' if ok else ' FAIL'}")
    elif effect == "residual_compliance":
        R = np.asarray(truth_p["matrix"], float)
        M, why = _found_matrix(found_p, R.shape)
        if M is None:
            return False, [why]
        r = float(np.linalg.norm(M - R) / np.linalg.norm(R))
        ok = r <= TOL["resid_rel"]
        notes.append(f"matrix rel err {100 * r:.1f}%{'' if ok else ' FAIL'}")
    return bool(ok), notes


def run_case(case):
    from workbench.diagnosis import diagnose

    t0 = time.process_time()
    try:
        res = diagnose(case.nominal, case.data)
        err = None
    except Exception as exc:  # a crash is a failure of the case, not of the run
        res, err = None, f"{type(exc).__name__}: {exc}"
    cpu = time.process_time() - t0
    a = case.answer
    floor = a["noise_floor_error"]
    rec = dict(
        name=case.name,
        plant=case.plant,
        kind=case.kind,
        effects=list(case.effects),
        truth=jsonable(a["effects"]),
        noise_floor=floor,
        visibility=a["visibility"],
        nominal_error_oracle=a["nominal_error"],
        band_hz=a["band_hz"],
        cpu_s=cpu,
    )
    if res is None:
        rec.update(
            error=err,
            passed=False,
            top=None,
            findings=[],
            effect_ok=False,
            params_ok=False,
            ratio=None,
            notes=[err],
        )
        return rec
    fnd = list(res.findings)
    effs = [f.effect for f in fnd]
    rec["findings"] = [
        dict(
            effect=f.effect,
            parameters=jsonable({k: v for k, v in f.parameters.items() if k not in ("b", "c")}),
            error_after=f.error_after,
        )
        for f in fnd
    ]
    rec["error_before"] = res.error_before
    final = fnd[-1].error_after if fnd else res.error_before
    rec["final_error"] = final
    rec["ratio"] = final / floor
    real = [e for e in effs if e != "none"]
    rec["top"] = real[0] if real else "none"
    truth_effs = list(case.effects)
    if truth_effs == ["none"]:
        effect_ok = not real
    elif len(truth_effs) == 1:
        effect_ok = bool(fnd) and fnd[0].effect == truth_effs[0]
    else:
        effect_ok = bool(fnd) and fnd[0].effect in truth_effs and all(e in effs for e in truth_effs)
    params_ok = True
    notes = []
    for te in a["effects"]:
        if te["effect"] == "none":
            continue
        f = next((f for f in fnd if f.effect == te["effect"]), None)
        if f is None:
            params_ok = False
            notes.append(f"{te['effect']}: not found")
            continue
        ok, nn = check_params(te["effect"], te["parameters"], f.parameters, a["band_hz"])
        params_ok &= ok
        notes.append(f"{te['effect']}: " + "; ".join(nn))
    ratio_ok = rec["ratio"] <= TOL["error_ratio"]
    rec.update(
        effect_ok=bool(effect_ok),
        params_ok=bool(params_ok),
        ratio_ok=bool(ratio_ok),
        notes=notes,
        passed=bool(effect_ok and params_ok and ratio_ok),
        error_before_vs_oracle=res.error_before / a["nominal_error"],
    )
    return rec


def _fmt(rec):
    fs = ",".join(f["effect"] for f in rec["findings"]) or "-"
    ratio = "nan" if rec.get("ratio") is None else f"{rec['ratio']:.2f}"
    return (
        f"{rec['name']:48s} vis={rec['visibility']:7.1f} findings=[{fs}] ratio={ratio} "
        f"effect={'ok' if rec['effect_ok'] else 'WRONG'} "
        f"params={'ok' if rec['params_ok'] else 'OFF'} "
        f"{'PASS' if rec['passed'] else 'FAIL'} cpu={rec['cpu_s']:.1f}s | "
        + " | ".join(rec["notes"])
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--kinds", default="frf,time")
    ap.add_argument("--pairs", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--only", default=None, help="run only cases whose name contains this")
    ap.add_argument("--selfcheck", action="store_true", help="print the generator self checks")
    args = ap.parse_args(argv)
    kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    cases = og.make_suite(args.seed, kinds=kinds, pairs=args.pairs)
    if args.only:
        cases = [c for c in cases if args.only in c.name]
    from workbench.report import package_versions

    head = package_versions()["workbench"]  # its version, and the checkout's git commit
    print(
        f"# oracle benchmark seed={args.seed} kinds={kinds} pairs={args.pairs} "
        f"cases={len(cases)} workbench {head}",
        flush=True,
    )
    recs = []
    for c in cases:
        if args.selfcheck:
            print(f"#   selfcheck {c.name}: {og.self_check(c)}", flush=True)
        rec = run_case(c)
        recs.append(rec)
        print(_fmt(rec), flush=True)

    # confusion table: truth (effect or pair) vs top finding
    conf = defaultdict(Counter)
    for r in recs:
        conf["+".join(r["effects"])][r["top"] or "crash"] += 1
    cols = sorted({k for c in conf.values() for k in c})
    print("\n# confusion (rows: truth, columns: top finding)")
    w = max(len(k) for k in conf) + 2
    print(" " * w + " ".join(f"{c[:12]:>12s}" for c in cols))
    for k in sorted(conf):
        print(f"{k:{w}s}" + " ".join(f"{conf[k].get(c, 0):12d}" for c in cols))
    print("\n# pass counts")
    for kind in kinds:
        rr = [r for r in recs if r["kind"] == kind]
        n_eff = sum(r["effect_ok"] for r in rr)
        n_par = sum(r["params_ok"] for r in rr)
        n_err = sum(bool(r.get("ratio_ok")) for r in rr)
        print(
            f"{kind:5s}: {sum(r['passed'] for r in rr)}/{len(rr)} "
            f"(effect {n_eff}, params {n_par}, error<=2x floor {n_err})"
        )
    print(f"total: {sum(r['passed'] for r in recs)}/{len(recs)}")
    cpu = np.array([r["cpu_s"] for r in recs])
    if cpu.size:
        print(
            f"cpu per case: median {np.median(cpu):.1f}s max {cpu.max():.1f}s "
            f"total {cpu.sum():.1f}s"
        )
    fails = [r for r in recs if not r["passed"]]
    if fails:
        print("\n# failing cases")
        for r in fails:
            print(_fmt(r))
    if args.json:
        record = dict(seed=args.seed, kinds=kinds, pairs=args.pairs, tolerances=TOL, cases=recs)
        write_text(args.json, json.dumps(jsonable(record), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
