"""``workbench modalfit FRF.npz --out MODAL.npz``: modal parameters of a MIMO FRF.

p-LSCF stabilization diagram -> automatic pole selection -> noise-weighted
Levenberg-Marquardt fit of every element at once (rank-one residues, residual
compliance, upper residual, optional rigid term) -> a spec-2 model file (the
continuous modal state space) with the modal data beside it (``modal_*`` keys,
:meth:`workbench.modal.fit.ModalFit.arrays`). With ``--collocated S:A`` the
modes are scaled to mass-normalized shapes at every sensor and actuator
(Theorem 2, :mod:`workbench.modal.scaling`): the model's b, c are then the
shapes, stored also as ``modal_phi_sensors`` / ``modal_phi_actuators``.
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from workbench.core.atomic import check_not_input, check_output
from workbench.core.errors import InputError
from workbench.io.formats import FrfData, load_measurement, save_model
from workbench.signals.quality import check_measurement


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "modalfit",
        help="modal parameters (frequency, damping +- std, mode shapes) of a MIMO FRF",
        description=(
            "Modal parameter estimation from an FRF (spec 1b): p-LSCF stabilization diagram, "
            "automatic selection of stable poles, then a G_var-weighted Levenberg-Marquardt fit "
            "of all elements with rank-one residues c_k b_k^T, residual compliance and an upper "
            "residual. Writes a spec-2 model file with the mode table (modal_* keys)."
        ),
    )
    p.add_argument("frf", metavar="FRF", help="FRF measurement .npz (spec 1b)")
    p.add_argument("--out", required=True, metavar="MODAL", help="output model .npz (spec 2)")
    sel = p.add_mutually_exclusive_group()
    sel.add_argument("--modes", type=int, metavar="N", help="number of modes to fit")
    sel.add_argument("--band", type=float, nargs=2, metavar=("F1", "F2"), help="fit band, Hz")
    p.add_argument("--max-order", type=int, default=30, help="highest p-LSCF order")
    p.add_argument(
        "--rigid",
        action="store_true",
        help="add a rigid / lower residual L/s^2 (default: when --band cuts lower lines)",
    )
    p.add_argument("--no-upper", action="store_true", help="no upper residual pseudo-mode")
    p.add_argument(
        "--collocated",
        metavar="SENSOR:ACTUATOR",
        help="collocated pair: scale to mass-normalized shapes (e.g. s1:F1)",
    )
    p.add_argument("--json", action="store_true", help="print the mode table as JSON")
    p.add_argument("--plots", metavar="DIR", help="stabilization diagram and fit overlay PNGs")
    return p


def run(args) -> int:
    from workbench.modal.fit import fit_modal, plot_fit_overlay, plot_stabilization
    from workbench.modal.scaling import channel_index, scale_modes

    check_not_input(args.out, [args.frf])
    if args.plots:
        check_output(args.plots, [args.frf], folder=True, what="--plots")
    data = load_measurement(args.frf)
    if not isinstance(data, FrfData):
        raise InputError(f"{args.frf}: key 'kind': expected an FRF ('frf'), got 'time'")
    check_measurement(data, src=str(args.frf))
    pair = None
    if args.collocated is not None:
        pair = args.collocated.split(":")
        if len(pair) != 2 or not all(pair):
            raise InputError(
                f"--collocated: expected SENSOR:ACTUATOR (e.g. s1:F1), got {args.collocated!r}"
            )
    if pair is not None:  # names checked before the fit, not after a minute of work
        channel_index(data.output_names, pair[0], "collocated sensor")
        channel_index(data.input_names, pair[1], "collocated actuator")
    result = fit_modal(
        data,
        n_modes=args.modes,
        band_hz=None if args.band is None else tuple(args.band),
        max_order=args.max_order,
        rigid=True if args.rigid else None,
        upper=not args.no_upper,
    )
    model = result.model
    extra = result.arrays()
    summary = result.summary()
    if pair is not None:
        ext = scale_modes(model, sensor=pair[0], actuator=pair[1])
        model = ext.model
        extra["modal_phi_sensors"] = np.asarray(ext.phi_sensors)
        extra["modal_phi_actuators"] = np.asarray(ext.phi_actuators)
        extra["modal_collocated"] = np.array([ext.sensor, ext.actuator])
        summary["collocated"] = [ext.sensor, ext.actuator]
        summary["phi_sensors"] = ext.phi_sensors.tolist()
        summary["phi_actuators"] = ext.phi_actuators.tolist()
    save_model(args.out, model.to_statespace(), **extra)
    if args.plots:
        os.makedirs(args.plots, exist_ok=True)
        plot_stabilization(result, os.path.join(args.plots, "stabilization.png"))
        plot_fit_overlay(result, data, os.path.join(args.plots, "fit_overlay.png"))
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(result.table_text())
        print(
            f"wrote {args.out}: {result.n_modes} modes, FRF error {result.error:.3g}, "
            f"sigma2 {result.result.sigma2:.3g} ({result.status})"
        )
    return 0
