"""Benchmark: crossover per DOF at |S_ii| <= 2 (6 dB) on the TRUE wafer stage, and the physics.

Part 1 - the stage. Designs on the stage's nominal modal model (rigid body + the
913.8 / 1032 Hz modes, no effects; NOT the model identified from the closed-loop
record: that takes the identify/refine pipeline, left to the scenario), loop delay
1 sample (the stage's 2e-4 s at 5 kHz):

* baseline ``controllers.pid_notch.tune_pid_notch`` (PID + low-pass + notches);
* ``controllers.modal_sf.tune_modal_sf`` (modal LQG from per-mode bandwidths);

both analysed with ``workbench.loop.analyze_loop`` on the TRUE stage (its linear
part with the residual modes and its own delay). The delay-limited reference is the
best crossover a scanned lead + PI family or the tuned PID + low-pass reaches at
|S| <= 2 on the rigid body alone with the same delay (``rigid_reference``; per DOF the same
number: the figure is scale-free, so one double integrator gives it).

Part 2 - the physics: the worst DOF's loop (Ry: torque Ty -> Ry with the rigid body
and both flexible modes, as a 1-DOF modal model) under changes of the machine: loop
delay 1, 0.5, 0.25 samples, and the flexible modes at 1x / 0.5x / 0.3x their
frequency. Designs and analysis on that exact model (the design is told the delay).
It shows where the baseline becomes mode-limited and what modal-sf reaches there.

Part 1 also designs ``controllers.youla.tune_youla`` (coupled, Q on 40 Laguerre functions
around the pid-notch loops). Part 3 - limits of performance on the Ry loop: the widest
template |S| <= (f/fb)^2 at |S| <= 2 over all stabilizing controllers (Youla), growing
with the basis, with and without the flexible modes, against the designs' own templates.

Measured (session 20, loaded machine; part 1's truth now with the modes above Nyquist,
residual_max_hz = 5 kHz as in the scenario; before, the plant default left them out):
pid-notch x 220.0 / |S| 2.01 ... Ry 191.7 / 1.94, modal-sf 218-228.7, hinf 131-372.6 (as
before to 0.5 %); youla (designed on the nominal model) UNSTABLE on that truth: z |S| 7.86,
sigma(S) 79 (crossovers 301.6-381.8 Hz = 1.57-1.74x pid-notch; without the residual modes
it was stable, |S_ii| <= 1.91: the design is not robust to them). Part 3 with the modes,
n 20 / 40: fb 198 / 236 Hz, crossover 283 / 346 Hz (pid-notch 209.9); rigid body alone
n 40: fb 251, fc 389.5 Hz, above tune_hinf's 372.6 Hz: the "reference" of part 1 is the
best design known, not a limit.

Session 21: youla told the model's error by a measurement of the true stage
(``tune_youla(measured=...)``: decentralized, each channel's bounds held on the measured
loop, |T_ii| under the measured interaction bound), on the truth WITH the modes above
Nyquist, stable, |S_ii| <= 1.93: exact measurement x 353.3 (1.61x), y 332.6 (1.52x),
z 304.7 (1.39x), Rx 259.0 (1.20x), Ry 288.4 (1.50x), Rz 354.1 (1.61x); an FRF on 2.5 Hz
lines with 1 % noise: 347.7 / 325.0 / 293.9 / 269.0 / 279.0 / 346.2 Hz (1.58 / 1.49 / 1.35 /
1.25 / 1.46 / 1.58x), |S_ii| <= 1.92, sigma(S) 42.8; ~170 s a design, loaded machine.

Session 22: after that interaction-bound round, sequential loop closing (each loop
re-designed on what it sees of the measured plant with the others closed,
``closed_loop_error``) and each loop controller cut by balanced truncation under a
small-gain certificate on the measured loop (``reduce_loop``); n_basis 60. On the truth
WITH the modes above Nyquist, stable: exact measurement x 394.4 / 1.94 (1.79x), y 384.7 /
1.95 (1.76x), z 327.6 / 1.94 (1.50x), Rx 328.5 / 1.94 (1.53x), Ry 314.5 / 1.95 (1.64x), Rz
399.5 / 1.94 (1.82x), sigma(S) 129.7, 512 s; the 1 % FRF: 378.6 / 365.5 / 311.7 / 314.4 /
303.2 / 386.3 Hz (1.72 / 1.67 / 1.43 / 1.46 / 1.58 / 1.76x), |S_ii| <= 1.92, sigma(S) 107.2,
528 s (loaded machine). Same run: pid-notch, modal-sf, hinf as before to 0.5 %; the
coupled youla on the model alone still unstable (z |S| 7.70).

Session 24 (same code paths, rerun on a fresh machine, loaded): the figures repeat (exact
measurement to the 0.1 Hz; the FRF run within 0.3 %: 379.2 / 366.4 / 310.7 / 314.4 / 303.2 /
386.3 Hz). New: the MIMO sensitivity peak in scaled units (``workbench.loop.scaled_sigma_max``,
free of m vs rad): pid-notch 2.54, modal-sf 2.04, hinf 2.41; youla on the exact measurement
4.22 (unscaled 129.7), on the 1 % FRF 3.75 (108.6). So the unscaled growth was mostly units,
but not all: the decentralized Youla loops hold |S_ii| <= 1.95 each while the MIMO loop's
worst direction reaches 4.2 (12.5 dB), 1.7x the baseline's; a MIMO bound (scaled) in the
design is what would close it.

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_bandwidth.py [--quick] [--parts 1]``
(~25 min on a loaded machine; youla takes most of it).
"""

from __future__ import annotations

import argparse
import time
import warnings

import control
import numpy as np


def rigid_reference(fs: float, delay_s: float, ms_max: float = 2.0, hinf: bool = False) -> float:
    """Best crossover (Hz) at |S| <= ms_max on 1/s^2 with ZOH and delay_s: lead + PI scan.

    The best of the controller families: lead ratio a in 4..30 (zero wc/sqrt(a),
    pole wc sqrt(a)), PI corner wc/5, gain for |C(j wc)| = 1/|P(j wc)|, Tustin, scored
    by workbench.loop.screen_loops on the exact ZOH loop with the delay (fractional
    delays included); tune_pid_notch's PID + low-pass on the same rigid plant; and,
    with ``hinf``, tune_hinf's mixed-sensitivity design (a finer target scan than
    its default), whose higher-order shaping goes past the lead + PI family.
    """
    from controllers.pid_notch import tune_pid_notch
    from workbench.core.model import LTIModel
    from workbench.loop import analyze_loop, screen_loops

    plant = LTIModel.from_statespace(control.ss(control.tf([1.0], [1, 0, 0])), delay_s=delay_s)
    K, _ = tune_pid_notch(plant, fs, ms_max=ms_max)
    best = float(analyze_loop(plant, K.controller).loops[0].crossover_hz)
    for fc in np.logspace(np.log10(fs / 200), np.log10(fs / 6), 60):
        wc = 2 * np.pi * fc
        for a in (4.0, 6.0, 9.0, 14.0, 20.0, 30.0):
            shape = control.tf([1 / (wc / np.sqrt(a)), 1], [1 / (wc * np.sqrt(a)), 1])
            shape = shape * control.tf([1, wc / 5], [1, 0])
            K = control.ss(control.c2d(wc**2 / abs(shape(1j * wc)) * shape, 1 / fs, "tustin"))
            stable, peak, fcs = screen_loops(plant, K)
            if stable and peak[0] <= ms_max and np.isfinite(fcs[0]):
                best = max(best, float(fcs[0]))
    if hinf:
        from controllers.hinf import tune_hinf

        d = tune_hinf(plant, ms_max=ms_max, fs=fs, n_scan=17, refine=3)
        a = analyze_loop(plant, d.controller)
        if a.stable and a.loops[0].s_peak <= ms_max * (1 + 1e-9):
            best = max(best, float(a.loops[0].crossover_hz))
    return best


def _designs(model, fs, m, truth, m_truth, pid_model=None):
    """(pid fc per loop, modal-sf fc per loop, peaks, times) on the truth."""
    from controllers.modal_sf import tune_modal_sf
    from controllers.pid_notch import tune_pid_notch
    from workbench.loop import analyze_loop

    t = time.perf_counter()
    K, _ = tune_pid_notch(model.to_lti() if pid_model is None else pid_model, fs,
                          ms_max=2.0, loop_delay_samples=m)  # fmt: skip
    t_pid = time.perf_counter() - t
    t = time.perf_counter()
    d = tune_modal_sf(model, ms_max=2.0, loop_delay_samples=m, fs=fs)
    t_msf = time.perf_counter() - t
    a_pid = analyze_loop(truth, K.controller, loop_delay_samples=m_truth)
    a_msf = analyze_loop(truth, d.controller, loop_delay_samples=m_truth)
    return a_pid, a_msf, d, t_pid, t_msf


def part1(quick: bool):
    import plants
    from workbench.core.model import LTIModel

    p = plants.get_plant("wafer_stage")
    fs = p.fs
    # the truth of scenarios/wafer_stage_bandwidth.toml: the stage's modes above Nyquist
    # (to 5 kHz) are in it; the plant's default (residual_max_hz = 0) leaves them out, and
    # a design that is fine without them can be unstable with them (youla, session 20)
    true_plant = p.with_effects(residual_max_hz=5000.0)
    truth = LTIModel.from_statespace(true_plant.linear_model(), delay_s=float(true_plant.delay_s))
    m = int(round(p.delay_s * fs))
    nominal = p.nominal_modal_model()
    a_pid, a_msf, d, t_pid, t_msf = _designs(nominal, fs, m, truth, 0,
                                             pid_model=p.nominal_model())  # fmt: skip
    from controllers.hinf import tune_hinf
    from workbench.loop import analyze_loop

    t = time.perf_counter()
    h = tune_hinf(nominal, ms_max=2.0, loop_delay_samples=m, fs=fs)
    t_hinf = time.perf_counter() - t
    a_hinf = analyze_loop(truth, h.controller)
    from controllers.youla import tune_youla

    t = time.perf_counter()
    y = tune_youla(nominal, ms_max=2.0, loop_delay_samples=m, fs=fs, n_basis=20 if quick else 40)
    t_youla = time.perf_counter() - t
    a_youla = analyze_loop(truth, y.controller)
    # robust: the same tool told what the model lacks, from a measurement of the true stage:
    # (1) exact (the truth's own response), (2) an FRF on the closed-loop experiment's
    # 2.5 Hz lines with 1 % complex noise and its variance (seeded)
    from workbench.core.lti import frf, zoh_frf
    from workbench.io.formats import FrfData
    from workbench.loop import discrete_plant

    Gt = discrete_plant(truth, fs, 0)  # from the controller output: the stage's delay in
    fl = np.arange(2.5, fs / 2, 2.5)
    # an FRF from the plant input u, i.e. after the real-time delay (spec 1b: hold divided out)
    after = LTIModel.from_statespace(true_plant.linear_model(), delay_s=0.0)
    G_meas = frf(discrete_plant(after, fs, 0), fl) / zoh_frf(fl, fs)[:, None, None]
    rng = np.random.default_rng(20261125)
    sd = 0.01 * np.abs(G_meas) / np.sqrt(2)
    shape = G_meas.shape
    noisy = G_meas + sd * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    robust = {}
    for label, measured in (("exact", Gt), ("frf", FrfData(fl, noisy, G_var=2 * sd**2, fs=fs))):
        t = time.perf_counter()
        yr = tune_youla(nominal, ms_max=2.0, loop_delay_samples=m, fs=fs,
                        n_basis=20 if quick else 60, measured=measured)  # fmt: skip
        robust[label] = (
            analyze_loop(truth, yr.controller),
            time.perf_counter() - t,
            yr.report.orders,
        )
    ref_lead = rigid_reference(fs, p.delay_s)
    ref = rigid_reference(fs, p.delay_s, hinf=True)
    print(f"Part 1: wafer stage, fs {fs:g} Hz, delay {p.delay_s * 1e6:.0f} us ({m} sample), "
          "designs on the nominal model, figures on the TRUE stage")  # fmt: skip
    print(f"  design time: pid-notch {t_pid:.1f} s, modal-sf {t_msf:.1f} s, hinf {t_hinf:.1f} s, "
          f"youla {t_youla:.0f} s (modal-sf kept {d.report.settings}; youla n {y.report.n_basis}, "
          f"{y.report.solves} programs)")  # fmt: skip
    print(
        "  delay-limited reference (rigid body only, same delay): lead+PI scan / PID "
        f"{ref_lead:.1f} Hz; best with tune_hinf {ref:.1f} Hz (the ref of the ratios)"
    )
    print(f"  {'DOF':>4} {'pid fc':>8} {'|S|':>5} {'msf fc':>8} {'|S|':>5} {'hinf fc':>8} "
          f"{'|S|':>5} {'msf/pid':>8} {'hinf/pid':>8} {'pid/ref':>8} {'msf/ref':>8} "
          f"{'hinf/ref':>8} {'youla fc':>8} {'|S|':>5} {'yla/pid':>8}")  # fmt: skip
    for lp, lm, lh, ly in zip(a_pid.loops, a_msf.loops, a_hinf.loops, a_youla.loops):
        print(f"  {lp.name:>4} {lp.crossover_hz:8.1f} {lp.s_peak:5.2f} {lm.crossover_hz:8.1f} "
              f"{lm.s_peak:5.2f} {lh.crossover_hz:8.1f} {lh.s_peak:5.2f} "
              f"{lm.crossover_hz / lp.crossover_hz:8.2f} {lh.crossover_hz / lp.crossover_hz:8.2f} "
              f"{lp.crossover_hz / ref:8.2f} {lm.crossover_hz / ref:8.2f} "
              f"{lh.crossover_hz / ref:8.2f} {ly.crossover_hz:8.1f} {ly.s_peak:5.2f} "
              f"{ly.crossover_hz / lp.crossover_hz:8.2f}")  # fmt: skip
    print(f"  stable: pid {a_pid.stable}, modal-sf {a_msf.stable}, hinf {a_hinf.stable}, "
          f"youla {a_youla.stable}; MIMO max sigma(S): pid {a_pid.sigma_max_S_inf:.2f}, "
          f"modal-sf {a_msf.sigma_max_S_inf:.2f}, hinf {a_hinf.sigma_max_S_inf:.2f}, "
          f"youla {a_youla.sigma_max_S_inf:.2f} (scaled, free of the m / rad units: pid "
          f"{a_pid.scaled_sigma_max_S_inf:.2f}, modal-sf {a_msf.scaled_sigma_max_S_inf:.2f}, "
          f"hinf {a_hinf.scaled_sigma_max_S_inf:.2f}, "
          f"youla {a_youla.scaled_sigma_max_S_inf:.2f})")  # fmt: skip
    print("  youla told the model's error by a measurement of the true stage (measured=..., "
          "decentralized, |T_ii| <= interaction bound, then sequential loop closing on the "
          f"measured plant; n {20 if quick else 60}): fc / |S| / x pid-notch")  # fmt: skip
    for label, (a, dt, orders) in robust.items():
        cells = "  ".join(f"{ly.name} {ly.crossover_hz:.1f}/{ly.s_peak:.2f}/"
                          f"{ly.crossover_hz / lp.crossover_hz:.2f}x"
                          for ly, lp in zip(a.loops, a_pid.loops))  # fmt: skip
        print(f"    {label:>5}: stable {a.stable}, sigma(S) {a.sigma_max_S_inf:.2f} "
              f"(scaled {a.scaled_sigma_max_S_inf:.2f}), "
              f"{dt:.0f} s, loop orders {list(orders)}: {cells}")  # fmt: skip
    return p


def _ry_slice(p, freq_scale: float, delay_s: float):
    """The stage's Ty -> Ry loop as a 1-DOF ModalModel (rigid + both flexible modes)."""
    from workbench.modal.model import ModalModel, Mode

    full = p.nominal_modal_model()
    j = list(full.output_names).index("Ry")
    i = list(full.input_names).index("Ty")
    modes = []
    for md in full.modes:
        if md.kind == "rigid" and abs(md.b[i] * md.c[j]) < 1e-12:
            continue  # another DOF's rigid body
        f = md.freq_hz * (freq_scale if md.kind == "flexible" else 1.0)
        modes.append(Mode(md.kind, f, md.damping, b=[md.b[i]], c=[md.c[j]]))
    return ModalModel(modes=tuple(modes), D=np.zeros((1, 1)), delay_s=delay_s,
                      input_names=("Ty",), output_names=("Ry",))  # fmt: skip


def part2(p, quick: bool):
    fs = p.fs
    delays = (1.0, 0.5) if quick else (1.0, 0.5, 0.25)
    scales = (1.0, 0.5) if quick else (1.0, 0.5, 0.3)
    print("\nPart 2: Ry loop (Ty -> Ry, rigid + flexible modes), designs and figures on the "
          "exact model; delay in samples, modes at scale x (913.8, 1032) Hz")  # fmt: skip
    print(f"  {'delay':>5} {'modes x':>7} {'ref fc':>7} {'pid fc':>7} {'msf fc':>7} "
          f"{'hinf fc':>7} {'msf/pid':>7} {'hinf/pid':>8} {'pid/ref':>7} {'msf/ref':>7} "
          f"{'hinf/ref':>8}  modal-sf damping")  # fmt: skip
    from controllers.hinf import tune_hinf
    from workbench.loop import analyze_loop

    refs = {}
    for dly in delays:
        refs[dly] = rigid_reference(fs, dly / fs, hinf=True)
        for sc in scales:
            model = _ry_slice(p, sc, dly / fs)
            a_pid, a_msf, d, _, _ = _designs(model, fs, 0, model.to_lti(), 0)
            a_h = analyze_loop(model.to_lti(), tune_hinf(model, ms_max=2.0, fs=fs).controller)
            fp, fm = a_pid.loops[0].crossover_hz, a_msf.loops[0].crossover_hz
            fh = a_h.loops[0].crossover_hz
            r = refs[dly]
            note = "" if a_pid.stable and a_msf.stable and a_h.stable else "  (UNSTABLE)"
            print(f"  {dly:5.2f} {sc:7.2f} {r:7.1f} {fp:7.1f} {fm:7.1f} {fh:7.1f} {fm / fp:7.2f} "
                  f"{fh / fp:8.2f} {fp / r:7.2f} {fm / r:7.2f} {fh / r:8.2f}  "
                  f"{d.report.settings['flexible']:g}{note}")  # fmt: skip


def _template_fb(f, S) -> float:
    """Largest fb with |S(f)| <= (f/fb)^2 for every line f <= fb (the Youla programs' template)."""
    a = np.abs(S)
    ok = [fb for fb in f if np.all(a[f <= fb] <= (f[f <= fb] / fb) ** 2)]
    return float(max(ok)) if ok else 0.0


def part3(p, quick: bool):
    """Limits of performance on the Ry loop: the best template over ALL stabilizing
    controllers (controllers.youla.max_bandwidth, Q on a growing Laguerre basis) on the
    rigid body alone and with the flexible modes, against the designs' own templates."""
    from controllers.hinf import tune_hinf
    from controllers.modal_sf import tune_modal_sf
    from controllers.pid_notch import tune_pid_notch
    from controllers.youla import _design_grid, max_bandwidth, youla_maps
    from workbench.loop import analyze_loop, discrete_plant, loop_frf

    fs = p.fs
    sizes = (20, 40) if quick else (20, 40, 80, 120)
    print("\nPart 3: limits of performance on the Ry loop (1-sample delay), |S| <= 2: the "
          "widest template |S(f)| <= (f/fb)^2 over all stabilizing controllers (Youla, Q on "
          "n Laguerre functions, pole 0.75), and the crossover of its design")  # fmt: skip
    for label, rigid_only in (("Ry, flexible modes 1x", False), ("Ry, rigid body only", True)):
        model = _ry_slice(p, 1.0, 1.0 / fs)
        if rigid_only:
            import dataclasses

            model = dataclasses.replace(
                model, modes=tuple(md for md in model.modes if md.kind == "rigid")
            )
        lti = model.to_lti()
        G = discrete_plant(lti, fs, 0)
        f = _design_grid(model, 0, fs)
        K0, _ = tune_pid_notch(lti, fs, ms_max=2.0)
        row = []
        for name, K in (("pid-notch", K0.controller),
                        ("modal-sf", tune_modal_sf(model, ms_max=2.0, fs=fs).controller),
                        ("hinf", tune_hinf(model, ms_max=2.0, fs=fs).controller)):  # fmt: skip
            a = analyze_loop(lti, K)
            _, L = loop_frf(lti, K, f)
            fb = _template_fb(f, 1 / (1 + L[:, 0, 0]))
            row.append(f"{name} fc {a.loops[0].crossover_hz:.1f} / fb {fb:.1f}")
        print(f"  {label}: " + ", ".join(row) + " Hz")
        fc0 = analyze_loop(lti, K0.controller).loops[0].crossover_hz
        for n in sizes:
            d = max_bandwidth(youla_maps(G, K0.controller, f, n_basis=n, pole=0.75),
                              ms_max=2.0 * 0.99, slope=2.0, level=1.0)  # fmt: skip
            a = analyze_loop(lti, d.controller)
            lp = a.loops[0]
            print(f"    n {n:4d}: template fb {d.value:6.1f} Hz, its design: fc "
                  f"{lp.crossover_hz:6.1f} Hz, |S| {lp.s_peak:.3f}, stable {a.stable}, "
                  f"fc / pid-notch {lp.crossover_hz / fc0:.2f} ({d.solves} programs, "
                  f"{d.seconds:.0f} s)", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer machine changes in part 2")
    ap.add_argument("--parts", default="123", help="which parts to run, e.g. 1 or 23")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    t = time.perf_counter()
    import plants

    p = part1(args.quick) if "1" in args.parts else plants.get_plant("wafer_stage")
    if "2" in args.parts:
        part2(p, args.quick)
    if "3" in args.parts:
        part3(p, args.quick)
    print(f"\ntotal {time.perf_counter() - t:.0f} s")


if __name__ == "__main__":
    main()
