"""``workbench predict --fe FE.npz --data FRF.npz [--outputs s3,s4] --out PRED.npz``.

The FE model's (spec 4) response at any of its sensors, on the data's frequency
grid and for the data's inputs, as a spec-1b FRF file; with measured data for
those outputs, the prediction error (mean over lines of
``||G_pred - G_meas||_F / ||G_meas||_F``) is printed.
"""

from __future__ import annotations

import argparse

import numpy as np

from workbench.core.atomic import check_not_input, save_npz
from workbench.core.errors import InputError
from workbench.io.formats import FrfData, load_measurement
from workbench.signals.quality import check_measurement


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "predict",
        help="predict the FRF of an FE model (spec 4) at any of its sensors",
        description=(
            "Modal sum of the FE model (plus residual compliance of the modes without a "
            "damping) at the chosen outputs, on the data's frequency grid and inputs; the error "
            "against the data where the data has those outputs."
        ),
    )
    p.add_argument("--fe", required=True, metavar="FE", help="FE model .npz (spec 4)")
    p.add_argument("--data", required=True, metavar="FRF", help="FRF .npz giving grid and inputs")
    p.add_argument("--outputs", default=None, help="comma-separated output names (default all)")
    p.add_argument("--out", required=True, metavar="PRED", help="predicted FRF .npz (spec 1b)")
    p.add_argument(
        "--sampled",
        action="store_true",
        help=(
            "predict what a sampled experiment at the data's fs measures (ZOH, modes above "
            "Nyquist aliased, ZOH divided out): for data taken without an anti-aliasing filter"
        ),
    )
    return p


def run(args) -> int:
    from workbench.fe.model import read_fe
    from workbench.fe.predict import predict_frf, prediction_error

    check_not_input(args.out, [args.fe, args.data])
    fe = read_fe(args.fe)
    data = load_measurement(args.data)
    if not isinstance(data, FrfData):
        raise InputError(f"{args.data}: key 'kind': expected an FRF ('frf', spec 1b), got 'time'")
    check_measurement(data, src=str(args.data))
    outputs = (
        fe.output_names
        if args.outputs is None
        else tuple(s.strip() for s in args.outputs.split(",") if s.strip())
    )
    if not outputs:
        raise InputError(f"--outputs: expected names such as s3,s4, got {args.outputs!r}")
    fe.output_index(outputs, "--outputs")
    fe.input_index(data.input_names, str(args.data))
    if args.sampled and data.fs is None:
        raise InputError(f"{args.data}: key 'fs': --sampled needs the sampling frequency, got none")
    G = predict_frf(
        fe,
        data.freq,
        outputs=outputs,
        inputs=data.input_names,
        fs=data.fs if args.sampled else None,
    )
    arrays = {
        "kind": np.array("frf"),
        "freq": data.freq,
        "G": G,
        "input_names": np.array(data.input_names),
        "output_names": np.array(outputs),
    }
    if data.fs is not None:
        arrays["fs"] = np.array(data.fs)
    save_npz(args.out, **arrays)
    pe = prediction_error(G, outputs, data)
    if pe is not None:
        print(
            f"prediction error ({', '.join(pe.outputs)}): mean {pe.mean:.4g}, "
            f"median {pe.median:.4g} (||G_pred - G||_F / ||G||_F per line)"
        )
        if data.G_var is not None:
            print(f"noise level of the data: mean {pe.noise_mean:.4g} (same measure)")
    print(f"wrote {args.out}: outputs {', '.join(outputs)}, inputs {', '.join(data.input_names)}")
    return 0
