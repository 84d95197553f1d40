"""FE updating benchmark (issue 9): update accuracy, held-out prediction, eigen-solve time.

1. Synthetic beam: truth = the default beam on a 150-element mesh (modal damping
   of plants.beam), FRF of s1, s2, s5 with 1 % noise; the prior file (50
   elements) has E +8 % and flexures +30 % (plants.beam.beam_prior_config).
   modal fit -> update -> parameter errors; prediction at s3, s4 against their
   FRF up to the 9th mode, in units of the noise level.
2. The public example /work/shared/fe_examples/example_beam_update_frf (if present).
3. Eigen-solve of an 8000-DOF beam, 20 modes: workbench.fe.solve_modes against
   scipy eigsh (sparse LU shift-invert) in the same run, best of 5. (solve_modes'
   sparse path IS eigsh shift-invert: the issue's 30 ms target is not met; a
   block subspace iteration with a banded Cholesky was tried and dropped.)

Run: OMP_NUM_THREADS=1 python benchmarks/bench_fe.py
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from plants.beam import BeamConfig, _damping, beam_fe_file, beam_prior_config
from workbench.fe import (
    MeasuredModes,
    fe_arrays,
    fe_from_arrays,
    modal_terms,
    predict_frf,
    prediction_error,
    solve_modes,
    update_fe,
)
from workbench.io.formats import FrfData, load_measurement
from workbench.modal.fit import fit_modal

EXAMPLE = Path(__file__).resolve().parents[2] / "shared/fe_examples/example_beam_update_frf"


def _update(fe, data: FrfData, band):
    fit = fit_modal(data, band_hz=band)
    res = update_fe(fe, MeasuredModes.from_fit(fit))
    upd = fe_from_arrays(fe_arrays(fe, alpha=res.alpha, damping=res.damping))
    return res, upd


def _pred_error(fe, valid: FrfData, f_max):
    G = predict_frf(fe, valid.freq, outputs=valid.output_names, inputs=valid.input_names)
    pe = prediction_error(G, valid.output_names, valid, f_max_hz=f_max)
    return pe.mean, pe.noise_mean


def synthetic():
    cfg = dataclasses.replace(BeamConfig(), n_elements=150)
    truth = beam_fe_file(cfg)
    f_true = solve_modes(*truth.matrices(), truth.n_dof).freq_hz
    damping = _damping(cfg, f_true.copy(), 2)
    truth = fe_from_arrays(fe_arrays(truth, damping=damping))
    freq = np.arange(0.5, 1024.0, 0.5)
    G = modal_terms(truth).frf(freq)
    rng = np.random.default_rng(7)
    sigma = 0.01 * np.abs(G) + 1e-12
    noisy = G + sigma / np.sqrt(2) * (
        rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape)
    )
    names = ("F1", "F2", "F3")
    meas = FrfData(
        freq, noisy[:, [0, 1, 4]], sigma[:, [0, 1, 4]] ** 2, 2048.0, names, ("s1", "s2", "s5")
    )
    valid = FrfData(freq, noisy[:, [2, 3]], sigma[:, [2, 3]] ** 2, 2048.0, names, ("s3", "s4"))
    prior = beam_fe_file(beam_prior_config(), damping=0.01)
    t = time.perf_counter()
    res, upd = _update(prior, meas, (1.0, 1000.0))
    dt = time.perf_counter() - t
    print(
        f"1. synthetic beam (truth 150 elements, file 50, 1 % noise), modal fit + update {dt:.2f} s"
    )
    for name, a0, a, s, at in zip(
        prior.parameter_names, res.alpha_nominal, res.alpha, res.alpha_std, cfg.alpha, strict=True
    ):
        print(
            f"   {name:<26} prior {a0 / at - 1:+7.2%}  updated {a / at - 1:+8.4%}"
            f"  (std {s / a:.3%})"
        )
    f9 = res.freq_measured_hz[min(8, res.freq_measured_hz.size - 1)]
    e0, noise = _pred_error(prior, valid, f9)
    e1, _ = _pred_error(upd, valid, f9)
    print(
        f"   prediction s3, s4 up to {f9:.0f} Hz: prior {e0:.4f}, updated {e1:.4f}, noise "
        f"{noise:.4f} -> {e1 / noise:.2f} x noise; unpaired {res.unpaired}"
    )


def example():
    if not EXAMPLE.is_dir():
        print("2. public example not found, skipped")
        return
    from workbench.fe import read_fe

    ans = json.loads((EXAMPLE / "answer.json").read_text())
    fe = read_fe(EXAMPLE / "fe_model.npz")
    res, upd = _update(fe, load_measurement(EXAMPLE / "measurement.npz"), (1.0, 1000.0))
    at = np.array([ans["alpha_true"][n] for n in fe.parameter_names])
    print(
        "2. public example: parameter error after update "
        + ", ".join(
            f"{n} {a / t - 1:+.4%}"
            for n, a, t in zip(fe.parameter_names, res.alpha, at, strict=True)
        )
    )
    valid = load_measurement(EXAMPLE / "validation.npz")
    e0, _ = _pred_error(fe, valid, ans["f_lim_hz"])
    e1, _ = _pred_error(upd, valid, ans["f_lim_hz"])
    print(
        f"   prediction error (answer.json's measure): nominal {e0:.4f} "
        f"(answer {ans['nominal_prediction_error']:.4f}), "
        f"updated {e1:.4f}, noise floor {ans['noise_floor_prediction_error']:.4f}"
    )


def eigen():
    cfg = dataclasses.replace(BeamConfig(), n_elements=3999)
    fe = beam_fe_file(cfg)
    K, M = fe.matrices()
    Ks, Ms = scipy.sparse.csc_matrix(K), scipy.sparse.csc_matrix(M)
    t_wb, t_sp = [], []
    for _ in range(5):
        t = time.perf_counter()
        m = solve_modes(Ks, Ms, 20)
        t_wb.append(time.perf_counter() - t)
        t = time.perf_counter()
        lam = np.sort(scipy.sparse.linalg.eigsh(Ks, k=20, M=Ms, sigma=-1.0, which="LM")[0])
        t_sp.append(time.perf_counter() - t)
    print(
        f"3. eigen-solve {fe.n_dof} DOF, 20 modes: workbench {1e3 * min(t_wb):.1f} ms, scipy eigsh "
        f"{1e3 * min(t_sp):.1f} ms; max rel. eigenvalue difference "
        f"{np.max(np.abs(m.lam / lam - 1)):.1e}"
    )


if __name__ == "__main__":
    synthetic()
    example()
    eigen()
