"""``workbench minimality MODEL``: Lemma 1/2 controllability and observability per mode."""

from __future__ import annotations

import argparse

from workbench.cli.commands import add_modal_model_arguments
from workbench.io.formats import load_model


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "minimality",
        help="controllability/observability of every mode (Lemma 1/2, PBH, Gramians)",
        description=(
            "Bring the model to modal form and check every mode: b_k nonzero and independent "
            "among modes sharing an eigenvalue (Lemma 1), likewise c_k (Lemma 2), cross-checked "
            "by the PBH test and Gramians, each with a relative margin."
        ),
    )
    add_modal_model_arguments(p, json_help="print the report as JSON")
    p.add_argument("--tol", type=float, default=1e-8, help="a margin below this fails")
    p.add_argument("--weak", type=float, default=1e-3, help="a margin below this is reported weak")
    return p


def run(args) -> int:
    from workbench.modal.minimality import check_minimality
    from workbench.modal.model import ModalModel

    model = ModalModel.from_statespace(
        load_model(args.model), rigid_threshold_hz=args.rigid_threshold_hz
    )
    report = check_minimality(model, tol=args.tol, weak=args.weak)
    print(report.to_json() if args.json else report.text())
    return 0
