"""Benchmark: H-inf synthesis on the wafer stage, Riccati (SLICOT SB10AD) vs LMI (cvxpy).

The stage's nominal modal model (``plants.wafer_stage``'s ``nominal_modal_model``:
rigid body + the 913.8 / 1032 Hz modes, as in bench_bandwidth.py) with the loop's
1-sample delay (the stage's 2e-4 s at 5 kHz), BLAS limited to ``--blas-threads``:

1. One synthesis: the mixed-sensitivity problem that ``tune_hinf`` builds for DOF
   ``--dof`` at target ``--target-hz`` (its weights, plant normalized at the target,
   rigid poles shifted; generalized plant of order 10, the LMI 44 x 44), solved by
   ``hinf_riccati`` and ``hinf_lmi``: best-of-N wall and CPU time, the ratio, both
   gammas, and the norm each controller attains on that plant (``control.linfnorm``,
   an independent evaluation).
2. ``tune_hinf`` on the 6-DOF model with each method (the LMI one once, ~6 minutes;
   skipped with ``--quick``): time, ratio, and per DOF the target and crossover kept,
   and the loops on the TRUE stage (``workbench.loop.analyze_loop``).

Run: ``python benchmarks/bench_hinf.py [--repeat 5] [--quick]`` (~1 min with --quick,
~8 min without).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import control
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import plants  # noqa: E402
from controllers import hinf  # noqa: E402
from workbench.core.blas import limited_blas  # noqa: E402
from workbench.core.model import LTIModel  # noqa: E402
from workbench.loop import analyze_loop  # noqa: E402


def best(fn, repeat: int) -> tuple[float, float, object]:
    """(best wall time, best CPU time, last result) of ``repeat`` calls, s.

    CPU time (process_time, all threads) as well: on a machine shared with other
    jobs the wall time includes waiting for a core.
    """
    walls, cpus, out = [], [], None
    for _ in range(max(int(repeat), 1)):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus), out


def attained(P, n_meas: int, n_ctrl: int, K) -> float:
    """||T_zw||inf of P closed by K (u = K v), by SLICOT AB13DD (control.linfnorm)."""
    T = P.lft(K.statespace(), n_ctrl, n_meas)
    if np.max(np.abs(T.poles())) >= 1.0:
        return float("inf")
    return float(control.linfnorm(T)[0])


def part1(stage, m: int, dof: str, target_hz: float, repeat: int, repeat_lmi: int) -> None:
    fs = stage.fs
    modal = stage.nominal_modal_model()
    i = list(modal.input_names).index(dof) if dof in modal.input_names else None
    if i is None:
        i = list(modal.output_names).index(dof)
    G = hinf.channel_plant(modal, i, fs, m)
    _g0, Gn, W1, W2, W3, shift = hinf._channel_problem(G, target_hz, fs, 2.0)
    P, nm, nc, rho = hinf.mixed_sensitivity(Gn, W1, W2, W3, pole_shift=shift)
    n = P.nstates
    print(f"Part 1: one synthesis, DOF {modal.output_names[i]} at target {target_hz:g} Hz "
          f"(generalized plant order {n}, pole shift {1 - rho:.4f}; LMI "
          f"{4 * n + P.ninputs + P.noutputs - nm - nc} x "
          f"{4 * n + P.ninputs + P.noutputs - nm - nc})")  # fmt: skip
    rows = []
    for method, fn, rep_n in (
        ("riccati", lambda: hinf.hinf_riccati(P, nm, nc), repeat),
        ("lmi", lambda: hinf.hinf_lmi(P, nm, nc), repeat_lmi),
    ):
        wall, cpu, (K, rep) = best(fn, rep_n)
        rows.append((method, wall, cpu, rep, attained(P, nm, nc, K), rep_n))
    print(f"  {'method':>8} {'best wall':>10} {'best CPU':>10} {'of N':>5} {'gamma_opt':>10} "
          f"{'gamma':>10} {'attained':>10}  status")  # fmt: skip
    for method, wall, cpu, rep, att, rep_n in rows:
        print(f"  {method:>8} {wall:9.4f}s {cpu:9.4f}s {rep_n:5d} {rep.gamma_opt:10.6f} "
              f"{rep.gamma:10.6f} {att:10.6f}  {rep.status}")  # fmt: skip
    (_, w_r, c_r, r_r, _, _), (_, w_l, c_l, r_l, _, _) = rows
    print(f"  LMI / Riccati: wall {w_l / w_r:.0f}x, CPU {c_l / c_r:.0f}x; gamma_opt LMI / "
          f"Riccati = {r_l.gamma_opt / r_r.gamma_opt:.4f}")  # fmt: skip


def part2(stage, m: int, repeat: int, with_lmi: bool) -> None:
    fs = stage.fs
    modal = stage.nominal_modal_model()
    truth = LTIModel.from_statespace(stage.linear_model(), delay_s=float(stage.delay_s))
    print("\nPart 2: tune_hinf on the 6-DOF nominal model (ms_max 2, loop delay "
          f"{m} sample), loops on the TRUE stage")  # fmt: skip
    results = {}
    for method, rep_n in (("riccati", repeat), ("lmi", 1)):
        if method == "lmi" and not with_lmi:
            continue
        wall, cpu, d = best(
            lambda method=method: hinf.tune_hinf(
                modal, ms_max=2.0, loop_delay_samples=m, fs=fs, method=method
            ),
            rep_n,
        )
        a = analyze_loop(truth, d.controller)
        results[method] = (wall, cpu, d, a)
        print(f"  {method}: best wall {wall:.2f} s, best CPU {cpu:.2f} s (of {rep_n}), "
              f"{len(d.scanned)} syntheses; stable on the truth {a.stable}, MIMO max "
              f"sigma(S) {a.sigma_max_S_inf:.2f}")  # fmt: skip
        print(f"    {'DOF':>4} {'target':>8} {'fc model':>9} {'fc true':>8} {'|S| true':>9} "
              f"{'gamma':>7}")  # fmt: skip
        for j, lp in enumerate(a.loops):
            print(f"    {lp.name:>4} {d.target_hz[j]:8.1f} {d.crossover_hz[j]:9.1f} "
                  f"{lp.crossover_hz:8.1f} {lp.s_peak:9.3f} {d.gamma[j]:7.3f}")  # fmt: skip
    if len(results) == 2:
        (w_r, c_r, *_), (w_l, c_l, *_) = results["riccati"], results["lmi"]
        print(f"  tune_hinf LMI / Riccati: wall {w_l / w_r:.0f}x, CPU {c_l / c_r:.0f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="best of N (Riccati; LMI: --repeat-lmi)")
    ap.add_argument("--repeat-lmi", type=int, default=2, help="best of N for one LMI synthesis")
    ap.add_argument("--dof", default="x", help="the channel of part 1 (an output or input name)")
    ap.add_argument("--target-hz", type=float, default=200.0, help="part 1's design target")
    ap.add_argument("--blas-threads", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="skip the LMI tune_hinf (~6 min)")
    args = ap.parse_args()
    warnings.simplefilter("ignore")  # cvxpy's "Solution may be inaccurate"
    stage = plants.get_plant("wafer_stage")
    m = int(round(stage.delay_s * stage.fs))
    t = time.perf_counter()
    with limited_blas(args.blas_threads):
        part1(stage, m, args.dof, args.target_hz, args.repeat, args.repeat_lmi)
        part2(stage, m, max(args.repeat // 2, 1), not args.quick)
    print(f"\ntotal {time.perf_counter() - t:.0f} s")


if __name__ == "__main__":
    main()
