"""Monte Carlo of ``identify --refine`` on closed-loop records: is the reported std honest?

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_refine_mc.py [--realizations 30]``

Records of the 6x6 wafer stage (10,000 samples at 5 kHz, period 2000, flat
random-phase multisine r at the plant input, 5 .. 1500 Hz, lead-lag PID at
100 Hz) from the independent generator ``tests/refgen_closed_loop.py``, with
the one-sample computation delay placed

- ``loop``: between the controller and the plant (``u -> y`` has 1 sample delay),
- ``controller``: inside the controller (``u -> y`` has none),

and, for reference, ``experiments``: the project's own
:func:`workbench.experiments.wafer_stage_closed_loop_record`. Each record goes
through what ``workbench identify --method cl-moesp --order 16 --modal --refine``
does (cl-moesp with the periodic projection, 20 block rows, the known delay,
:meth:`ModalModel.from_statespace`, :func:`refine_modal_model`). Per flexible
mode (913.8 / 1032 Hz) and parameter the table gives the mean error, the
empirical std over the realizations, the mean reported std, their ratio, the
share of realizations with ``|error| < 2 reported std`` (95 % for an honest
Gaussian std), the rms Cramer-Rao bound (:func:`modal_crb` at the true modes,
each realization's noise-free input, the plant's sensor noise) and the mean
weighted misfit (1 = noise level).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from refgen_closed_loop import closed_loop_record  # noqa: E402

TRUE_HZ = (913.8, 1032.0)
TRUE_ZETA = (0.0091, 0.0095)


def sensor_noise_cov(plant) -> np.ndarray:
    """Per-sample output noise covariance (n_y, n_y), m^2: raw white noise + q^2/12, decoupled."""
    var = plant.measurement_noise_std**2 + plant.measurement_quantization**2 / 12
    return (plant.decouple * var) @ plant.decouple.T


def make(plant, arrangement: str, seed: int, *, period: int, noise_free: bool = False):
    """(TimeData, input delay in samples) of one realization (10,000 samples)."""
    if arrangement == "experiments":
        from workbench.experiments import wafer_stage_closed_loop_record

        p = plant.with_effects(noise_std=0.0, quantization=0.0) if noise_free else plant
        return wafer_stage_closed_loop_record(p, rng=seed, period=period), 1
    rec = closed_loop_record(
        plant,
        np.random.default_rng(seed),
        arrangement=arrangement,
        period=period,
        noise_free=noise_free,
    )
    return rec.data, rec.input_delay


def one(plant, arrangement: str, seed: int, true, noise_cov, *, period: int) -> dict:
    """Errors, reported stds and bound of the flexible modes for one realization."""
    from workbench.ident import identify_subspace
    from workbench.ident.refine import modal_crb, periodic_spectra, refine_modal_model
    from workbench.modal.model import ModalModel

    data, delay = make(plant, arrangement, seed, period=period)
    res = identify_subspace(data, method="cl-moesp", order=16, block_rows=20, input_delay=delay)
    ref = refine_modal_model(ModalModel.from_statespace(res.model), data, input_delay=delay)
    quiet, _ = make(plant, arrangement, seed, period=period, noise_free=True)
    crb = modal_crb(true, periodic_spectra(quiet), noise_cov=noise_cov, input_delay=delay)
    kt = [k for k, m in enumerate(true.modes) if m.kind == "flexible"]
    flex = [k for k, m in enumerate(ref.model.modes) if m.kind == "flexible"]
    fr = np.array([ref.model.modes[k].freq_hz for k in flex])
    out = {"err": [], "std": [], "crb": [], "misfit": ref.misfit}
    for j, (f0, z0) in enumerate(zip(TRUE_HZ, TRUE_ZETA)):
        k = flex[int(np.argmin(np.abs(fr - f0)))]
        m = ref.model.modes[k]
        out["err"].append([m.freq_hz - f0, m.damping - z0])
        out["std"].append([ref.freq_std_hz[k], ref.damping_std[k]])
        out["crb"].append([crb.freq_std_hz[kt[j]], crb.damping_std[kt[j]]])
    return out


def table(rows: dict) -> None:
    print(
        f"{'arrangement':>12s} {'mode':>9s} {'param':>6s} {'mean err':>10s} {'emp std':>9s} "
        f"{'rep std':>9s} {'emp/rep':>8s} {'<2 rep':>7s} {'rms CRB':>9s} {'emp/CRB':>8s} "
        f"{'misfit':>7s}"
    )
    for arr, rs in rows.items():
        err = np.array([r["err"] for r in rs])  # (n, mode, param)
        std = np.array([r["std"] for r in rs])
        crb = np.array([r["crb"] for r in rs])
        mis = np.mean([r["misfit"] for r in rs])
        for j, f0 in enumerate(TRUE_HZ):
            for p, (name, scale, unit) in enumerate((("freq", 1.0, "Hz"), ("zeta", 1e4, "e-4"))):
                e, s = scale * err[:, j, p], scale * std[:, j, p]
                c = scale * np.sqrt(np.mean(crb[:, j, p] ** 2))
                emp = e.std(ddof=1)
                print(
                    f"{arr:>12s} {f0:7.1f}Hz {name:>6s} {e.mean():+10.4f} {emp:9.4f} "
                    f"{s.mean():9.4f} {emp / s.mean():8.2f} {np.mean(np.abs(e) < 2 * s):7.0%} "
                    f"{c:9.4f} {emp / c:8.2f} {mis:7.3f}   [{unit}]"
                )
    print(
        "(emp std: over the realizations, ddof 1, itself uncertain by ~1/sqrt(2 (n - 1)); "
        "rep std: mean of the reported std; <2 rep: share with |error| < 2 reported std, "
        "95 % for an honest std; zeta in units of 1e-4)"
    )


def main() -> None:
    import plants

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realizations", type=int, default=30)
    p.add_argument("--arrangements", default="loop,controller,experiments")
    p.add_argument("--seed0", type=int, default=0)
    p.add_argument(
        "--period",
        type=int,
        default=2000,
        help="samples per period (divides 10,000; 2500 leaves 3 steady periods)",
    )
    args = p.parse_args()
    plant = plants.get_plant("wafer_stage")
    true = plant.modes.to_modal()  # the plant's own modes (truth side only)
    noise_cov = sensor_noise_cov(plant)
    rows = {}
    t0 = time.perf_counter()
    for arr in args.arrangements.split(","):
        rows[arr] = [
            one(plant, arr, args.seed0 + s, true, noise_cov, period=args.period)
            for s in range(args.realizations)
        ]
    print(
        f"== identify --refine Monte Carlo: {args.realizations} realizations per arrangement, "
        f"period {args.period} ({10_000 // args.period} periods, the first dropped), "
        f"{time.perf_counter() - t0:.0f} s =="
    )
    table(rows)


if __name__ == "__main__":
    main()
