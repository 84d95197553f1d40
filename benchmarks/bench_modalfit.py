"""Modal fit benchmark (issue 9): accuracy and time against sdypy-EMA on the same FRF.

The beam (plants.beam truth, 100-element FE mesh, modal damping of the plant), its
5 x 3 receptance FRF at 1..1000 Hz (0.5 Hz lines) from every FE mode, 1 % complex
noise per element (G_var given), several seeds:

* ours: ``workbench.modal.fit.fit_modal`` (p-LSCF stabilization diagram, automatic
  pole selection, G_var-weighted rank-one LM fit with residual terms);
* sdypy-EMA (LSCF poles + LSFD constants), called as its documentation does:
  ``Model(frf, freq, lower, upper, pol_order_high, frf_form='receptance')``,
  ``get_poles()``, ``select_closest_poles(approx_nat_freq)``, ``get_constants()``.
  Its automatic selection needs the approximate frequencies: it is GIVEN the true
  ones (an advantage ours does not get). sdypy-EMA is not a project dependency:
  ``pip install sdypy-EMA`` to include it; without it only ours is run.

Printed: max frequency error (%), max damping error (%) over the 9 modes below
1 kHz, wall and CPU time (``time.process_time``; best of 5 interleaved rounds on
seed 0: on a shared, loaded machine the wall clock varies by 2-4x, the CPU clock
far less), and the ratios sdypy / ours.

Run: OMP_NUM_THREADS=1 python benchmarks/bench_modalfit.py
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from threadpoolctl import threadpool_limits

from plants.beam import BeamConfig, beam_fe_file
from workbench.fe import modal_terms, read_fe, save_fe
from workbench.io.formats import FrfData
from workbench.modal.fit import fit_modal

SEEDS = range(5)


def beam_frf():
    """Noise-free FRF of every FE mode, the truth's frequencies and damping (< 1 kHz)."""
    import tempfile
    from pathlib import Path

    cfg = dataclasses.replace(BeamConfig(), n_elements=100)
    fe = beam_fe_file(cfg)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "truth.npz"
        save_fe(path, fe, damping=np.linspace(0.006, 0.012, fe.n_dof))
        fe = read_fe(path)
    terms = modal_terms(fe, n_modes=fe.n_dof)
    freq = np.arange(1.0, 1000.0, 0.5)
    keep = terms.freq_hz < 1000.0
    return freq, terms.frf(freq), terms.freq_hz[keep], terms.damping[keep], fe


def noisy(G, seed):
    rng = np.random.default_rng(seed)
    sig = 0.01 * np.abs(G) + 1e-15
    return G + sig / np.sqrt(2) * (
        rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape)
    ), sig**2


def errors(f_est, z_est, f_true, z_true, above_hz=0.0):
    """Max relative errors (%) pairing each true mode with the nearest estimate: all
    modes, then the modes above ``above_hz``; modes found (within 1 %); extra modes."""
    f_est, z_est = np.asarray(f_est), np.asarray(z_est)
    if f_est.size == 0:
        return np.inf, np.inf, np.inf, np.inf, 0, 0
    k = np.argmin(np.abs(f_est[None, :] - f_true[:, None]), axis=1)
    ef = np.abs(f_est[k] / f_true - 1) * 100
    ez = np.abs(z_est[k] / z_true - 1) * 100
    hi = f_true > above_hz
    found = int(np.sum(ef < 1.0))
    extra = int(np.sum(np.min(np.abs(f_est[:, None] / f_true[None, :] - 1), axis=1) > 0.01))
    return np.max(ef), np.max(ez), np.max(ef[hi]), np.max(ez[hi]), found, extra


def ours(freq, G, var, fe):
    fit = fit_modal(FrfData(freq, G, var, 2048.0, fe.input_names, fe.output_names))
    return fit.freq_hz, fit.damping


def run_sdypy(freq, G, f_true, lower=None):
    import contextlib
    import io

    from sdypy import EMA

    # sdypy-EMA takes FRFs as (n_locations, n_freq); MIMO columns stacked
    frf = G.reshape(G.shape[0], -1).T
    with contextlib.redirect_stdout(io.StringIO()):
        m = EMA.Model(
            frf=frf,
            freq=freq,
            lower=float(freq[0]) if lower is None else lower,
            upper=float(freq[-1]),
            pol_order_high=60,
            frf_form="receptance",
        )
        m.get_poles(show_progress=False)
        approx = [f for f in f_true if lower is None or f > lower]
        m.select_closest_poles(approx, f_window=5)
        m.get_constants(whose_poles="own")
    return np.asarray(m.nat_freq), np.asarray(m.nat_xi)


def best_time(fn, n=3):
    """Best wall and best CPU time (s) of n calls, and the last output."""
    wall = cpu = np.inf
    for _ in range(n):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        wall = min(wall, time.perf_counter() - t)
        cpu = min(cpu, time.process_time() - c)
    return (wall, cpu), out


def main():
    try:
        import sdypy.EMA  # noqa: F401

        have_sdypy = True
    except ImportError:
        have_sdypy = False
        print("sdypy-EMA not installed (pip install sdypy-EMA): ours only")
    freq, G0, f_true, z_true, fe = beam_frf()
    print(
        f"beam, 5 x 3 FRF, {freq.size} lines 1..1000 Hz, 1 % noise, {f_true.size} modes "
        f"({f_true[0]:.2f} .. {f_true[-1]:.1f} Hz), seeds {list(SEEDS)}; 1 BLAS thread"
    )
    rows = {"ours": [], "sdypy-EMA": [], "sdypy >10Hz": []}
    with threadpool_limits(1):
        for seed in SEEDS:
            G, var = noisy(G0, seed)
            rows["ours"].append(errors(*ours(freq, G, var, fe), f_true, z_true, 10.0))
            if have_sdypy:
                est = run_sdypy(freq, G, f_true)
                rows["sdypy-EMA"].append(errors(*est, f_true, z_true, 10.0))
                # its single-band LSCF cannot resolve the 2.6 / 3.2 Hz suspension modes
                # against a 1 kHz band: the band above them as a second try
                hi = f_true > 10.0
                est = run_sdypy(freq, G, f_true, lower=10.0)
                rows["sdypy >10Hz"].append(errors(*est, f_true[hi], z_true[hi], 10.0))
        G, var = noisy(G0, 0)
        # interleaved rounds, best of each: a load spike on this shared machine hits both
        t_ours = t_sdypy = (np.inf, np.inf)
        for _ in range(5):
            t = best_time(lambda: ours(freq, G, var, fe), n=1)[0]
            t_ours = tuple(map(min, t_ours, t))
            if have_sdypy:
                t = best_time(lambda: run_sdypy(freq, G, f_true), n=1)[0]
                t_sdypy = tuple(map(min, t_sdypy, t))
        if not have_sdypy:
            t_sdypy = (np.nan, np.nan)
    print("errors: max over seeds of the max over modes; '>10 Hz': the modes above 10 Hz")
    head = ("method", "freq err %", "damp err %", ">10Hz freq %", ">10Hz damp %", "found", "extra")
    print(" ".join(f"{h:>12}" for h in head) + "   wall s    CPU s")
    for name, t in (("ours", t_ours), ("sdypy-EMA", t_sdypy), ("sdypy >10Hz", (np.nan, np.nan))):
        if not rows[name]:
            continue
        r = np.array(rows[name], float)
        n = f_true.size if name != "sdypy >10Hz" else int(np.sum(f_true > 10))
        print(
            f"{name:>12} {np.max(r[:, 0]):12.4f} {np.max(r[:, 1]):12.3f} {np.max(r[:, 2]):12.4f} "
            f"{np.max(r[:, 3]):12.3f} {int(np.min(r[:, 4])):>10d}/{n} {int(np.max(r[:, 5])):12d}"
            f" {t[0]:8.2f} {t[1]:8.2f}"
        )
    if have_sdypy:
        a, b = np.array(rows["ours"]), np.array(rows["sdypy >10Hz"])
        print(
            f"ratios sdypy-EMA / ours: wall time {t_sdypy[0] / t_ours[0]:.2f}x, CPU time "
            f"{t_sdypy[1] / t_ours[1]:.2f}x; on the modes > 10 Hz "
            f"(sdypy on that band): max freq error {np.max(b[:, 2]) / np.max(a[:, 2]):.1f}x, "
            f"max damping error {np.max(b[:, 3]) / np.max(a[:, 3]):.1f}x"
        )
    ok = np.array(rows["ours"])
    met = np.max(ok[:, 0]) < 0.05 and np.max(ok[:, 1]) < 5 and np.min(ok[:, 4]) == f_true.size
    print(f"targets (freq < 0.05 %, damping < 5 %, all modes): {'met' if met else 'NOT met'}")
    if have_sdypy:
        b = np.array(rows["sdypy-EMA"])
        faster = t_ours[1] < t_sdypy[1]
        better = np.max(ok[:, 0]) < np.max(b[:, 0]) and np.max(ok[:, 1]) < np.max(b[:, 1])
        print(
            f"against sdypy-EMA (faster in CPU time, more accurate on the same FRF): "
            f"{'met' if faster and better else 'NOT met'}"
        )


if __name__ == "__main__":
    main()
