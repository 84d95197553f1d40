"""``workbench identify DATA --method M --out MODEL.npz``: subspace identification.

Reads a time-domain measurement (spec 1a), identifies a discrete model
(dt = 1/fs) with a closed-loop (projection onto r) or open-loop subspace
method, prints the singular values with the suggested order, and writes the
model in the spec model format (plus ``delay_s`` when an input delay was
given). ``--modal`` also writes the continuous modal model; ``--refine``
refines it first by maximum likelihood on the period-averaged spectra of a
periodic record (:func:`workbench.ident.refine.refine_modal_model`);
``--sv-plot`` saves the singular values as a PNG.
"""

from __future__ import annotations

import argparse

import numpy as np

from workbench.atomic import check_not_input
from workbench.errors import InputError
from workbench.formats import TimeData, load_measurement, save_model
from workbench.ident import METHODS, format_singular_values, identify_subspace, plot_singular_values


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "identify",
        help="identify a discrete state-space model from a time record (subspace methods)",
        description=(
            "Closed-loop subspace identification by orthogonal projection onto the excitation r "
            "(cl-n4sid, cl-moesp, cl-cva) or plain open-loop N4SID/MOESP (biased on closed-loop "
            "data). Prints the singular values and the suggested order; writes a discrete model "
            "(dt = 1/fs) in the spec model format."
        ),
    )
    p.add_argument("data", metavar="DATA", help="time-domain measurement .npz (kind 'time')")
    p.add_argument("--method", choices=METHODS, default="cl-moesp", help="default: cl-moesp")
    p.add_argument("--order", type=int, default=None, help="model order (default: suggested)")
    p.add_argument("--block-rows", type=int, default=20, help="block rows i (default 20)")
    p.add_argument(
        "--max-order", type=int, default=None, help="largest order the suggestion considers"
    )
    p.add_argument(
        "--input-delay",
        type=int,
        default=0,
        help="known input delay in samples, removed from the data (stored as delay_s)",
    )
    p.add_argument("--no-feedthrough", action="store_true", help="D = 0 (strictly proper plant)")
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="output model file")
    p.add_argument("--modal", metavar="MODAL.npz", help="also write the continuous modal model")
    p.add_argument(
        "--rigid-threshold-hz", type=float, default=5.0, help="rigid-body threshold for --modal, Hz"
    )
    p.add_argument(
        "--refine",
        action="store_true",
        help="refine the --modal model by maximum likelihood on the period-averaged spectra "
        "(periodic records)",
    )
    p.add_argument("--sv-plot", metavar="PNG", help="save the singular values plot")
    return p


def run(args) -> int:
    outputs = [o for o in (args.out, args.modal, args.sv_plot) if o]
    for out in outputs:
        check_not_input(out, [args.data])
    if len(set(outputs)) != len(outputs):
        raise InputError(
            "--out, --modal and --sv-plot: expected distinct files, got a repeated path"
        )
    if getattr(args, "refine", False) and not args.modal:
        raise InputError(
            "--refine: expected --modal MODAL.npz for the refined modal model, got none"
        )
    data = load_measurement(args.data)
    if not isinstance(data, TimeData):
        raise InputError(
            f"{args.data}: expected a time-domain measurement (kind 'time'), got kind 'frf'"
        )
    res = identify_subspace(
        data,
        method=args.method,
        order=args.order,
        block_rows=args.block_rows,
        input_delay=args.input_delay,
        feedthrough=not args.no_feedthrough,
        max_order=args.max_order,
    )
    modal = None
    if args.modal:
        from workbench.modal import ModalModel

        modal = ModalModel.from_statespace(res.model, rigid_threshold_hz=args.rigid_threshold_hz)
    refined = None
    if modal is not None and getattr(args, "refine", False):
        from workbench.ident.refine import refine_modal_model

        refined = refine_modal_model(
            modal, data, input_delay=res.input_delay, feedthrough=not args.no_feedthrough
        )
        modal = refined.model
    extra = {"delay_s": np.array(res.delay_s)} if res.input_delay else {}
    save_model(args.out, res.model, **extra)
    if modal is not None:
        save_model(args.modal, modal.to_statespace(), **extra)
    if args.sv_plot:
        plot_singular_values(
            res.singular_values,
            args.sv_plot,
            order=res.order,
            suggested=res.suggested_order,
            title=f"{args.method}, i = {res.block_rows}",
        )
    print(
        f"method {res.method}, block rows {res.block_rows}, input delay {res.input_delay} samples"
    )
    print(
        format_singular_values(
            res.singular_values, order=res.order, suggested=res.suggested_order, gap=res.gap
        )
    )
    for note in res.notes:
        print(f"note: {note}")
    print(f"wrote {args.out} (order {res.order}, dt = {1 / data.fs:g} s)")
    if refined is not None:
        print(
            f"refined by maximum likelihood on {refined.n_lines} lines: weighted misfit "
            f"{refined.misfit:.2f} (1 = noise level), {refined.nfev} evaluations"
        )
        for m, sf, sz in zip(refined.model.modes, refined.freq_std_hz, refined.damping_std):
            if m.kind == "flexible":
                print(f"  {m.freq_hz:10.3f} +/- {sf:.3f} Hz   damping {m.damping:.5f} +/- {sz:.5f}")
        for note in refined.notes:
            print(f"note: {note}")
    if modal is not None:
        print(f"wrote {args.modal} (continuous modal model, {len(modal.modes)} modes)")
    return 0
