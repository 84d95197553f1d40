"""The whole diagnosis suite: every effect of the vocabulary on both plants, FRF
and time data, clear and subtle sizes, two-effect and clean cases.

Prints one line per case (visibility, top finding, parameter errors,
error_after / noise floor, seconds) and the confusion table.

    python benchmarks/bench_diagnosis_suite.py [--quick] [--seeds 1 2 3] [--kinds frf time]
        [--plants wafer_stage beam] [--domain auto|time|frequency] [--jobs 2]
        [--skip wafer_stage:time:nonlinearity]

``--domain`` is :func:`workbench.diagnosis.diagnose`'s: where a time record is fitted.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from tqdm import tqdm  # noqa: E402

import casegen  # noqa: E402
from workbench.diagnosis import diagnose  # noqa: E402


@dataclass(frozen=True)
class CaseRow:
    """What the report needs of a case (a Case holds a StateSpace, which does not pickle)."""

    case_id: str
    effects: tuple[str, ...]
    visibility: float


def one_case(spec, seed: int, domain: str = "auto"):
    """Make, diagnose and score one case: (CaseRow, score, (wall, CPU) seconds in diagnose).

    The CPU time (this process) is the figure to compare on a shared machine: the
    wall time moves with the other processes' load.
    """
    case = casegen.make_case(*spec, seed=seed)
    t0, c0 = time.perf_counter(), time.process_time()
    result = diagnose(case.model, case.data, domain=domain).to_json()
    dt = (time.perf_counter() - t0, time.process_time() - c0)
    row = CaseRow(case.case_id, tuple(case.effects), float(case.visibility))
    return row, casegen.score(case, result), dt


def run(specs, seeds, *, verbose=True, domain="auto", jobs: int = 1):
    """Every (spec, seed) case; ``jobs`` worker processes (each with one BLAS thread)."""
    todo = [(spec, seed) for seed in seeds for spec in specs]
    rows, scores = [], []
    # progress on stderr, silent when stderr is not a terminal (disable=None)
    bar = tqdm(total=len(todo), unit="case", disable=None, file=sys.stderr)
    if jobs > 1:
        pool = ProcessPoolExecutor(jobs)
        futures = [pool.submit(one_case, spec, seed, domain) for spec, seed in todo]
        results = (f.result() for f in futures)  # in the suite's order
    else:
        pool = None
        results = (one_case(spec, seed, domain) for spec, seed in todo)
    for case, s, dt in results:
        bar.update()
        scores.append((case, s, dt))
        rows.append(("+".join(case.effects), s["top"]))
        if verbose:
            perr = " ".join(f"{k}={v:.3f}" for k, v in s["param_errors"].items())
            print(
                f"{case.case_id:58s} vis={case.visibility:7.1f} top={s['top']!s:22s} "
                f"named={s['named']!s:5} params={s['params_ok']!s:5} "
                f"after/floor={s['error_after_ratio']:.2f} {dt[0]:5.1f}s cpu {dt[1]:5.2f}s {perr}",
                flush=True,
            )
    if pool is not None:
        pool.shutdown()
    bar.close()
    return rows, scores


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="the CI subset only")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--kinds", nargs="+", default=["frf", "time"], choices=["frf", "time"])
    ap.add_argument("--plants", nargs="+", default=["wafer_stage", "beam"])
    ap.add_argument("--domain", default="auto", choices=["auto", "time", "frequency"])
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (the machine's cores)")
    ap.add_argument(
        "--skip",
        nargs="+",
        default=[],
        metavar="PLANT:KIND:EFFECT",
        help="leave out that plant, kind and effect (wafer_stage:time:nonlinearity)",
    )
    args = ap.parse_args()
    skip = {tuple(s.split(":")) for s in args.skip}
    specs = [
        s
        for s in casegen.suite(full=not args.quick)
        if s[0] in args.plants
        and s[1] in args.kinds
        and not any((s[0], s[1], effect) in skip for effect, _ in s[2])
    ]
    t0 = time.perf_counter()
    rows, scores = run(specs, args.seeds, domain=args.domain, jobs=args.jobs)
    wall = time.perf_counter() - t0
    n = len(scores)
    named = sum(s["named"] for _, s, _ in scores)
    params = sum(s["params_ok"] for _, s, _ in scores)
    floor_ok = sum(
        s["error_after_ratio"] <= 2.0 for c, s, _ in scores if c.effects != ("nonlinearity",)
    )
    n_lin = sum(1 for c, _, _ in scores if c.effects != ("nonlinearity",))
    print()
    print(casegen.confusion_table(rows))
    print()
    print(f"right effect named: {named}/{n} = {named / n:.0%}")
    print(f"key parameters within tolerance: {params}/{n} = {params / n:.0%}")
    print(f"error_after within 2x noise floor (linear cases): {floor_ok}/{n_lin}")
    times = sorted(d[0] for *_, d in scores)
    cpu = sorted(d[1] for *_, d in scores)
    print(f"diagnose time: median {times[n // 2]:.2f} s, max {times[-1]:.2f} s (wall)")
    print(f"diagnose CPU time: median {cpu[n // 2]:.2f} s, max {cpu[-1]:.2f} s (this process)")
    print(f"wall time: {wall:.0f} s for {n} cases with {args.jobs} worker(s)")


if __name__ == "__main__":
    main()
