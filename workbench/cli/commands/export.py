"""``workbench export DATA_OR_MODEL.npz --out FILE.uff|FILE.mat``: spec files for other tools.

Measurements (FRFs, time records) go to a universal file (dataset 164 + binary
58b records, exact) or a v5 .mat; models (A, B, C, D, dt, names) to .mat. What
the target cannot hold (an FRF's ``G_var`` in a UFF) is printed as ``note:``
lines (:mod:`workbench.io.importers`).
"""

from __future__ import annotations

import argparse

from workbench.core.atomic import check_not_input


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "export",
        help="export a measurement or model .npz to UFF58 (.uff) or MATLAB (.mat)",
        description=(
            "Write a spec measurement (FRF or time record) as a universal file (dataset 58, "
            "binary double precision) or a MATLAB .mat, or a spec model (A, B, C, D, dt) as "
            ".mat. The format comes from the output's suffix: .uff/.unv or .mat."
        ),
    )
    p.add_argument("file", metavar="DATA_OR_MODEL", help="measurement or model .npz")
    p.add_argument("--out", required=True, metavar="FILE", help="output .uff/.unv or .mat")
    return p


def run(args) -> int:
    from workbench.io.importers import export_file, export_format

    export_format(args.out)  # a bad suffix is refused before any reading
    check_not_input(args.out, [args.file])
    notes = export_file(args.file, args.out)
    print(f"wrote {args.out} (from {args.file})")
    for note in notes:
        print(f"note: {note}")
    return 0
