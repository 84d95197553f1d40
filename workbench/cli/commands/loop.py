"""``workbench loop --plant {wafer_stage,beam,MODEL.npz,FRF.npz} --controller K.npz``.

The frequency-domain figures of the loop (:func:`workbench.loop.analyze_loop`):
per-loop crossover, -3 dB bandwidth, |S|inf, gain / phase / disk margins,
closed-loop stability; ``--json`` the summary, ``--plots`` Bode / Nyquist /
S and T (:func:`workbench.loop.save_loop_plots`).

The plant is a true plant of ``plants/`` (its linear model with its own input
delay, which already holds the real-time system's delay: the loop delay then
defaults to 0), a model file (with its ``delay_s``) or a measured FRF file
(spec 1b). For a file the loop delay defaults to the controller file's
``delay_samples`` (the delay its design assumed); ``--loop-delay-samples N``
overrides either default.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from workbench.cli.commands import add_report_outputs
from workbench.cli.commands.design import add_loop_delay_argument, check_outputs
from workbench.core.atomic import check_output, write_text
from workbench.core.errors import InputError

TRUE_PLANTS = ("wafer_stage", "beam")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "loop",
        help="loop analysis of a plant with a controller file (margins, |S|, crossover)",
        description=(
            "Analyse the feedback loop of a plant (a true plant: "
            + ", ".join(TRUE_PLANTS)
            + "; a model file; or a measured FRF file) with a spec-5 controller file: per-loop "
            "crossover, bandwidth, |S|inf, gain / phase / disk margins and stability."
        ),
    )
    p.add_argument(
        "--plant",
        required=True,
        metavar="PLANT",
        help=f"one of {', '.join(TRUE_PLANTS)}, a model .npz or a measured FRF .npz",
    )
    p.add_argument("--controller", required=True, metavar="K.npz", help="controller (spec 5)")
    add_loop_delay_argument(p)
    add_report_outputs(p, json_help="write the loop figures as JSON to OUT")
    return p


def _plant(spec: str):
    """(plant for analyze_loop, True when it is a true plant of plants/)."""
    if spec in TRUE_PLANTS:
        import plants
        from workbench.core.model import LTIModel

        true = plants.get_plant(spec)
        model = LTIModel.from_statespace(true.linear_model(), delay_s=float(true.delay_s))
        return model, True
    if not Path(spec).is_file():
        raise InputError(
            f"--plant: expected one of {', '.join(TRUE_PLANTS)} or an existing .npz file, "
            f"got {spec!r}"
        )
    from workbench.io.formats import TimeData, load_any

    obj = load_any(spec)
    if isinstance(obj, TimeData):
        raise InputError(f"{spec}: expected a model or a measured FRF (kind 'frf'), got time data")
    from workbench.io.formats import FrfData
    from workbench.signals.quality import check_measurement, check_model

    if isinstance(obj, FrfData):  # the same data-quality warnings as every command that reads one
        check_measurement(obj, src=spec)
    else:
        check_model(obj, src=spec)
    return obj, False


def run(args) -> int:
    from controllers.protocol import StateSpaceController
    from workbench.loop import analyze_loop, save_loop_plots

    check_outputs((args.json,), [args.plant, args.controller])
    if args.plots:
        check_output(args.plots, [args.plant, args.controller], folder=True, what="--plots")
    K = StateSpaceController.read(args.controller)
    plant, true = _plant(args.plant)
    if plant.n_u != K.n_u or plant.n_y != K.n_y:
        raise InputError(
            f"{args.controller}: expected a controller with {plant.n_y} inputs (errors) and "
            f"{plant.n_u} outputs to match the plant {args.plant}, got {K.n_y} inputs and "
            f"{K.n_u} outputs"
        )
    if args.loop_delay_samples is not None:
        m = int(args.loop_delay_samples)
        if m < 0:
            raise InputError(f"--loop-delay-samples: expected an integer >= 0, got {m}")
    else:
        m = 0 if true else K.delay_samples
    analysis = analyze_loop(plant, K, loop_delay_samples=m)
    print(
        f"loop {args.plant} with {args.controller}: fs = {K.fs:g} Hz, loop delay {m} samples"
        + (f" + plant delay {plant.delay_s:g} s" if getattr(plant, "delay_s", 0) else "")
    )
    print(analysis.table())
    if args.json:
        write_text(args.json, analysis.to_json() + "\n")
    if args.plots:
        for path in save_loop_plots(analysis, args.plots):
            print(f"plot: {path}")
    return 0
