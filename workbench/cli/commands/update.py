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

import numpy as np

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


def report_dict(fe, res) -> dict:
    """The update report: parameters before/after +- std, frequencies, MAC, unpaired modes."""
    return {
        "parameters": [
            {
                "name": name,
                "before": float(a0),
                "after": float(a1),
                "std": float(s),
                "change_rel": float(a1 / a0 - 1),
            }
            for name, a0, a1, s in zip(
                fe.parameter_names, res.alpha_nominal, res.alpha, res.alpha_std, strict=True
            )
        ],
        "modes": [
            {
                "measured_index": i,
                "fe_index": k,
                "freq_measured_hz": float(res.freq_measured_hz[i]),
                "freq_before_hz": float(res.freq_before_hz[k]),
                "freq_after_hz": float(res.freq_after_hz[k]),
                "mac": float(res.mac[i, k]),
                "damping": float(res.damping[k]),
            }
            for i, k in res.pairs
        ],
        "unpaired_measured": [
            {"measured_index": i, "freq_hz": float(res.freq_measured_hz[i])} for i in res.unpaired
        ],
        "mac": res.mac.tolist(),
        "cost": res.cost,
        "iterations": res.n_iter,
        "notes": list(res.notes),
    }


def run(args) -> int:
    from workbench.fe.model import fe_arrays, fe_from_arrays
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
    # rank-one residues c_k b_k^T: the scale split between c_k and b_k drops out
    residues = fit.c[:, :, None] * fit.b[:, None, :]
    meas = MeasuredModes(
        fit.freq_hz,
        fit.damping,
        residues,
        data.output_names,
        data.input_names,
        freq_std_hz=fit.freq_std_hz,
        residue_std=fit.c_std[:, :, None] * np.abs(fit.b[:, None, :]),
    )
    res = update_fe(fe, meas, prior_rel=args.prior_rel)
    arrays = fe_arrays(fe, alpha=res.alpha, damping=res.damping, original=raw)
    fe_from_arrays(arrays, src=str(args.out))
    save_npz(args.out, **arrays)
    report = report_dict(fe, res)
    if args.json:
        write_text(args.json, json.dumps(report, indent=1) + "\n")
    if args.plots:
        _plots(args.plots, res)
    print(f"{'parameter':<28}{'before':>14}{'after':>14}{'std':>12}")
    for p in report["parameters"]:
        print(f"{p['name']:<28}{p['before']:>14.6g}{p['after']:>14.6g}{p['std']:>12.3g}")
    print(f"{'mode':>4}{'measured Hz':>14}{'before Hz':>12}{'after Hz':>12}{'MAC':>7}")
    for m in report["modes"]:
        print(
            f"{m['fe_index']:>4}{m['freq_measured_hz']:>14.3f}{m['freq_before_hz']:>12.3f}"
            f"{m['freq_after_hz']:>12.3f}{m['mac']:>7.3f}"
        )
    for u in report["unpaired_measured"]:
        print(f"unpaired measured mode at {u['freq_hz']:.2f} Hz (no FE partner)")
    return 0


def _plots(folder, res) -> None:
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from workbench.core.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(6, 4.5))
    im = ax.imshow(res.mac, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xlabel("FE mode")
    ax.set_ylabel("measured mode")
    ax.set_title("MAC of residues after the update")
    fig.colorbar(im, ax=ax)
    with atomic_path(Path(folder) / "update_mac.png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    im_, kf = [i for i, _ in res.pairs], [k for _, k in res.pairs]
    fm = res.freq_measured_hz[im_]
    ax.semilogx(fm, 100 * (res.freq_before_hz[kf] / fm - 1), "o-", label="before")
    ax.semilogx(fm, 100 * (res.freq_after_hz[kf] / fm - 1), "s-", label="after")
    ax.set_xlabel("measured frequency (Hz)")
    ax.set_ylabel("FE - measured (%)")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    with atomic_path(Path(folder) / "update_frequencies.png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
