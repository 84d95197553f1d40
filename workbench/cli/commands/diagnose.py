"""``workbench diagnose --model MODEL --data DATA [--json OUT] [--plots DIR]``.

Tells which physical effect the model misses to explain the measurement,
fits it and shows the error fall; findings JSON as the exchange spec,
section 3 (with parameters_std, noise_floor and alternatives beside).
"""

from __future__ import annotations

import argparse
import json

from workbench.cli.commands import (
    add_model_and_data,
    add_report_outputs,
    check_model_quality,
    load_checked,
)
from workbench.core.atomic import check_output, write_text
from workbench.core.errors import InputError
from workbench.io.formats import read_model


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "diagnose",
        help="which physical effect does the model miss? fit it, rank the findings",
        description=(
            "Compare a model with a measurement (FRF or time record) and tell which physical "
            "effect of the vocabulary (time_delay, missing_mode, modal_mismatch, "
            "residual_compliance, actuator_dynamics, sensor_dynamics, suspension_stiffness, "
            "crosstalk, nonlinearity, none) the model is missing; each is fitted and the "
            "error before/after reported. Time data: ZOH simulation driven by the recorded u, "
            "from rest, or from the initial state compare estimates when the record does not "
            "start at rest (the notes say which)."
        ),
    )
    add_model_and_data(p)
    add_report_outputs(p, json_help="write the findings JSON to OUT")
    p.add_argument(
        "--max-effects", type=int, default=3, help="effects looked for in turn (default 3)"
    )
    return p


def summary(result) -> str:
    lines = [f"error before: {result.error_before:.5g}"]
    if result.noise_floor is not None:
        lines[0] += f"   (noise floor from G_var: {result.noise_floor:.5g})"
    for k, f in enumerate(result.findings, 1):
        params = {
            key: v for key, v in f.parameters.items() if key not in ("matrix", "residue_matrix")
        }
        text = ", ".join(f"{key}={_short(v)}" for key, v in params.items())
        lines.append(f"{k}. {f.effect}: {text}")
        lines.append(
            f"   error after: {f.error_after:.5g}; inputs {list(f.inputs)}, outputs "
            f"{list(f.outputs)}, band {f.band_hz[0]:.4g}-{f.band_hz[1]:.4g} Hz"
        )
        lines.append(f"   {f.explanation}")
    # what the numbers are (from rest or an estimated start, a model converted): said, not
    # left to the JSON
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.5g}"
    if isinstance(v, list):
        return "[" + ", ".join(_short(x) if x is not None else "-" for x in v) + "]"
    if isinstance(v, dict):  # a mode in a list (modes, modes_above_nyquist)
        return "{" + ", ".join(f"{k}={_short(x)}" for k, x in v.items()) + "}"
    return str(v)


def run(args) -> int:
    from workbench.diagnosis import diagnose

    if args.json:
        check_output(args.json, [args.model, args.data], what="--json")
    if args.plots:
        check_output(args.plots, [args.model, args.data], folder=True, what="--plots")
    if args.max_effects < 1:
        raise InputError(f"--max-effects: expected an integer >= 1, got {args.max_effects}")
    model = read_model(args.model)  # the file's delay_s travels with the model
    data = load_checked(args.data, model=model, model_src=str(args.model))
    check_model_quality(model, args.model)
    result = diagnose(model, data, max_effects=args.max_effects)
    print(summary(result))
    if args.json:
        write_text(args.json, json.dumps(result.to_json(), indent=2) + "\n")
    if args.plots:
        from workbench.diagnosis.diagnose import base_model
        from workbench.diagnosis.plots import write_plots

        before = base_model(model.without_delay().to_statespace(), data, model.delay_s)
        paths = write_plots(
            args.plots, data, before, result.model, title="diagnose: before / after"
        )
        print("plots: " + ", ".join(str(p) for p in paths))
    return 0
