"""``workbench run SCENARIO.toml``: run a scenario, write a results folder."""

from __future__ import annotations


def register(sub):
    p = sub.add_parser(
        "run",
        help="run a scenario file (experiment, FRF, identification, modes, diagnosis ...)",
        description="Run a scenario file and write its results folder (JSON figures, PNG plots).",
    )
    p.add_argument("scenario", help="scenario file (.toml)")
    p.add_argument("--results", help="results folder (default: the scenario's [scenario] results)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


def run(args) -> int:
    from workbench.cli.pipeline import run_scenario
    from workbench.core.atomic import check_output
    from workbench.digest import run_digest
    from workbench.io.scenario import load_scenario
    from workbench.report import REPORT_NAME, write_run_report

    scenario = load_scenario(args.scenario, results=args.results)
    check_output(scenario.results, [args.scenario], folder=True, what="results folder")
    summary = run_scenario(scenario, progress=not args.quiet)
    print(run_digest(summary))
    # the page of the folder, as ``workbench report`` rebuilds it (with the scenario's copy)
    written = write_run_report(scenario.results, args.scenario, progress=not args.quiet)
    print(f"results: {scenario.results}/ ({', '.join(sorted({*summary['files'], *written}))})")
    print(f"report: {scenario.results / REPORT_NAME}")
    return 0
