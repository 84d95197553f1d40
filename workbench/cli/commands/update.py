"""``workbench update --fe FE.npz --data FRF.npz --out UPDATED_FE.npz``: FE model updating.

The measured FRF (spec 1b) goes through the modal fit (:func:`workbench.modal.fit.fit_modal`)
to frequencies, damping and rank-one residues; its channels are matched to the
FE file (spec 4) by name; :func:`workbench.fe.update.update_fe` pairs the modes
by MAC (a measured mode without an FE partner is reported unpaired) and updates
alpha by regularized Gauss-Newton. The output file is the input file with only
``alpha`` and ``damping`` changed: every matrix is written back exactly as read.
"""

from __future__ import annotations

import argparse
import json

from workbench.cli.commands import add_report_outputs
from workbench.core.atomic import check_not_input, check_output, save_npz, write_text
from workbench.core.errors import InputError
from workbench.io.formats import FrfData, load_measurement, read_npz
from workbench.signals.quality import check_measurement


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "update",
        help="update an FE model's parameters (spec 4) on a measured FRF",
        description=(
            "Fit the modes of the measured FRF, pair them with the FE model's modes by MAC "
            "(unmatched measured modes reported, not forced), update the parameters alpha by "
            "regularized Gauss-Newton on frequencies and residues, and write the FE file back "
            "with the updated alpha and the measured damping of the paired modes."
        ),
    )
    p.add_argument("--fe", required=True, metavar="FE", help="FE model .npz (spec 4)")
    p.add_argument("--data", required=True, metavar="FRF", help="measured FRF .npz (spec 1b)")
    p.add_argument("--out", required=True, metavar="UPDATED_FE", help="updated FE model .npz")
    add_report_outputs(p, json_help="write the update report (JSON) to OUT")
    p.add_argument("--modes", type=int, default=None, help="measured modes to fit (default auto)")
    p.add_argument("--band", type=float, nargs=2, metavar=("F1", "F2"), help="fit band, Hz")
    p.add_argument(
        "--prior-rel", type=float, default=0.5, help="prior relative std of each parameter"
    )
    return p


def run(args) -> int:
    from workbench.fe.model import fe_arrays, fe_from_arrays
    from workbench.fe.plots import plot_update
    from workbench.fe.update import MeasuredModes, update_fe
    from workbench.modal.fit import fit_modal

    check_not_input(args.out, [args.fe, args.data])
    if args.json:
        check_output(args.json, [args.fe, args.data], what="--json")
    if args.plots:
        check_output(args.plots, [args.fe, args.data], folder=True, what="--plots")
    raw = read_npz(args.fe)
    fe = fe_from_arrays(raw, src=str(args.fe))
    data = load_measurement(args.data)
    if not isinstance(data, FrfData):
        raise InputError(f"{args.data}: key 'kind': expected an FRF ('frf', spec 1b), got 'time'")
    check_measurement(data, src=str(args.data))
    fe.output_index(data.output_names, str(args.data))  # refuse unknown names before fitting
    fe.input_index(data.input_names, str(args.data))
    fit = fit_modal(
        data, n_modes=args.modes, band_hz=None if args.band is None else tuple(args.band)
    )
    # with the data's fs, unpaired modes are checked for being images of modes above Nyquist
    res = update_fe(fe, MeasuredModes.from_fit(fit), prior_rel=args.prior_rel, fs=data.fs)
    arrays = fe_arrays(fe, alpha=res.alpha, damping=res.damping, original=raw)
    fe_from_arrays(arrays, src=str(args.out))
    save_npz(args.out, **arrays)
    if args.json:
        report = res.report(fe.parameter_names)
        write_text(args.json, json.dumps(report, indent=1) + "\n")
    if args.plots:
        plot_update(args.plots, res)
    print(res.table_text(fe.parameter_names))
    return 0
