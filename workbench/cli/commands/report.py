"""``workbench report RESULTS_DIR [--out FILE]``: the results folder as one HTML page.

Rebuilds the page ``workbench run`` writes at its end (``report.html``) from the
folder alone: figures embedded, tables, the scenario file, package versions,
seed and stage timings (:mod:`workbench.report`).
"""

from __future__ import annotations

import argparse


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "report",
        help="rebuild the self-contained HTML report of a results folder",
        description=(
            "Write one self-contained HTML page for a results folder of workbench run: its "
            "PNG figures embedded, its JSON figures and text tables, the scenario file, the "
            "package versions, seed and stage timings. Default: RESULTS_DIR/report.html."
        ),
    )
    p.add_argument("results", metavar="RESULTS_DIR", help="a results folder of workbench run")
    p.add_argument("--out", metavar="FILE", help="the page (default: RESULTS_DIR/report.html)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


def run(args) -> int:
    from workbench.report import write_report

    done = write_report(args.results, args.out, progress=not args.quiet)
    print(f"wrote {done['path']} ({done['figures']} figures, {done['tables']} tables)")
    return 0
