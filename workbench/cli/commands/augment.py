"""``workbench augment --model MODEL --data DATA --effect NAME [--out MODEL2] [--plots DIR]``.

Adds one effect to the model, fits it, prints the error before/after and
writes the augmented model (spec keys, the delay apart in 'delay_s', and a
Pade state-space version of the delay in '*_pade' keys).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from workbench.cli.commands import (
    add_model_and_data,
    add_report_outputs,
    check_model_quality,
    load_checked,
)
from workbench.core.atomic import check_output, write_text
from workbench.io.formats import model_arrays, read_model, save_model


def register(subparsers) -> argparse.ArgumentParser:
    from workbench.diagnosis.augment import EFFECTS

    p = subparsers.add_parser(
        "augment",
        help="add one physical effect to a model and fit it to the data",
        description=(
            "Add a named effect to the model, fit its parameters to the measurement, print the "
            "error before/after and write the augmented model. A delay is kept exact in the "
            "key 'delay_s' (A, B, C, D without it) and given as Pade states in A_pade.. keys."
        ),
    )
    add_model_and_data(p)
    p.add_argument("--effect", required=True, choices=EFFECTS, help="the effect to add")
    p.add_argument("--out", metavar="MODEL2", help="write the augmented model .npz")
    add_report_outputs(p, json_help="write the fitted parameters as JSON")
    return p


def run(args) -> int:
    from workbench.core.model import pade_order
    from workbench.diagnosis.augment import augment

    for out, what in ((args.out, "--out"), (args.json, "--json")):
        if out:
            check_output(out, [args.model, args.data], what=what)
    if args.plots:
        check_output(args.plots, [args.model, args.data], folder=True, what="--plots")
    model = read_model(args.model)  # the file's delay_s travels with the model
    data = load_checked(args.data, model=model, model_src=str(args.model))
    check_model_quality(model, args.model)
    res = augment(model, data, args.effect)
    params = {k: v for k, v in res.parameters.items() if k not in ("matrix", "residue_matrix")}
    print(f"effect: {res.effect}")
    for k, v in params.items():
        std = res.parameters_std.get(k)
        print(
            f"  {k} = {v}"
            + (f"  (std {std})" if std is not None and not isinstance(std, list) else "")
        )
    if "matrix" in res.parameters:
        print("  matrix =\n" + np.array2string(np.asarray(res.parameters["matrix"]), precision=4))
    print(f"error before: {res.error_before:.5g}")
    print(f"error after:  {res.error_after:.5g}")
    if res.note:
        print(f"note: {res.note}")
    if args.out:
        extra = {}
        if res.delay_s > 0:
            f_max = float(data.freq[-1]) if data.kind == "frf" else data.fs / 2
            n = pade_order(res.delay_s, f_max)
            arr = model_arrays(res.model.to_statespace(pade_order=n))
            extra.update({f"{k}_pade": arr[k] for k in ("A", "B", "C", "D")})
            extra["pade_order"] = np.array(n)
            print(
                f"delay {res.delay_s * 1e6:.4g} us: exact in key 'delay_s' (A, B, C, D without "
                "it); "
                f"Pade order {n} per input in keys A_pade..D_pade (phase error < 1 deg up to "
                f"{f_max:.4g} Hz)"
            )
        save_model(args.out, res.model, **extra)  # the delay exact in 'delay_s' when > 0
        print(f"augmented model: {args.out} ({res.model.n_x} states, continuous)")
    if args.json:
        from workbench.core.jsonutil import jsonable

        write_text(args.json, json.dumps(jsonable(res.to_json()), indent=2) + "\n")
    if args.plots and res.extended is not None:
        from workbench.diagnosis.diagnose import base_model
        from workbench.diagnosis.plots import write_plots

        before = base_model(model.without_delay().to_statespace(), data, model.delay_s)
        paths = write_plots(args.plots, data, before, res.extended, title=f"augment {res.effect}")
        print("plots: " + ", ".join(str(p) for p in paths))
    return 0
