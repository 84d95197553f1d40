"""Benchmark: closed-loop simulation of the 6-DOF wafer stage with the decentralized PID.

10 s at 5 kHz (50,000 samples), excitation at the plant input as in the
experiments, BLAS threads limited to 1. Printed (best of ``--repeat``):

- ``sim.closed_loop`` on the stage as configured (0.15 nm quantization: a
  nonlinear plant, so the loop is stepped sample by sample, in the compiled
  kernel of ``workbench.compiled``; benchmarks/bench_closed_loop.py compares it
  with the Python step loop);
- ``sim.closed_loop`` on the same stage without quantization (linear path: one
  discrete LTI system driven by [r, d, v]), with where its time goes;
- ``control.forced_response`` and ``scipy.signal.dlsim`` on that same discrete
  closed loop (same matrices, same input): the peers of the linear path;
- the real-time factor (10 s / wall time) of each.

Run: ``python benchmarks/bench_sim.py [--repeat 3] [--residual-max-hz 20000]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import control
import numpy as np
import scipy.signal
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import plants  # noqa: E402
from workbench import sim  # noqa: E402
from workbench.experiments import default_controller, effective_mass  # noqa: E402

FS = 5000.0  # Hz, the wafer stage's sampling rate
DURATION_S = 10.0


def best(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument(
        "--residual-max-hz",
        type=float,
        default=0.0,
        help="switch on the stage's structural modes up to this frequency (more states)",
    )
    args = ap.parse_args(argv)
    stage = plants.wafer_stage()
    if args.residual_max_hz:
        stage = stage.with_effects(residual_max_hz=args.residual_max_hz)
    linear_stage = stage.with_effects(quantization=0.0)
    K = default_controller(stage, crossover_hz=100.0)
    N = int(DURATION_S * FS)
    rng = np.random.default_rng(0)
    d = rng.standard_normal((N, stage.n_u)) * 0.3 * effective_mass(stage, 100.0)

    def run(plant, method):
        return sim.closed_loop(plant, K, d=d, rng=np.random.default_rng(1), method=method)

    rows = []
    with threadpool_limits(1):
        t_step, _ = best(lambda: run(stage, "auto"), 1)  # the step path is slow: once
        rows.append(("closed_loop, quantized stage (compiled step loop)", t_step))
        t_auto, (u_lin, y_lin) = best(lambda: run(linear_stage, "auto"), args.repeat)
        rows.append(("closed_loop, linear stage, auto (probe + linear)", t_auto))
        t_lin, _ = best(lambda: run(linear_stage, "linear"), args.repeat)
        rows.append(("closed_loop, linear stage, linear path", t_lin))

        # where the linear path's time goes
        P = sim.discretize(linear_stage.linear_model(), FS, delay_s=linear_stage.delay_s)
        Ks = K.statespace()
        t_mats, (A, B, C, D) = best(
            lambda: sim.closed_loop_matrices(P, (Ks.A, Ks.B, Ks.C, Ks.D)), args.repeat
        )
        t_eig, _ = best(lambda: np.linalg.eigvals(A), args.repeat)
        t_noise, v = best(
            lambda: linear_stage.simulate(np.zeros_like(d), rng=np.random.default_rng(1)),
            args.repeat,
        )
        w = np.hstack([np.zeros((N, stage.n_y)), d, v])
        t_dlsim, out = best(lambda: sim.dlsim(A, B, C, D, w), args.repeat)
        sys_cl = control.ss(A, B, C, D, 1.0 / FS)
        t_ct, resp = best(lambda: control.forced_response(sys_cl, U=w.T), 1)
        t_sp, sp = best(lambda: scipy.signal.dlsim((A, B, C, D, 1.0 / FS), w), 1)

    ref = resp.outputs.T
    err_ct = np.linalg.norm(out - ref) / np.linalg.norm(ref)
    err_sp = np.linalg.norm(out - sp[1]) / np.linalg.norm(sp[1])
    err_path = np.linalg.norm(np.hstack([u_lin, y_lin]) - out) / np.linalg.norm(out)
    print(
        f"wafer stage: {stage.n_u} inputs, {stage.n_y} outputs ({stage.n_raw} raw sensors), "
        f"{stage.chain.n_x} plant states, closed loop {A.shape[0]} states; "
        f"{N} samples ({DURATION_S:g} s at {FS:g} Hz); 1 BLAS thread"
    )
    print(f"{'case':58s} {'time [ms]':>10s} {'x real time':>12s}")
    for name, t in rows:
        print(f"{name:58s} {1e3 * t:10.1f} {DURATION_S / t:12.0f}")
    print("linear path, parts:")
    for name, t in (
        ("  closed-loop matrices", t_mats),
        ("  stability check (eigvals)", t_eig),
        ("  plant noise v = plant.simulate(0)", t_noise),
        ("  sim.dlsim (lifted recursion)", t_dlsim),
    ):
        print(f"{name:58s} {1e3 * t:10.1f}")
    print("peers on the same discrete closed loop and input:")
    for name, t, err in (
        ("  control.forced_response", t_ct, err_ct),
        ("  scipy.signal.dlsim", t_sp, err_sp),
    ):
        print(
            f"{name:58s} {1e3 * t:10.1f} {DURATION_S / t:12.0f}"
            f"   dlsim {t / t_dlsim:5.1f}x faster, rel. diff {err:.1e}"
        )
    print(f"closed_loop (linear) vs the same dlsim: rel. diff {err_path:.1e}")


if __name__ == "__main__":
    main()
