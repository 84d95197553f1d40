"""``workbench compare --model MODEL --data DATA``: how well a model fits a measurement.

Prints the spec's error figure, per-channel errors and the bands where the
model fails beyond the noise; ``--json OUT`` writes the summary atomically,
``--plots DIR`` writes PNG figures (error map, Bode overlay or time plots).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from workbench.cli.commands import (
    add_model_and_data,
    add_report_outputs,
    check_model_quality,
    load_checked,
)
from workbench.core.atomic import check_output, write_text
from workbench.core.errors import InputError
from workbench.io.formats import lti_model_from_arrays, read_npz
from workbench.validate.compare import Comparison, compare
from workbench.validate.plots import write_plots

_MAX_PRINTED_BANDS = 40


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "compare",
        help="compare a model with a measurement: error, per-channel errors, failing bands",
        description=(
            "Compare a state-space model with a measurement (FRF or time). FRF: per line and "
            "element z = |G_meas - G_model|^2 / G_var and the bands where the model fails "
            "beyond the noise. Time: simulation errors (ZOH) from rest (the spec measure) "
            "and from the initial state estimated by least squares, one-step prediction "
            "errors, residual spectra, residual/excitation cross-correlation and failing "
            "bands (from the estimated start)."
        ),
    )
    add_model_and_data(p)
    add_report_outputs(p, json_help="write the summary as JSON to OUT")
    p.add_argument(
        "--delay-s",
        type=float,
        default=None,
        help="input delay added to the model, s (default: the model file's delay_s key, else 0)",
    )
    p.add_argument("--window", type=int, default=9, help="lines per running median (default 9)")
    p.add_argument(
        "--false-alarm",
        type=float,
        default=1e-3,
        help="probability that a right model shows any failing band (default 1e-3)",
    )
    return p


def _fmt_band(b, out_names, in_names) -> str:
    ch = out_names[b.output] + ("" if b.input is None else f"/{in_names[b.input]}")
    idx = f"({b.output})" if b.input is None else f"({b.output},{b.input})"
    return (
        f"  {ch:>12s} {idx:8s} {b.f_lo_hz:10.4g} - {b.f_hi_hz:<10.4g} Hz  "
        f"{b.n_lines:5d} lines  median {b.median:.3g}  peak {b.peak:.3g}"
    )


def format_text(res: Comparison, model_src: str, data_src: str) -> str:
    lines = [
        f"model: {model_src}" + (f" (input delay {res.delay_s:g} s)" if res.delay_s else ""),
        f"data:  {data_src} ({res.kind})",
        f"error (spec measure): {res.error:.6g}"
        + (" (simulation from rest)" if res.kind == "time" else ""),
    ]
    if res.kind == "time":
        if res.error_estimated_start is not None:
            lines.append(
                f"error with estimated start: {res.error_estimated_start:.6g} "
                "(initial state by least squares)"
            )
        else:
            lines.append(f"error with estimated start: not computed ({res.time.x0_note})")
    if res.whole_record_ratio is not None:
        lines.append(
            f"whole record: {res.whole_record_ratio:.4g}x the noise floor "
            f"{res.error_noise_floor:.4g} (about 1 when within noise; every sample and line)"
        )
    if res.z_mean is not None:
        # F(2, d) (G_var from few averages, periods) has mean d / (d - 2), not 1
        right = "1" if res.z_expected is None else f"{res.z_expected:.3g}"
        lines.append(
            f"mean noise-normalized error z: {res.z_mean:.4g} (about {right} when within noise)"
        )
    if res.kind == "frf":
        lines.append("error per channel (rows: outputs, columns: inputs):")
        lines += ["  " + "  ".join(f"{v:9.3g}" for v in row) for row in res.error_per_channel]
    else:
        t = res.time
        lines.append(
            "per output:  simulation error from rest   from estimated start   "
            "one-step prediction error"
        )
        for i, name in enumerate(res.output_names):
            x0 = "-" if t.sim_error_x0 is None else f"{t.sim_error_x0[i]:.4g}"
            lines.append(
                f"  {name:>10s}  {t.sim_error[i]:24.4g}   {x0:>20s}   {t.pred_error[i]:14.4g}"
            )
        lines.append(
            f"residual spectra, cross-correlation and bands: simulation from {t.residual_from}"
        )
        lines.append(
            f"residual x {t.xcorr_against} cross-correlation: {100 * t.xcorr_outside:.1f} % of "
            f"lags outside the 99 % bound {t.xcorr_bound:.3g}; "
            f"{int(t.xcorr_exceeds.sum())} of {t.xcorr_exceeds.size} pairs exceed at some lag"
        )
    lines.append(f"criterion: {res.criterion}")
    if res.failing_bands:
        lines.append(f"failing bands ({len(res.failing_bands)}):")
        for b in res.failing_bands[:_MAX_PRINTED_BANDS]:
            lines.append(_fmt_band(b, res.output_names, res.input_names))
        if len(res.failing_bands) > _MAX_PRINTED_BANDS:
            lines.append(
                f"  ... and {len(res.failing_bands) - _MAX_PRINTED_BANDS} more (see --json)"
            )
    elif res.z_mean is not None:
        lines.append("failing bands: none, the model is within noise")
    else:
        lines.append("failing bands: none declared (no noise reference)")
    lines += [f"note: {n}" for n in res.notes]
    return "\n".join(lines)


def run(args) -> int:
    inputs = [args.model, args.data]
    if args.json:
        check_output(args.json, inputs, what="--json")
    if args.plots:
        check_output(args.plots, inputs, folder=True, what="--plots")
    model_arrays = read_npz(args.model)
    if "A" not in model_arrays:
        raise InputError(
            f"{args.model}: expected a model file (keys A, B, C, D, dt), got a measurement"
        )
    model = lti_model_from_arrays(model_arrays, src=str(args.model))  # with its delay_s
    if args.delay_s is not None:
        if not np.isfinite(args.delay_s) or args.delay_s < 0:
            raise InputError(
                f"--delay-s: expected a finite delay >= 0 s (it replaces the model file's "
                f"delay_s), got {args.delay_s:g}"
            )
        model = model.replace(delay_s=args.delay_s)
    data = load_checked(args.data, model=model, model_src=str(args.model))
    check_model_quality(model, args.model)
    res = compare(
        model,
        data,
        window=args.window,
        false_alarm=args.false_alarm,
        model_src=str(args.model),
        data_src=str(args.data),
    )
    print(format_text(res, str(args.model), str(args.data)))
    if args.json:
        summary = {"model": str(args.model), "data": str(args.data), **res.as_dict()}
        write_text(args.json, json.dumps(summary, indent=2) + "\n")
    if args.plots:
        for p in write_plots(res, Path(args.plots), inputs):
            print(f"plot: {p}")
    return 0
