"""``workbench design --model MODEL --method {pid-notch,modal-sf,hinf,youla} [--out K.npz]``.

Designs a controller on a model file and writes it as a spec-5 controller file
(e = r - y -> u, ``role = "controller"``, ``delay_samples`` = the loop delay the
design assumed). The loop's computation delay is the model file's own
``delay_s`` plus ``--loop-delay-samples N`` samples of the real-time system
(give N when the model was identified from the plant input u, which comes after
that delay, and so does not contain it). The per-DOF table printed is
:func:`workbench.loop.analyze_loop` of the model with the designed controller.

Bad input (a non-square model, an unstable design, an |S| bound no design
meets, a mode failing Lemma 1/2) is one line and exit 2; outputs are checked
before the work and written atomically, never half.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from workbench.cli.commands import check_model_quality
from workbench.core.atomic import check_output, write_text
from workbench.core.errors import InputError

METHODS = ("pid-notch", "modal-sf", "hinf", "youla")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "design",
        help="design a controller on a model file and write it (spec-5 controller file)",
        description=(
            "Design a decentralized PID + notch (pid-notch), a modal state feedback with "
            "observer (modal-sf), per-DOF mixed-sensitivity H-infinity controllers (hinf) or "
            "a convex Youla-parameter design around the pid-notch loops (youla; minutes on a "
            "6-DOF model) on MODEL for the highest crossover at |S| <= --ms-max, print "
            "the per-DOF loop table on the model and write the controller e = r - y -> u."
        ),
    )
    p.add_argument("--model", required=True, metavar="MODEL", help="model .npz (A, B, C, D, dt)")
    p.add_argument("--method", required=True, choices=METHODS, help="design method")
    p.add_argument(
        "--ms-max", type=float, default=2.0, help="bound on |S| per loop (ratio; 2.0 = 6 dB)"
    )
    add_loop_delay_argument(p)
    p.add_argument(
        "--fs", type=float, help="controller sampling frequency, Hz (default: 1/dt of MODEL)"
    )
    p.add_argument(
        "--frf",
        metavar="FRF.npz",
        help="youla only: the plant's measured FRF (spec 1b, from the same input as MODEL); "
        "the design then holds |S| on the measured loop, robust to what MODEL lacks",
    )
    p.add_argument("--out", metavar="K.npz", help="write the controller (spec-5 file)")
    p.add_argument("--json", metavar="REPORT.json", help="write the design report as JSON")
    return p


def add_loop_delay_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--loop-delay-samples",
        type=int,
        metavar="N",
        help="computation delay of the real-time system in the loop, samples",
    )


def check_outputs(outputs, inputs) -> None:
    """Refuse, before any work, an output over an input or one that cannot be written."""
    for out in outputs:
        if out:
            check_output(out, inputs)


def _sample_rate(model, fs) -> float:
    if model.is_discrete:
        own = 1.0 / model.dt
        if fs is not None and abs(fs - own) > 1e-9 * own:
            raise InputError(
                f"--fs: expected the discrete model's rate {own:g} Hz (or no --fs), got {fs:g}"
            )
        return own
    if fs is None:
        raise InputError("--fs: expected the controller sampling frequency for a continuous model")
    if not np.isfinite(fs) or fs <= 0:
        raise InputError(f"--fs: expected a sampling frequency > 0 Hz, got {fs:g}")
    return float(fs)


def run(args) -> int:
    from workbench.io.formats import read_model, save_controller
    from workbench.loop import analyze_loop

    check_outputs((args.out, args.json), [args.model] + ([args.frf] if args.frf else []))
    if args.frf and args.method != "youla":
        raise InputError(f"--frf: used by --method youla only, got --method {args.method}")
    ms_max = float(args.ms_max)
    if not np.isfinite(ms_max) or ms_max <= 1.0:
        raise InputError(f"--ms-max: expected a bound > 1 on |S|, got {args.ms_max}")
    m = 0 if args.loop_delay_samples is None else int(args.loop_delay_samples)
    if m < 0:
        raise InputError(f"--loop-delay-samples: expected an integer >= 0, got {m}")
    model = read_model(args.model)
    if model.n_u != model.n_y or model.n_u == 0:
        raise InputError(
            f"{args.model}: expected a square model (one actuator per measured output), got "
            f"{model.n_u} inputs and {model.n_y} outputs"
        )
    check_model_quality(model, args.model)
    fs = _sample_rate(model, args.fs)
    settings: dict = {}
    if args.method == "pid-notch":
        from controllers.pid_notch import tune_pid_notch

        K, _report = tune_pid_notch(model, fs, ms_max=ms_max, loop_delay_samples=m)
        controller = K.controller
    elif args.method == "hinf":
        from controllers.hinf import tune_hinf

        design = tune_hinf(model, ms_max=ms_max, loop_delay_samples=m, fs=fs)
        controller = design.controller
        settings = {"target_hz": list(design.target_hz), "gamma": list(design.gamma)}
    elif args.method == "youla":
        from controllers.youla import tune_youla

        measured = None
        if args.frf:
            from workbench.io.formats import load_measurement

            measured = load_measurement(args.frf)
            if measured.kind != "frf":
                raise InputError(f"{args.frf}: expected an FRF measurement, got {measured.kind}")
        design = tune_youla(model, ms_max=ms_max, loop_delay_samples=m, fs=fs, measured=measured)
        controller = design.controller
        settings = {"template_hz": list(design.report.template_hz),
                    "programs": design.report.solves, "measured": args.frf,
                    "orders": list(design.report.orders)}  # fmt: skip
    else:
        from controllers.modal_sf import tune_modal_sf

        design = tune_modal_sf(model, ms_max=ms_max, loop_delay_samples=m, fs=fs)
        controller = design.controller
        settings = dict(design.report.settings)
    analysis = analyze_loop(model, controller, loop_delay_samples=m)
    if not analysis.stable:
        raise InputError(
            f"{args.method}: the designed loop is unstable on the model (largest closed-loop "
            f"pole radius {analysis.max_pole_radius:.4f})"
        )
    worst = max(analysis.loops, key=lambda lp: lp.s_peak)
    if worst.s_peak > ms_max * (1 + 1e-6):
        raise InputError(
            f"{args.method}: |S| bound {ms_max:g} not met on the model: loop {worst.name} "
            f"has |S|inf = {worst.s_peak:.4g}"
        )
    print(
        f"design {args.method} on {args.model}: fs = {fs:g} Hz, loop delay {m} samples"
        + (f" + model delay {model.delay_s:g} s" if model.delay_s else "")
        + (f", {controller.n_x} controller states" if hasattr(controller, "n_x") else "")
    )
    print(analysis.table())
    if args.out:
        save_controller(args.out, controller, delay_samples=m)
        print(f"controller: {args.out}")
    if args.json:
        report = {
            "method": args.method,
            "model": str(args.model),
            "ms_max": ms_max,
            "settings": settings,
            "controller": args.out,
            "analysis": analysis.summary(),
        }
        write_text(args.json, json.dumps(report, indent=2) + "\n")
    return 0
