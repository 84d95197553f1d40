"""``workbench frf DATA --out FRF.npz``: nonparametric FRF from a time record.

Periodic (multisine) records use the multisine estimator, others the Welch
H1 estimator (``--method auto``); with ``r`` recorded the estimate goes
through it (the closed-loop indirect estimate). The FRF is written in the
spec's frf format with ``G_var``, the zero-order hold compensated
(:mod:`workbench.signals.frf`).
"""

from __future__ import annotations

import argparse

import numpy as np

from workbench.core.atomic import check_not_input
from workbench.core.errors import InputError
from workbench.io.formats import TimeData, load_measurement, save_measurement
from workbench.signals.quality import check_measurement


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "frf",
        help="estimate the FRF (with its variance) from a time-domain measurement",
        description=(
            "Estimate the frequency response from a time record (spec 1a): per excited line "
            "from a periodic multisine record, or Welch H1 for noise; through the excitation "
            "r when it is recorded (closed loop). Writes spec 1b (freq, G, G_var, fs), zero-"
            "order hold compensated."
        ),
    )
    p.add_argument("data", metavar="DATA", help="time-domain measurement .npz")
    p.add_argument("--out", required=True, help="output FRF .npz")
    p.add_argument("--method", choices=("auto", "multisine", "h1"), default="auto")
    p.add_argument(
        "--reference",
        choices=("auto", "r", "u"),
        default="auto",
        help="signal the estimate goes through (auto: r when recorded)",
    )
    p.add_argument("--transient", type=int, default=1, help="periods dropped per block")
    p.add_argument("--nperseg", type=int, default=None, help="H1 segment length, samples")
    p.add_argument("--overlap", type=float, default=0.5, help="H1 segment overlap, share")
    p.add_argument("--no-zoh", action="store_true", help="keep the discrete-time FRF")
    return p


def run(args) -> int:
    from workbench.signals.frf import estimate_frf

    check_not_input(args.out, [args.data])
    data = load_measurement(args.data)
    if not isinstance(data, TimeData):
        raise InputError(f"{args.data}: key 'kind': expected a time record ('time'), got 'frf'")
    check_measurement(data, src=str(args.data))  # load_checked's checks, after the kind test
    est = estimate_frf(
        data,
        method=args.method,
        zoh="none" if args.no_zoh else "compensate",
        reference=args.reference,
        n_transient=args.transient,
        nperseg=args.nperseg,
        overlap=args.overlap,
    )
    save_measurement(args.out, est.frf)
    f = est.frf.freq
    extra = ""
    if est.lines is not None:
        odd, even = est.lines.excess_db(1), est.lines.excess_db(2)
        extra = (
            f"; left-out lines over noise: odd {np.nanmax(odd):.1f} dB, "
            f"even {np.nanmax(even):.1f} dB (max over outputs)"
        )
    print(
        f"wrote {args.out}: {est.method} estimate through {est.reference}, {f.size} lines "
        f"{f[0]:g}..{f[-1]:g} Hz, {est.n_blocks} blocks x {est.n_averages} averages{extra}"
    )
    return 0
