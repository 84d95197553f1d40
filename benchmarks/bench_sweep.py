"""Benchmark: the per-run overhead of ``workbench sweep`` and its scaling on 1 and 2 workers.

A cheap scenario (the wafer stage, a 200-sample closed-loop step experiment under the
experiment's PID: ~0.1-0.2 s of work a run, plant build, closed loop, the measurement and
summary files) is swept over ``scenario.seed`` (every seed another noise realization):

1. the reference: a direct loop in this process, ``run_scenario(apply_overrides(...))``
   for each variation (after one warm-up run: imports and caches are not its work);
2. :func:`workbench.sweep.run_sweep` with ``workers = 1`` and ``workers = 2`` (local
   process pool, forkserver), each for N1 and N2 runs into fresh folders.

The first pool of the process starts the forkserver, which imports the pipeline once; that
cold start is timed apart (a 2-run sweep) before the measured sweeps. The work of a run is
its ``seconds`` (measured in the worker, around the run and the
collection of its figures). The overhead of a sweep with W workers is

    overhead = W * wall - sum(work)     (worker-seconds not spent in runs)

per run: its total / N (pool start-up, IPC, the rows, the table, the summary and the plots
included) and the marginal one, the slope between N1 and N2 (what one more run costs beyond
its work). Target: <= 50 ms per run. The runs' CPU time is printed too: on a machine
shared with other jobs the wall times include waiting for a core (then work > CPU, and two
workers cannot be twice as fast).

Run: ``python benchmarks/bench_sweep.py [--n1 10] [--n2 50]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from workbench.cli.pipeline import run_scenario  # noqa: E402
from workbench.core.blas import limited_blas  # noqa: E402
from workbench.io.scenario import load_scenario  # noqa: E402
from workbench.sweep import apply_overrides, parse_vary, plan_sweep, run_sweep  # noqa: E402

TARGET_S = 0.050  # the goal: <= 50 ms per run beyond the run's own work

SCENARIO = """
[scenario]
name = "bench_sweep"
seed = 1
results = "{folder}/results"

[plant]
name = "wafer_stage"

[experiment]
kind = "step"
loop = "closed"
n_samples = 200

[sweep.collect]
y_rms_max = "max(summary.json:experiment.y_rms.*)"
"""


def reference(scenario, n: int, folder: Path) -> tuple[float, float]:
    """(wall, sum of the runs' work) of a direct in-process loop over n seeds, one BLAS thread
    (as a sweep's worker has: on 2 shared cores two BLAS threads only slow small problems)."""
    with limited_blas(1):
        return _reference(scenario, n, folder)


def _reference(scenario, n: int, folder: Path) -> tuple[float, float]:
    plan = plan_sweep(scenario, [parse_vary(f"scenario.seed=1:{n}:{n}")])
    run_scenario(
        apply_overrides(scenario, plan[0].overrides, results=folder / "warm"), progress=False
    )
    t0 = time.perf_counter()
    work = 0.0
    for v in plan:
        t = time.perf_counter()
        run_scenario(
            apply_overrides(scenario, v.overrides, results=folder / v.run_id), progress=False
        )
        work += time.perf_counter() - t
    return time.perf_counter() - t0, work


def sweep(scenario, n: int, workers: int, folder: Path) -> tuple[float, float, float]:
    """(wall, sum of the runs' work, of their CPU time) of run_sweep over n seeds."""
    varies = [parse_vary(f"scenario.seed=1:{n}:{n}")]
    t0 = time.perf_counter()
    result = run_sweep(scenario, varies=varies, out=folder, workers=workers)
    wall = time.perf_counter() - t0
    assert result.n_run == n and result.n_failed == 0, result.text
    return wall, sum(r["seconds"] for r in result.rows), sum(r["cpu_seconds"] for r in result.rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n1", type=int, default=10, help="runs of the short sweeps")
    ap.add_argument("--n2", type=int, default=50, help="runs of the long sweeps")
    args = ap.parse_args()
    n1, n2 = args.n1, args.n2
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        path = tmp / "bench.toml"
        path.write_text(SCENARIO.format(folder=tmp))
        scenario = load_scenario(path)
        # the first pool of this process starts the forkserver, which imports the pipeline
        # once (every later pool forks from it): a cold start, reported apart
        t0 = time.perf_counter()
        sweep(scenario, 2, 2, tmp / "cold")
        cold = time.perf_counter() - t0
        print(f"cold start (forkserver + its imports, a 2-run sweep on 2 workers): {cold:.2f} s")
        wall, work = reference(scenario, n2, tmp / "ref")
        ref_per_run = wall / n2
        print(f"reference: direct loop in this process, {n2} runs: {wall:.2f} s wall, "
              f"{work:.2f} s work, {ref_per_run * 1e3:.1f} ms a run, overhead "
              f"{(wall - work) / n2 * 1e3:.2f} ms a run")  # fmt: skip
        print(f"{'workers':>7} {'runs':>5} {'wall s':>7} {'work s':>7} {'cpu s':>6} "
              f"{'overhead/run ms':>16} {'wall/reference':>14} {'cores busy':>10}")  # fmt: skip
        walls: dict[int, dict[int, float]] = {}
        over: dict[int, dict[int, float]] = {}
        for workers in (1, 2):
            for n in (n1, n2):
                wall, work, cpu = sweep(scenario, n, workers, tmp / f"w{workers}_n{n}")
                walls.setdefault(workers, {})[n] = wall
                over.setdefault(workers, {})[n] = workers * wall - work
                per_run, ratio = over[workers][n] / n * 1e3, wall / (ref_per_run * n)
                print(f"{workers:7d} {n:5d} {wall:7.2f} {work:7.2f} {cpu:6.2f} {per_run:16.1f} "
                      f"{ratio:14.2f} {cpu / wall:10.2f}")  # fmt: skip
        print("marginal overhead per run (slope between the two sweep sizes, start-up excluded):")
        for workers in (1, 2):
            slope = (over[workers][n2] - over[workers][n1]) / (n2 - n1)
            start = over[workers][n1] - slope * n1
            verdict = "meets" if slope <= TARGET_S else "MISSES"
            print(f"  {workers} worker(s): {slope * 1e3:6.1f} ms a run ({verdict} the "
                  f"{TARGET_S * 1e3:.0f} ms target); fixed cost {start:.2f} worker-s "
                  "(pool start, table, summary, plots)")  # fmt: skip
        speedup = walls[1][n2] / walls[2][n2]
        print(f"scaling: {n2} runs on 2 workers {speedup:.2f}x faster than on 1 "
              "(ideal 2.00 on 2 free cores; 'cores busy' = the runs' CPU time / wall: below the "
              "worker count when other jobs hold the cores, and then work > cpu)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
