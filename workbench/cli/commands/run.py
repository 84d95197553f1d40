"""``workbench run SCENARIO.toml``: run a scenario, write a results folder."""

from __future__ import annotations

import json


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
    from workbench.io.scenario import load_scenario

    scenario = load_scenario(args.scenario, results=args.results)
    summary = run_scenario(scenario, progress=not args.quiet)
    print(_digest(summary))
    print(f"results: {scenario.results}/ ({', '.join(summary['files'])})")
    return 0


def _digest(summary: dict) -> str:
    """The few numbers a person wants first; everything is in summary.json."""
    lines = [f"scenario {summary['scenario']['name']} (seed {summary['scenario']['seed']})"]
    if "modes" in summary and "text" in summary["modes"]:
        lines.append(summary["modes"]["text"])
    if "evaluate" in summary:  # the designs on the true plant: the table the scenario exists for
        lines.append(summary["evaluate"]["text"])
    for key in ("identify", "minimality", "compare", "diagnose", "augment"):
        if key in summary:
            short = {k: v for k, v in summary[key].items() if k not in ("singular_values", "text")}
            lines.append(f"{key}: {json.dumps(short, default=str)[:400]}")
    return "\n".join(lines)
