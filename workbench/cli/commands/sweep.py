"""``workbench sweep SCENARIO.toml --vary KEY=SPEC ... [--runs N] [--workers N | --scheduler A]``.

A scenario run over a grid or Monte-Carlo set of overridden keys (:mod:`workbench.sweep`):
one results table (CSV and Parquet), a summary and plots; rerunning the same command resumes.
"""

from __future__ import annotations

import argparse

EPILOG = """\
KEY: a dotted scenario key, TABLE.key[.key...] or scenario.seed, e.g.
  plant.effects.delay_s  plant.effects.mode_freq_error  design.ms_max  scenario.seed
SPEC:
  a:b:n                 n points from a to b (both included); several grids: full product
  [v1, v2, ...]         the listed values (TOML values; bare words are strings)
  uniform(lo,hi)        Monte Carlo (needs --runs N or [sweep] runs)
  loguniform(lo,hi)     log-uniform, for scale factors (0 < lo)
  normal(mu,sigma)
  choice(a,b,...)
  DIST+c, DIST-c        an offset on every draw: loguniform(0.5,2)-1 is a damping factor
                        0.5..2 stored as the relative error that mode_damping_error takes
Draws are seeded from [scenario] seed and the key (the same command, the same table); a key
the scenario gives a list (mode_freq_error = [0.0, 0.0]) is drawn per element.

Each run writes OUT/runs/<run_id>/ (run_id: a hash of the scenario and the overrides) and its
row OUT/rows/<run_id>.json as it completes; a failed run is a row with its error as status.
Rerunning the command skips every run whose row exists (an interrupted or killed sweep
resumes). At the end OUT/sweep_table.csv, sweep_table.parquet, sweep_summary.json/.txt and
sweep_shares.png, sweep_worst.png, sweep_scatter.png are rebuilt from the rows.

The scenario's [sweep] table gives defaults:
  [sweep]
  vary = ["plant.effects.delay_s=uniform(0,4e-4)"]   # used when no --vary is given
  runs = 60
  gate = "stable"                                     # worst values over the runs where true
  [sweep.collect]                                     # column = FILE:KEY of a run's JSON file
  stable = "evaluation.json:designs.*.analysis.stable"
  s_peak_max = "max(evaluation.json:designs.*.analysis.loops.*.s_peak)"

Examples:
  workbench sweep scenarios/wafer_stage_robustness.toml
  workbench sweep S.toml --vary plant.effects.delay_s=0:4e-4:5 --vary design.ms_max=[1.6,2.0]
  workbench sweep S.toml --vary plant.effects.mode_freq_error=uniform(-0.05,0.05) --runs 100
  workbench sweep S.toml --scheduler tcp://10.0.0.5:8786
"""


def register(sub):
    p = sub.add_parser(
        "sweep",
        help="run a scenario over a grid / Monte-Carlo set of keys (resumable; CSV + Parquet)",
        description=(
            "Run SCENARIO once per variation of its keys, on a local process pool (default: "
            "every core) or a Dask cluster; write one table (CSV and Parquet), a summary "
            "(share false of each boolean figure, e.g. unstable; worst value of each "
            "max()/min() figure per design) and plots. Exit 0 when every run has a row (a "
            "failed run is a row), 1 when a worker process died, 2 on bad input, 130 when "
            "interrupted (the finished rows are kept either way: rerun to resume)."
        ),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", help="scenario file (.toml)")
    p.add_argument(
        "--vary",
        action="append",
        metavar="KEY=SPEC",
        help="a key and its grid or distribution (repeatable; replaces [sweep] vary)",
    )
    p.add_argument("--runs", type=int, metavar="N", help="Monte-Carlo draws (default [sweep] runs)")
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="local worker processes (default: every core; 0 = in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask distributed cluster (e.g. tcp://host:8786) instead of the local pool",
    )
    p.add_argument("--out", metavar="DIR", help="sweep folder (default: <results>/sweep)")
    p.add_argument(
        "--redo-failed", action="store_true", help="rerun the runs whose row has an error status"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    return p


def run(args) -> int:
    import sys
    from pathlib import Path

    from workbench.core.atomic import check_output
    from workbench.io.scenario import load_scenario
    from workbench.sweep import SweepStopped, parse_vary, run_sweep

    scenario = load_scenario(args.scenario)
    varies = [parse_vary(v) for v in args.vary] if args.vary else None
    out = Path(args.out) if args.out else Path(scenario.results) / "sweep"
    check_output(out, [args.scenario], folder=True, what="sweep folder")
    try:
        result = run_sweep(
            scenario,
            varies=varies,
            runs=args.runs,
            out=out,
            workers=args.workers,
            scheduler=args.scheduler,
            redo_failed=args.redo_failed,
            progress=not args.quiet,
        )
    except SweepStopped as exc:  # a worker died: the finished rows are kept, rerun resumes
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(result.text)
    print(
        f"runs: {result.n_run} run now, {result.n_resumed} found done, {result.n_failed} failed; "
        f"{result.wall_s:.1f} s"
    )
    print(f"results: {result.out}/ ({', '.join(result.files)}, rows/, runs/)")
    return 0
