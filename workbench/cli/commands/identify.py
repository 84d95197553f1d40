"""``workbench identify DATA --method M --out MODEL.npz``: subspace identification.

Reads a time-domain measurement (spec 1a), identifies a discrete model
(dt = 1/fs) with a closed-loop (projection onto r) or open-loop subspace
method, prints the singular values with the suggested order, and writes the
model in the spec model format (plus ``delay_s`` when an input delay was
given). ``--modal`` also writes the continuous modal model; ``--refine``
refines it first by maximum likelihood on the period-averaged spectra of a
periodic record (:func:`workbench.ident.refine.refine_modal_model`);
``--sv-plot`` saves the singular values as a PNG.

Real records: ``--validate FRACTION`` identifies on the first
``1 - FRACTION`` of the samples and scores the model on the rest (or
``--validation DATA.npz``): fit per output with the validation part's initial
state estimated by least squares. ``--orders A:B`` scans the orders by that
fit (table and PNG). ``--detrend mean|linear`` removes offsets or trends
first. Everything is also written to a JSON report beside the model
(``--json``, default ``MODEL.json``), offsets included so that predictions
can add them back.
"""

from __future__ import annotations

import argparse

import numpy as np

from workbench.core.atomic import check_not_input
from workbench.core.errors import InputError
from workbench.core.model import LTIModel
from workbench.ident import METHODS, format_singular_values, identify_subspace, plot_singular_values
from workbench.io.formats import TimeData, load_measurement
from workbench.signals.quality import check_measurement


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
    val = p.add_mutually_exclusive_group()
    val.add_argument(
        "--validate",
        type=float,
        metavar="FRACTION",
        help="identify on the first 1-FRACTION of the samples, validate on the rest",
    )
    val.add_argument(
        "--validation", metavar="DATA.npz", help="validate on this separate time record"
    )
    p.add_argument(
        "--orders",
        metavar="A:B",
        help="scan the orders A..B by validation fit (table and PNG); needs a validation part",
    )
    p.add_argument(
        "--orders-plot",
        metavar="PNG",
        help="where to save the order-scan plot (default: MODEL_orders.png beside --out)",
    )
    p.add_argument(
        "--detrend",
        choices=("none", "mean", "linear"),
        default="none",
        help="remove per-channel means or linear trends of u and y first (default none)",
    )
    p.add_argument(
        "--json",
        metavar="REPORT.json",
        help="the identification report (default: MODEL.json beside --out)",
    )
    return p


def _parse_orders(text: str, limit: int) -> list[int]:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise InputError(f"--orders: expected A:B (two integers), got {text!r}") from None
    if not 1 <= a <= b < limit:
        raise InputError(
            f"--orders: expected 1 <= A <= B < block_rows * n_y = {limit}, got {text!r}"
        )
    return list(range(a, b + 1))


def run(args) -> int:
    import json
    from pathlib import Path

    from workbench.core.atomic import write_text
    from workbench.core.jsonutil import jsonable
    from workbench.ident.order import (
        format_order_scan,
        gap_verdict,
        plot_order_scan,
        runner_up_gap,
    )
    from workbench.ident.validate import (
        offset_warning,
        remove_offsets,
        simulation_fit,
        split_record,
    )

    out = Path(args.out)
    report_path = args.json or str(out.with_suffix(".json"))
    scan_plot = None
    if args.orders:
        scan_plot = args.orders_plot or str(out.with_name(out.stem + "_orders.png"))
    outputs = [o for o in (args.out, args.modal, args.sv_plot, report_path, scan_plot) if o]
    inputs = [args.data] + ([args.validation] if args.validation else [])
    for o in outputs:
        check_not_input(o, inputs)
    if len(set(outputs)) != len(outputs):
        raise InputError(
            "--out, --modal, --sv-plot, --json and --orders-plot: expected distinct files, "
            "got a repeated path"
        )
    if getattr(args, "refine", False) and not args.modal:
        raise InputError(
            "--refine: expected --modal MODAL.npz for the refined modal model, got none"
        )
    if args.orders and args.validate is None and not args.validation:
        raise InputError(
            "--orders: expected a validation part (--validate FRACTION or --validation "
            "DATA.npz), got neither"
        )
    data = _load_time(args.data)
    check_measurement(data, src=str(args.data), method=args.method)
    val_data, val_t0, val_source = None, 0.0, None
    if args.validate is not None:
        data, val_data = split_record(data, args.validate)
        val_t0 = data.n_samples / data.fs
        total = data.n_samples + val_data.n_samples
        val_source = (
            f"last {100 * val_data.n_samples / total:.3g} % of {args.data} "
            f"({val_data.n_samples} samples; identification on the first {data.n_samples}"
            + (", cut at a period boundary" if data.period is not None else "")
            + ")"
        )
    elif args.validation:
        val_data = _load_time(args.validation)
        check_measurement(val_data, src=str(args.validation))
        if (val_data.n_u, val_data.n_y) != (data.n_u, data.n_y):
            raise InputError(
                f"{args.validation}: expected {data.n_u} inputs and {data.n_y} outputs like "
                f"{args.data}, got {val_data.n_u} and {val_data.n_y}"
            )
        val_source = f"{args.validation} ({val_data.n_samples} samples)"
    warning = offset_warning(data)
    if warning and args.detrend == "none":
        print(f"warning: {warning}")
    data, offsets = remove_offsets(data, args.detrend)
    if val_data is not None and args.detrend != "none":
        val_data = offsets.apply(val_data, t0=val_t0)
    kw = dict(
        method=args.method,
        block_rows=args.block_rows,
        input_delay=args.input_delay,
        feedthrough=not args.no_feedthrough,
        max_order=args.max_order,
    )
    scan = None
    if args.orders:
        orders = _parse_orders(args.orders, args.block_rows * data.n_y)
        results = identify_subspace(data, orders=orders, **kw)
        fits = [simulation_fit(r.lti_model, val_data) for r in results]
        scan = (orders, fits)
    res = identify_subspace(data, order=args.order, **kw)
    val_fit = None
    if val_data is not None:
        val_fit = simulation_fit(res.lti_model, val_data)
    modal = None
    if args.modal:
        from workbench.modal.model import ModalModel

        modal = ModalModel.from_statespace(res.model, rigid_threshold_hz=args.rigid_threshold_hz)
    refined = None
    if modal is not None and getattr(args, "refine", False):
        from workbench.ident.refine import refine_modal_model

        refined = refine_modal_model(
            modal, data, input_delay=res.input_delay, feedthrough=not args.no_feedthrough
        )
        modal = refined.model
    res.lti_model.write(args.out)  # the delay exact in key 'delay_s'
    if modal is not None:
        LTIModel.from_statespace(modal.to_statespace(), delay_s=res.delay_s).write(args.modal)
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
    max_order = args.max_order or max(1, res.block_rows * data.n_y // 2)
    print(
        format_singular_values(
            res.singular_values,
            order=res.order,
            suggested=res.suggested_order,
            gap=res.gap,
            max_order=max_order,
        )
    )
    print(f"B, D: {res.bd_method}")
    if args.detrend != "none":
        print(
            f"detrend {args.detrend}: removed u offsets {np.round(offsets.u_offset, 6).tolist()}, "
            f"y offsets {np.round(offsets.y_offset, 6).tolist()}"
            + (
                f", slopes u {offsets.u_slope.tolist()} y {offsets.y_slope.tolist()} per s"
                if args.detrend == "linear"
                else ""
            )
            + " (in the report)"
        )
    for note in res.notes:
        print(f"note: {note}")
    if scan is not None:
        print(f"order scan on the validation part, {val_source}:")
        print(format_order_scan(scan[0], scan[1], output_names=data.output_names))
        plot_order_scan(
            scan[0],
            scan[1],
            scan_plot,
            output_names=data.output_names,
            title=f"{args.method}, i = {res.block_rows}: validation fit by order",
        )
        print(f"wrote {scan_plot}")
    if val_fit is not None:
        print(
            f"validation (order {res.order}) on {val_source}: "
            + val_fit.describe(list(data.output_names))
        )
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
    report = {
        "data": str(args.data),
        "method": res.method,
        "block_rows": res.block_rows,
        "order": res.order,
        "suggested_order": res.suggested_order,
        "gap_ratio": res.gap,
        "gap_verdict": gap_verdict(
            res.gap, runner_up=runner_up_gap(res.singular_values, res.suggested_order, max_order)
        ),
        "singular_values": res.singular_values,
        "bd_method": res.bd_method,
        "input_delay_samples": res.input_delay,
        "identification_samples": data.n_samples,
        "initial_state_identification": res.x0,
        "offsets": offsets.as_dict(),
        "offset_warning": warning,
        "notes": list(res.notes),
    }
    if val_fit is not None:
        report["validation"] = {"source": val_source, **val_fit.as_dict()}
    if scan is not None:
        report["order_scan"] = [{"order": n, **f.as_dict()} for n, f in zip(scan[0], scan[1])]
    write_text(report_path, json.dumps(jsonable(report), indent=2) + "\n")
    print(f"wrote {report_path} (report)")
    return 0


def _load_time(path) -> TimeData:
    data = load_measurement(path)
    if not isinstance(data, TimeData):
        raise InputError(
            f"{path}: expected a time-domain measurement (kind 'time'), got kind 'frf'"
        )
    return data
