"""``workbench info FILE``: what a measurement or model file holds.

Measurements: kind, shapes, sampling, period, loop, channel names, frequency
range, and the data-quality warnings of :mod:`workbench.signals.quality`. Models:
states, sample time, a pole summary (rigid-body poles, flexible modes in Hz
with damping, real poles) and the DC gain where it is finite. Plain text, or
one JSON object with ``--json``.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from workbench.core.model import LTIModel, dc_gain, pole_summary
from workbench.io.formats import (
    FrfData,
    TimeData,
    lti_model_from_arrays,
    measurement_from_arrays,
    read_npz,
)
from workbench.signals.quality import check_measurement, check_model

_SPEC_MODEL_KEYS = {"A", "B", "C", "D", "dt", "input_names", "output_names"}


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "info",
        help="describe a measurement or model file (shapes, sampling, poles, quality warnings)",
        description=(
            "Describe a measurement (.npz, kind 'time' or 'frf') or a state-space model file: "
            "shapes, sampling, channel names, frequency range; for models the poles "
            "(rigid-body, flexible modes with Hz and damping) and the DC gain. Measurements "
            "are checked for poor data (printed as 'warning: ...' lines, exit status 0)."
        ),
    )
    p.add_argument("file", metavar="FILE", help="measurement or model .npz file")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    return p


# ------------------------------------------------------------------ summaries
def describe_model(model: LTIModel, arrays: dict) -> dict:
    """Summary of a model, JSON-ready (``arrays``: the file's keys, for the extra ones)."""
    poles = pole_summary(model)
    gain = dc_gain(model, poles=poles)
    out = {
        "kind": "model",
        "time": "continuous" if model.dt == 0 else "discrete",
        "dt": model.dt,
        "n_states": model.n_x,
        "n_u": model.n_u,
        "n_y": model.n_y,
        "input_names": list(model.input_names),
        "output_names": list(model.output_names),
        "poles": poles,
        "dc_gain": None if gain is None else gain.tolist(),
    }
    if "delay_s" in arrays:
        out["delay_s"] = model.delay_s
    extra = sorted(set(arrays) - _SPEC_MODEL_KEYS)
    if extra:
        out["extra_keys"] = extra
    return out


def describe_measurement(data: TimeData | FrfData) -> dict:
    """Summary of a measurement, JSON-ready (warnings are added by the caller)."""
    base = {
        "kind": data.kind,
        "n_u": data.n_u,
        "n_y": data.n_y,
        "input_names": list(data.input_names),
        "output_names": list(data.output_names),
    }
    if isinstance(data, TimeData):
        N = data.n_samples
        out = {
            **base,
            "n_samples": N,
            "fs": data.fs,
            "duration_s": N / data.fs,
            "loop": data.loop,
            "has_r": data.r is not None,
            "period": data.period,
            "n_periods": None if data.period is None else N // data.period,
            "freq_range_hz": [data.fs / (N if data.period is None else data.period), data.fs / 2],
            "u_shape": list(data.u.shape),
            "y_shape": list(data.y.shape),
        }
        if data.period is not None and N // data.period >= 2:
            e = data.r if data.r is not None else data.u
            blocks = e.reshape(N // data.period, data.period, -1)
            out["periods_identical"] = bool(
                np.abs(np.diff(blocks, axis=0)).max() <= 1e-9 * max(np.abs(e).max(), 1e-300)
            )
        return out
    d = np.diff(data.freq)
    return {
        **base,
        "n_f": data.n_f,
        "G_shape": list(data.G.shape),
        "has_G_var": data.G_var is not None,
        "fs": data.fs,
        "freq_range_hz": [float(data.freq[0]), float(data.freq[-1])],
        "median_spacing_hz": float(np.median(d)) if d.size else None,
    }


# ----------------------------------------------------------------------- text
def _fmt_names(names) -> str:
    return ", ".join(names)


def format_text(info: dict) -> str:
    lines = [f"file: {info['file']}"]
    if info["kind"] == "model":
        lines += [
            f"kind: model, {info['time']} time"
            + (f", dt = {info['dt']:g} s" if info["dt"] else ""),
            f"states: {info['n_states']}",
            f"inputs ({info['n_u']}): {_fmt_names(info['input_names'])}",
            f"outputs ({info['n_y']}): {_fmt_names(info['output_names'])}",
        ]
        if "delay_s" in info:
            lines.append(f"input delay (key delay_s): {info['delay_s']:g} s")
        p = info["poles"]
        lines.append(f"rigid-body poles (s = 0): {p['n_rigid_body_poles']}")
        if p["flexible_modes"]:
            lines.append(f"flexible modes ({len(p['flexible_modes'])}):")
            lines += [
                f"  {m['freq_hz']:10.4g} Hz  damping {m['damping']:.4g}"
                for m in p["flexible_modes"]
            ]
        if p["real_poles_hz"]:
            lines.append("real poles (Hz): " + ", ".join(f"{f:.4g}" for f in p["real_poles_hz"]))
        if p["n_unstable"]:
            lines.append(f"unstable poles: {p['n_unstable']}")
        if info["dc_gain"] is None:
            lines.append("DC gain: infinite (integrating / rigid-body poles)")
        else:
            g = np.asarray(info["dc_gain"])
            lines.append("DC gain:")
            lines += ["  " + "  ".join(f"{v: .4g}" for v in row) for row in g]
        return "\n".join(lines)
    if info["kind"] == "time":
        lines += [
            f"kind: time, {info['loop']}-loop" + (", with r" if info["has_r"] else ", no r"),
            f"samples: {info['n_samples']} at fs = {info['fs']:g} Hz ({info['duration_s']:g} s)",
            f"u: {tuple(info['u_shape'])}, y: {tuple(info['y_shape'])}",
        ]
        if info["period"] is not None:
            same = info.get("periods_identical")
            note = ""
            if same is True:
                note = " (identical periods: one experiment; a per-line MIMO FRF needs more)"
            elif same is False:
                note = " (periods differ: multi-experiment excitation)"
            lines.append(f"period: {info['period']} samples, {info['n_periods']} periods{note}")
        lo, hi = info["freq_range_hz"]
        lines.append(f"frequency range: {lo:g} Hz (resolution) to {hi:g} Hz (Nyquist)")
    else:
        lo, hi = info["freq_range_hz"]
        lines += [
            f"kind: frf, {info['n_f']} lines, G {tuple(info['G_shape'])}"
            + (", with G_var" if info["has_G_var"] else ", no G_var"),
            f"frequency range: {lo:g} to {hi:g} Hz, "
            f"median spacing {info['median_spacing_hz']:g} Hz",
        ]
        if info["fs"] is not None:
            lines.append(f"fs of the experiment: {info['fs']:g} Hz")
    lines += [
        f"inputs ({info['n_u']}): {_fmt_names(info['input_names'])}",
        f"outputs ({info['n_y']}): {_fmt_names(info['output_names'])}",
        f"quality: {len(info['warnings'])} warning(s)" + ("" if info["warnings"] else ", none"),
    ]
    return "\n".join(lines)


def run(args) -> int:
    arrays = read_npz(args.file)
    src = str(args.file)
    if "kind" in arrays:
        data = measurement_from_arrays(arrays, src=src)
        info = {"file": src, **describe_measurement(data)}
        info["warnings"] = check_measurement(data, src=src)
    elif "A" in arrays:
        model = lti_model_from_arrays(arrays, src=src)
        info = {"file": src, **describe_model(model, arrays)}
        info["warnings"] = check_model(model, src=src)
    else:
        # load_any's refusal, with its one-line message
        from workbench.io.formats import load_any

        load_any(args.file)
        return 2  # not reached: load_any raised
    print(json.dumps(info, indent=2) if args.json else format_text(info))
    return 0
