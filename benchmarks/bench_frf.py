"""Benchmark: FRF estimation of a 6x6 multisine experiment, against scipy.signal.csd H1.

The case of the project issue: 6 experiments x 12 periods of 4096 samples on 6
inputs and 6 outputs (294,912 samples). Times are the best of ``--repeat``
runs, in this process, on the same data:

- ``frf_multisine`` on the in-memory experiment (blocks known);
- ``frf_multisine`` on the spec record (blocks found from the excitation);
- ``frf_h1`` (vectorized Welch H1, 4096-sample Hann segments, 50 % overlap);
- a reference H1 from ``scipy.signal.csd``: 36 + 36 cross spectra, then
  ``S_yu S_uu^-1`` per line, the way it is commonly written;
- the physical reference of the multisine estimator: averaging the kept
  periods of every block and one ``rfft`` per channel and block, for ``u`` and
  ``y`` (the least any period-averaging estimator must do; ``frf_multisine``
  also takes one FFT per kept period of the outputs for the noise variance);
- the reference plus the rfft of every kept period's deviation from its block
  mean (the least a per-line noise variance from the period spread needs);
- the three large parts of ``frf_multisine``: the periodic record (means and
  their DFTs, the reference's work plus the block and excitation bookkeeping),
  the DFTs of every kept period's deviation for the noise variance, and the
  equilibrated, condition-checked inverses of the 6x6 input matrices at the
  2,047 lines;
- two floors no implementation of this estimator goes below: the bare rffts
  of the 66 kept periods x 6 outputs (into one reused buffer, no subtraction,
  no reduction), which the per-line variance from the period spread needs
  (the spread at a line is a sum of squares of per-period spectra, not a
  linear function of the data: averaging first cannot give it), and
  ``np.linalg.inv`` of the 2,047 input matrices alone;

each with BLAS/OpenMP threads and ``scipy.fft`` workers limited to 1
(threadpoolctl, ``scipy.fft.set_workers``) and unlimited (all cores). The
cases take turns within every round, so that load on a shared machine
touches them alike. The table gives each case's time over the physical
reference and scipy's csd time over the case's.

The summary line gives ``frf_multisine``'s time over the reference (the
issue's target: within 2x) and the sum of the floors over it. ``--clock cpu``
times process CPU time instead of wall time: on a shared machine the
one-thread column then does not count the time other processes hold the core.

Run: ``python benchmarks/bench_frf.py [--repeat 5] [--clock wall|cpu]``. Prints a table to
stdout.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import control
import numpy as np
import scipy.fft
import scipy.signal
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from plants.base import LinearPlant  # noqa: E402
from workbench.experiments import run_multisine  # noqa: E402
from workbench.signals.excitation import multisine  # noqa: E402
from workbench.signals.frf import _inverse, frf_h1, frf_multisine  # noqa: E402
from workbench.signals.periodic import periodic_record  # noqa: E402

FS = 5000.0  # Hz, the wafer stage's sampling rate
MASS = np.array([20.0, 20.0, 20.0, 0.38, 0.46, 0.58])  # kg, kg m^2: the example stage


def stage() -> control.StateSpace:
    """Six rigid bodies on soft, damped suspensions (2 Hz, 70 %) and a 900 Hz mode."""
    n = 6
    A = np.zeros((2 * n + 2, 2 * n + 2))
    A[:n, n : 2 * n] = np.eye(n)
    ws = 2 * np.pi * 2.0
    A[n : 2 * n, :n] = -np.eye(n) * ws**2
    A[n : 2 * n, n : 2 * n] = -np.eye(n) * 2 * 0.7 * ws  # damped: transients gone in a period
    wn = 2 * np.pi * 900.0
    A[2 * n, 2 * n + 1] = 1.0
    A[2 * n + 1, 2 * n : 2 * n + 2] = [-(wn**2), -0.02 * wn]
    B = np.zeros((2 * n + 2, n))
    B[n : 2 * n] = np.diag(1 / MASS)
    B[2 * n + 1] = 0.01
    C = np.zeros((n, 2 * n + 2))
    C[:, :n] = np.eye(n)
    C[:, 2 * n] = 0.5
    return control.ss(A, B, C, np.zeros((n, n)))


def csd_h1(u: np.ndarray, y: np.ndarray, nperseg: int) -> np.ndarray:
    n_u, n_y = u.shape[1], y.shape[1]
    kw = dict(fs=FS, window="hann", nperseg=nperseg, noverlap=nperseg // 2)
    f, _ = scipy.signal.csd(u[:, 0], u[:, 0], **kw)
    Suu = np.empty((f.size, n_u, n_u), complex)
    Syu = np.empty((f.size, n_y, n_u), complex)
    for i in range(n_u):
        for j in range(n_u):
            Suu[:, i, j] = scipy.signal.csd(u[:, j], u[:, i], **kw)[1]  # E[U_i conj(U_j)]
        for j in range(n_y):
            Syu[:, j, i] = scipy.signal.csd(u[:, i], y[:, j], **kw)[1]  # E[Y_j conj(U_i)]
    return Syu @ np.linalg.inv(Suu)


def average_and_fft(exp, n_transient: int = 1) -> None:
    """The physical reference: mean of the kept periods per block, one rfft per channel."""
    for x in (exp.u, exp.y):
        blocks = x.reshape((-1,) + x.shape[2:])  # (n_blocks, n_periods, period, n_ch)
        scipy.fft.rfft(blocks[:, n_transient:].mean(axis=1), axis=1)


def average_fft_and_spread(exp, n_transient: int = 1) -> None:
    """The reference plus what a per-line noise variance needs at least: the rfft of every kept
    period's deviation from its block mean, for the outputs (the inputs here repeat exactly)."""
    average_and_fft(exp, n_transient)
    y = exp.y.reshape((-1,) + exp.y.shape[2:])[:, n_transient:]  # (blocks, periods, period, n_y)
    for p in y:  # block by block: the deviations of one block stay in cache
        D = scipy.fft.rfft(p - p.mean(axis=0), axis=1)
        v = D.view(np.float64).reshape(D.shape[0], -1)
        np.einsum("pi,pi->i", v, v)


def kept_period_ffts(exp, n_transient: int = 1) -> None:
    """Floor: the rfft of every kept period of every output, into one reused buffer."""
    y = exp.y.reshape((-1,) + exp.y.shape[2:])[:, n_transient:]  # (blocks, periods, period, n_y)
    out = np.empty(y.shape[1:2] + (y.shape[2] // 2 + 1,) + y.shape[3:], complex)
    for p in y:
        np.fft.rfft(p, axis=1, out=out)


def best_of(cases: dict, repeat: int, clock=time.perf_counter) -> dict:
    """Best time of every case over ``repeat`` rounds, s; the cases take turns in every round,
    so that a burst of load on the shared machine hits all of them alike, not one."""
    times = {name: np.inf for name in cases}
    for _ in range(repeat):
        for name, fn in cases.items():
            t = clock()
            fn()
            times[name] = min(times[name], clock() - t)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    plant = LinearPlant(sys=stage(), fs=FS, noise_std=1e-9)
    # every bin excited (full multisine), so that H1 on the same record is well posed
    design = multisine(
        fs=FS,
        period=4096,
        band_hz=(1.0, 2499.5),
        n_ch=6,
        rms=0.3 * MASS,
        kind="full",
        design="orthogonal",
        rng=rng,
    )
    exp = run_multisine(plant, design, n_periods=12, rng=rng)
    td = exp.to_time_data()
    rec = periodic_record(exp)
    Ul = np.moveaxis(rec.U[:, 1:2048], 0, -1)  # (lines, n_u, blocks): the input matrices
    B = Ul @ np.conj(np.swapaxes(Ul, 1, 2))
    cases = {
        "frf_multisine (in memory)": lambda: frf_multisine(exp),
        "frf_multisine (from record)": lambda: frf_multisine(td),
        "frf_h1 (vectorized Welch)": lambda: frf_h1(td, nperseg=4096),
        "scipy.signal.csd H1": lambda: csd_h1(td.u, td.y, 4096),
        "average periods + rfft (ref)": lambda: average_and_fft(exp),
        "ref + rfft of period deviations": lambda: average_fft_and_spread(exp),
        # where frf_multisine's time goes (its three large parts)
        "  part: periodic_record": lambda: periodic_record(exp),
        "  part: spread of y (noise_var)": lambda: rec.noise_var("y"),
        "  part: 6x6 inverses (_inverse)": lambda: _inverse(B, "B"),
        # what no implementation avoids
        "  floor: rffts of kept y periods": lambda: kept_period_ffts(exp),
        "  floor: np.linalg.inv (2,047)": lambda: np.linalg.inv(B),
    }
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    print(
        f"6x6, 6 experiments x 12 periods x 4096 samples = {td.n_samples} samples; best of "
        f"{args.repeat}, {args.clock} clock"
    )
    results = {}
    for limit in (1, None):
        # "default": every core for BLAS and for the FFTs (scipy.fft runs one worker unless told)
        with threadpool_limits(limits=limit), scipy.fft.set_workers(limit or os.cpu_count()):
            for name, t in best_of(cases, args.repeat, clock).items():
                results[(name, limit)] = t
    csd = {lim: results[("scipy.signal.csd H1", lim)] for lim in (1, None)}
    phys = {lim: results[("average periods + rfft (ref)", lim)] for lim in (1, None)}
    print(
        f"{'case':32s} {'1 thread':>12s} {'default':>12s} {'case / ref (1 thr)':>19s} "
        f"{'csd / case':>11s}"
    )
    for name in cases:
        t1, tn = results[(name, 1)], results[(name, None)]
        print(
            f"{name:32s} {t1 * 1e3:10.1f}ms {tn * 1e3:10.1f}ms {t1 / phys[1]:18.2f}x "
            f"{csd[None] / tn:10.1f}x"
        )
    ms = {name: 1e3 * results[(name, 1)] for name in cases}
    ref = ms["average periods + rfft (ref)"]
    floor = (
        ms["average periods + rfft (ref)"]
        + ms["  floor: rffts of kept y periods"]
        + ms["  floor: np.linalg.inv (2,047)"]
    )
    print(
        f"1 thread: frf_multisine (in memory) {ms['frf_multisine (in memory)']:.1f} ms = "
        f"{ms['frf_multisine (in memory)'] / ref:.2f}x the reference ({ref:.1f} ms; target "
        f"<= 2x); reference + kept-period rffts + inverses alone {floor:.1f} ms = "
        f"{floor / ref:.2f}x"
    )
    # accuracy against the true FRF on the same lines (ZOH compensated)
    a = frf_multisine(exp)
    h = csd_h1(td.u, td.y, 4096)[1:2048]
    z = np.exp(-1j * np.pi * a.frf.freq / FS) * np.sinc(a.frf.freq / FS)
    G0 = plant.frf(a.frf.freq)

    def rel(G):
        return np.median(np.linalg.norm(G - G0, axis=(1, 2)) / np.linalg.norm(G0, axis=(1, 2)))

    print(
        f"median relative error vs true FRF: multisine {rel(a.frf.G):.2e}, "
        f"csd-H1 {rel(h / z[:, None, None]):.2e}"
    )


if __name__ == "__main__":
    main()
