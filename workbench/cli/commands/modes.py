"""``workbench modes MODEL``: the modal table of a model (seed 000, Table 1).

Any model file (discrete models are converted with the ZOH inverse) is
brought to the modal canonical form; the table lists every mode (rigid,
flexible, real pole) with frequency, damping, input and output participation.
``--plot`` and ``--superposition`` save Bode plots (PNG).
"""

from __future__ import annotations

import argparse

from workbench.cli.commands import add_modal_model_arguments
from workbench.core.atomic import check_not_input
from workbench.io.formats import load_model


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "modes",
        help="modal table of a model (rigid and flexible modes, damping, participation)",
        description=(
            "Modal analysis by similarity: rigid-body modes (poles below the threshold, projected "
            "onto double integrators), flexible modes (Hz, damping ratio), real poles; input and "
            "output participation |b_k|, |c_k|."
        ),
    )
    add_modal_model_arguments(p, json_help="print the table as JSON")
    p.add_argument("--plot", metavar="PNG", help="save |G| of every input-output pair")
    p.add_argument("--superposition", metavar="PNG", help="save one pair as the sum of its modes")
    p.add_argument("--output", type=int, default=0, help="output index for --superposition")
    p.add_argument("--input", type=int, default=0, help="input index for --superposition")
    return p


def run(args) -> int:
    from workbench.modal.model import ModalModel, plot_mode_superposition, plot_model_bode

    for out in (args.plot, args.superposition):
        if out:
            check_not_input(out, [args.model])
    sys = load_model(args.model)
    model = ModalModel.from_statespace(sys, rigid_threshold_hz=args.rigid_threshold_hz)
    if args.plot:
        plot_model_bode(model, args.plot)
    if args.superposition:
        plot_mode_superposition(model, args.superposition, output=args.output, input=args.input)
    print(model.to_json() if args.json else model.table_text())
    return 0
