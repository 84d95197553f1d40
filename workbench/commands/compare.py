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

from workbench.atomic import check_not_input, write_text
from workbench.compare import Comparison, compare
from workbench.errors import InputError
from workbench.formats import load_measurement, read_npz
from workbench.quality import check_measurement

_MAX_PRINTED_BANDS = 40


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "compare",
        help="compare a model with a measurement: error, per-channel errors, failing bands",
        description=(
            "Compare a state-space model with a measurement (FRF or time). FRF: per line and "
            "element z = |G_meas - G_model|^2 / G_var and the bands where the model fails "
            "beyond the noise. Time: simulation (ZOH, from rest) and one-step prediction "
            "errors, residual spectra and residual/excitation cross-correlation."
        ),
    )
    p.add_argument("--model", required=True, metavar="MODEL", help="model .npz (A, B, C, D, dt)")
    p.add_argument("--data", required=True, metavar="DATA", help="measurement .npz")
    p.add_argument("--json", metavar="OUT", help="write the summary as JSON to OUT")
    p.add_argument("--plots", metavar="DIR", help="write PNG figures into DIR")
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
        f"error (spec measure): {res.error:.6g}",
    ]
    if res.z_mean is not None:
        lines.append(f"mean noise-normalized error z: {res.z_mean:.4g} (about 1 when within noise)")
    if res.kind == "frf":
        lines.append("error per channel (rows: outputs, columns: inputs):")
        lines += ["  " + "  ".join(f"{v:9.3g}" for v in row) for row in res.error_per_channel]
    else:
        t = res.time
        lines.append("per output:  simulation error   one-step prediction error")
        for i, name in enumerate(res.output_names):
            lines.append(f"  {name:>10s}  {t.sim_error[i]:14.4g}   {t.pred_error[i]:14.4g}")
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


def write_plots(res: Comparison, folder: Path, inputs) -> list[Path]:
    """The figures of a comparison, into ``folder``; returns the paths written."""
    from workbench import plotting

    folder.mkdir(parents=True, exist_ok=True)
    written = []

    def target(name):
        p = folder / name
        check_not_input(p, inputs)
        written.append(p)
        return p

    if res.kind == "frf":
        labels = [f"{y}/{u}" for y in res.output_names for u in res.input_names]
        stat = res.error_map.reshape(res.error_map.shape[0], -1)
        f = res.frf
        plotting.save_bode_overlay(
            target("bode_overlay.png"),
            f.freq_hz,
            f.G_meas,
            f.G_model,
            f.G_var,
            input_names=res.input_names,
            output_names=res.output_names,
        )
    else:
        labels = list(res.output_names)
        stat = res.error_map
        t = res.time
        tt = np.arange(t.y.shape[0]) / t.fs
        plotting.save_time_overlay(
            target("time_overlay.png"), tt, t.y, t.y_model, output_names=res.output_names
        )
        plotting.save_residual_spectra(
            target("residual_spectra.png"),
            t.psd_freq_hz,
            t.psd_residual,
            t.psd_output,
            output_names=res.output_names,
        )
        plotting.save_xcorr(
            target("residual_xcorr.png"),
            t.xcorr_lags,
            t.xcorr,
            t.xcorr_bound,
            input_names=res.input_names,
            output_names=res.output_names,
            against=t.xcorr_against,
        )
    plotting.save_error_map(
        target("error_map.png"),
        res.map_freq_hz,
        stat,
        channel_labels=labels,
        threshold=res.threshold,
        title=res.map_label,
    )
    return written


def run(args) -> int:
    inputs = [args.model, args.data]
    if args.json:
        check_not_input(args.json, inputs)
    model_arrays = read_npz(args.model)
    from workbench.formats import model_from_arrays

    if "A" not in model_arrays:
        raise InputError(
            f"{args.model}: expected a model file (keys A, B, C, D, dt), got a measurement"
        )
    model = model_from_arrays(model_arrays, src=str(args.model))
    data = load_measurement(args.data)
    delay_s = args.delay_s
    if delay_s is None:
        delay_s = 0.0
        if "delay_s" in model_arrays:
            d = np.asarray(model_arrays["delay_s"])
            if d.size != 1 or d.dtype.kind not in "iuf":
                raise InputError(
                    f"{args.model}: key 'delay_s': expected a real scalar, s, got shape {d.shape}"
                )
            delay_s = float(d.reshape(()))
    res = compare(
        model,
        data,
        delay_s=delay_s,
        window=args.window,
        false_alarm=args.false_alarm,
        model_src=str(args.model),
        data_src=str(args.data),
    )
    # after compare() has refused what it refuses: a refusal is never preceded by warnings
    check_measurement(data, src=str(args.data))
    print(format_text(res, str(args.model), str(args.data)))
    if args.json:
        summary = {"model": str(args.model), "data": str(args.data), **res.as_dict()}
        write_text(args.json, json.dumps(summary, indent=2) + "\n")
    if args.plots:
        for p in write_plots(res, Path(args.plots), inputs):
            print(f"plot: {p}")
    return 0
