"""Inferential control of the beam (issue 10): the unmeasured point against the conventional loops.

For z = s3 (near the first bending mode's antinode) and z = s4 (near its node),
with the FE model updated from a simulated 1 % FRF of s1, s2, s5 and with the
prior FE model (E +8 %, flexures +30 %), both designs of the [inferential] stage
(pid-notch on the measured loops, tune_inferential on z) run on the TRUE beam:

1. z error at the first flexible mode (disturbance spectra, band +-10 % of f1, and
   the exact closed-loop force -> z band peak), z rms, scan z rms, |S_ii|max and the
   lowest crossover of the measured loops; the ratio inferential / pid-notch in dB.
2. The |S| bound the 10 dB target needs: both designs re-tuned at ms_max = 2.5 (8 dB;
   updated model, z = s3) against section 1's ms_max = 2 figures.
3. Design time of each method (one model).
4. (``--parts 4``, 1.5-4 min a design) the Youla band-peak design around the pid-notch
   loops (workbench.cli.inferential_stages.design_youla_band: controllers.youla
   .min_band_peak, |S_ii| <= 2 held on the MEASURED loop, here the true beam's discrete loop
   known exactly, a study; the broadband z rms on the model at most ``--rms-factors`` x
   pid-notch's), z = s3, on the true beam as in section 1, with the exact z rms
   (Lyapunov) on the true beam next to the simulated one.

Run: OMP_NUM_THREADS=1 python benchmarks/bench_inferential.py [--parts 12|4]
     [--rms-factors 1,2] [--scan-factor 1] [--models updated,prior]
     [--measured truth,model,frf:0.001:1024:1]

Measured (commit d99c213, noise seed 11; z error at f1 = 35.03 Hz from the spectra /
the exact force -> z band peak; |S|max on the TRUE beam):

    z    FE       pid-notch            inferential           inferential - pid-notch
    s3   updated  5.99 dB, -64.5 dB    5.82 dB, -73.1 dB     f1 +8.9 / +8.6 dB, rms +12.5 dB
    s3   prior    7.24 dB, -59.3 dB    5.90 dB, -74.4 dB     f1 +11.1 / +15.0 dB, rms +9.3 dB
    s4   updated  5.99 dB, -68.3 dB    6.00 dB, -75.3 dB     f1 +5.7 / +7.0 dB, rms +18.4 dB
    s4   prior    7.24 dB, -64.0 dB    7.07 dB, -76.4 dB     f1 +8.4 / +12.5 dB, rms +12.7 dB
    s3 at |S| <= 2.5: inferential 7.87 dB, -75.6 dB = 11.0 dB below pid-notch at |S| <= 2

Why the 10 dB of issue 10 is not reached at |S| <= 2 (z = s3, updated FE): the open-loop
force -> z peak at f1 is -33.8 dB; pid-notch's three loops hold three points that see
mode 1 well (its shape at s1, s2, s5: -2.06, 1.55, -3.19 against 2.66 at s3) and already
bring it to -64.5 dB; the inferential design damps the mode out (force -> z flat in the
band at -73.1 dB), 2.4 dB above the beam's rigid-body mass line at f1 (-75.6 dB, the
response with no mode and no loop stiffness). Going lower needs loop gain at 35 Hz, i.e.
crossovers well above the 46-48 Hz the one-sample delay allows at |S| <= 2: at |S| <= 2.5
(8 dB) the inferential design reaches -75.6 dB. Updating matters most for the scan: the
prior's flexures are 30 % stiff in the feedforward (scan z rms 5.4 / 8.4 um on the prior
against 1.9 / 2.5 um updated, inferential / pid-notch), and the conventional loops tuned
on the prior leave the 6 dB bound on the true beam (7.24 dB).

Section 4 on the PRIOR model and on a measured FRF (issue 10, branch issue10b-s24; z = s3,
rms_factor 1, scan_factor 1, evaluated on the TRUE beam; the reference is pid-notch
designed on the UPDATED model: 5.99 dB, z@f1 150.07 nm/rtHz, exact -64.51 dB, z rms
3229 nm simulated / 3380 nm exact, scan z rms 2463 nm; dB against it, positive = better;
K0 = pid-notch on the same FE model as the Youla design, its band at that model's f1;
FRF: the SAMPLED loop's, 0.25 Hz lines to 1024 Hz, seed 17, spread k_std sigma):

    FE       measured loop       result                                          design
    prior    -- (pid-notch)      7.24 dB (> 6), z@f1 -1.6 / exact -5.2 dB,          2 s
                                 z rms +3.9 dB (exact), scan z rms -10.7 dB
    prior    true loop (exact)   infeasible: ||Delta K0 S0|| 10.4 at 35.0 Hz        17 s
    prior    none (model trusted) band -149 dB on the model; UNSTABLE on the       36 s
                                 true beam (|S|max 58.2 dB)
    updated  FRF 1 %, k_std 3    infeasible (Q = 0: r 8.5 at 2.75 Hz)                9 s
    updated  FRF 1 %, k_std 1    infeasible (Q = 0: r 3.6 at 2.50 Hz)               10 s
    updated  FRF 0.1 %, k_std 3  infeasible (Q = 0: r 0.85 at 2.75 Hz)              17 s
    updated  FRF 0.1 %, k_std 1  stable, |S|max 5.62 dB, z@f1 +48.2 / exact        436 s
                                 +57.3 dB (0.58 nm/rtHz, -121.8 dB), z rms -0.4
                                 simulated / +0.11 dB exact (3336 nm), scan z rms
                                 +2.4 dB (1873 nm); 10 programs, optimal_inaccurate

r = ||Delta K0 S0||_F + sum_a spread_a ||(K0 S0)[a, :]||, the small-gain figure the
measured-loop rows hold at <= 0.5 (controllers.youla._COUPLING_MAX). Why updating matters:
the prior puts f1 at 36.41 Hz against the beam's 35.03 Hz; at a 1 %-damped mode that
4 % makes ||Delta K0 S0|| 10.4 at f1 (> 0.5 on 0.83-491 Hz even with the truth as the
measurement; 10.5-13.8 with the FRFs below, not run), so the measured loop refuses
every Q around the prior's pid-notch (itself 7.24 dB on the beam); trusted without a
measurement, the prior's band design cancels its own f1 (-149 dB on the model) and is
unstable on the beam. On the
updated model the program is feasible with the truth (r 0.40 at 209.5 Hz, the FE model's
third mode) and with a 0.1 % FRF held at 1 sigma: the issue's target (>= 10 dB at f1,
|S_ii| <= 2 on the true beam, z rms not worse) met from a measurement, not from the
truth. A 1 % FRF is infeasible at k_std 3 and 1: pid-notch's K0 S0 inverts the nearly
rank-2 3 x 3 loop at the 2.4-2.8 Hz suspension modes, where the noise alone (at Q = 0,
without the spread) gives ||Delta K0 S0|| 0.95-1.34; 0.1 % at 3 sigma still has r 0.85
on 19 lines (2.30-2.86 Hz). A 0.1 % FRF to Nyquist is many averages; 1 sigma is no
guarantee (it held on this seed). The FRF is the sampled loop's (simulated_loop_frf):
simulated_frf's continuous response differs from it by aliasing (24 % at 900 Hz), which
the model error would take for the plant's. The stage offers the design as "youla-band"
(opt-in; [inferential.youla], defaults: 0.1 % to 1024 Hz, k_std 1). Run through the
CLI (scenarios/beam_inferential.toml with models = ["updated"], designs = ["pid-notch",
"youla-band"]; its seed draws other FRFs): stable, |S|max 5.62 dB, z at f1 +49.2 dB
(exact +57.2 dB) vs pid-notch, z rms +0.3 dB, scan z rms +2.3 dB; 8 programs, 301 s
(the stage 313 s). Its loops s2 and s5 have gain margins 0.63 and 0.45 (conditionally
stable: less gain destabilizes), pid-notch's 2.9-5.3.

Section 4 with the rms cone (issue 10, this branch; updated FE, z = s3, band 31.5-38.5 Hz
at the updated model's f1; Q 3 x 3 full, 12 Laguerre functions at pole 0.9, 250 log lines
+ 41 in the band + 40 around each mode, refine 2; pid-notch on the true beam: 5.99 dB,
z@f1 150.1 nm/rtHz, exact -64.5 dB, z rms 3229 nm simulated / 3380 nm exact, scan z rms
2463 nm; positive dB = better than pid-notch):

    rms_factor  stable  |S|max    z@f1 spectra/exact  z rms sim / exact   scan z rms  design
    1           yes     5.86 dB   +48.4 / +57.8 dB    -0.3 / +0.16 dB     -12.8 dB    227 s
    2           yes     5.88 dB   +47.3 / +51.1 dB    -6.5 / -6.03 dB     -18.4 dB     79 s
    1, scan 1   yes     5.87 dB   +47.7 / +53.2 dB    -0.6 / -0.09 dB      +1.7 dB    293 s
    (8 Laguerre functions, rms_factor 1: 5.96 dB, +46.4 / +50.6 dB, -0.3 / -0.04 dB,
    scan -9.0 dB, 173 s: no faster)

The band peak on the model is -148 dB (the model's cancellation); on the truth the updated
model's error at z limits it to 48-58 dB below pid-notch, whatever the rms allowance: a
larger rms_factor buys nothing at f1 and the design spends it (the rms is bounded, not
minimized). The simulated z rms is a 16 s record dominated by the 2-4 Hz suspension modes
(pid-notch: 3229 nm simulated, 3380 nm exact); sensor noise adds 16 nm (design) and 3 nm
(pid-notch) in quadrature. The rms cone leaves the scan (reference and feedforward path)
free: 4.4x pid-notch's scan z rms; ``--scan-factor 1`` adds the scan's z error on the model
as a second cone (controllers.youla.scan_error_affine) and the true beam's scan z rms is
then 1.7 dB below pid-notch's. The model holds both rms figures at pid-notch's (ratios
0.99997 and 1.0000); the true beam's exact z rms is 1.0 % above (3414 / 3380 nm): the
model's error at z, which no factor >= 1 covers. Before this branch the band sat on the
2.6 Hz suspension mode (the reduction's first "flexible" mode), in every row of the table
below.

Section 4, Youla band peak (session of issue 10, e31e4dd; updated FE, z = s3; Q 3 x 3 full,
12 Laguerre functions at pole 0.9, 250 log lines + 41 in the band + 40 around each mode;
pid-notch on the true beam: 5.99 dB, z@f1 150.1 nm/rtHz, exact -64.5 dB, z rms 3.23 um,
scan z rms 2.46 um; Youla against it):

    variant                              |S|max   z@f1 spectra/exact   z rms     scan z rms  design
    model only (no measured rows)^1      12.47 dB  +34.6 / +33.5 dB    -44.0 dB  -35.9 dB    173 s
    measured loop (exact), no elsewhere   6.17 dB  +46.9 / +54.5 dB    -28.0 dB  -18.9 dB    900 s
    measured loop (exact), elsewhere 1    not finished: 10 programs, 20 min, the line
                                          generation still at 1.03-1.04 (Clarabel
                                          'optimal_inaccurate' each time); on the model
                                          the band peak is -28 dB below K0's
    ^1 400 log lines; stable on the truth at this seed, but outside the 6 dB bound

Without the measured-loop rows the design inverts the 3 x 3 loop on the model (-169 dB on
the model) and leaves |S| <= 2 on the truth. With them (controllers.youla._MeasuredDiagonal)
it is stable and within 2.03 (6.17 dB: the bound holds on the grid; 4 refinement rounds
leave 0.15 dB between lines) and z at f1 is 47-55 dB below pid-notch, because the updated
FE model predicts z to 0.3 % at f1 (the cancellation survives); but z is amplified outside
the band (z rms 81 um against 3.2 um): the issue's broadband rms is lost, so
``elsewhere = 1`` (z nowhere above pid-notch's outside the band) is the default.
The error from a simulated 1 % FRF of the measured loop (as the FE update's) makes the
program infeasible even at Q = 0: K S inverts a nearly rank-2 3 x 3 loop at the suspension
modes, so 1 % noise per element gives ||Delta K0 S0|| = 1.6 at 2.4-2.6 Hz (exact: 3e-4); a
0.1 % FRF gives 0.16 there (0.35 at 209 Hz, the FE model's third mode), a feasible first
program (42 s), but later programs did not finish in 7 min (before the rms and scan cones;
with them, see the prior / FRF table above).
"""

from __future__ import annotations

import time

import numpy as np

from plants.beam import beam, beam_fe_file, beam_prior_config
from workbench.cli.inferential_stages import (
    PointSetup,
    design_point,
    design_youla_band,
    evaluate_point,
    reduction_db,
    simulated_frf,
    simulated_loop_frf,
    suspension_feedforward,
    update_from_frf,
)
from workbench.fe import solve_modes
from workbench.scan import ScanLimits, scan

MEASURED = ("s1", "s2", "s5")
DIST = {"std_n": 0.01, "n_samples": 32768, "nperseg": 4096}  # as scenarios/beam_inferential


def _models(plant):
    prior = beam_fe_file(beam_prior_config(), damping=0.01)
    data = simulated_frf(
        plant, MEASURED, np.random.default_rng(7), df_hz=0.25, f_max_hz=130.0, noise_rel=0.01
    )
    updated, _ = update_from_frf(prior, data)
    return {"updated": updated, "prior": prior}


def _evaluate(plant, fe, ctrl, setup, f1, profile, lines, design_s):
    """evaluate_point's figures of ``ctrl`` on the true beam (the scan with the FE model's
    suspension feedforward), with the design time."""
    ff = suspension_feedforward(fe, setup.measured, profile)
    ff = np.vstack([ff[setup.loop_delay_samples :], np.zeros((setup.loop_delay_samples, 3))])
    fig, _ = evaluate_point(
        plant, ctrl, setup, f1_hz=f1, disturbance=DIST, profile=profile, feedforward=ff,
        noise_seed=11, window_s=0.01, freq_hz=lines,
    )  # fmt: skip
    fig["design_s"] = design_s
    return fig


def _run(plant, fe, setup, f1, profile, lines):
    out = {}
    for design in ("pid-notch", "inferential"):
        t = time.perf_counter()
        ctrl, _ = design_point(fe, setup, design)
        out[design] = _evaluate(plant, fe, ctrl, setup, f1, profile, lines,
                                time.perf_counter() - t)  # fmt: skip
    return out


def _true_measured_loop(plant, setup):
    """The true beam's measured loop u -> (s1, s2, s5), discrete with ZOH and the loop delay."""
    from workbench.core.model import LTIModel
    from workbench.loop import discrete_plant

    idx = [list(plant.output_names).index(s) for s in setup.measured]
    lin = plant.linear_model()[idx, :]
    truth = LTIModel.from_statespace(lin, delay_s=float(plant.delay_s))
    return discrete_plant(truth, setup.fs, setup.loop_delay_samples)


def _exact_z_rms(plant, setup, ctrl) -> float:
    """The rms of z (m) on the TRUE beam under the section's white force (DIST std at every
    actuator), exact (discrete Lyapunov, controllers.youla.z_rms_exact): the simulated
    figure is a 16 s record of a signal dominated by the 2-4 Hz suspension modes, a few %
    off (3229 nm simulated against 3380 nm exact for pid-notch)."""
    from controllers.youla import z_rms_exact
    from workbench.core.model import LTIModel
    from workbench.loop import discrete_plant

    names = list(plant.output_names)
    truth = LTIModel.from_statespace(plant.linear_model(), delay_s=float(plant.delay_s))
    P = discrete_plant(truth, setup.fs, setup.loop_delay_samples)
    G, Gz = P[[names.index(s) for s in setup.measured], :], P[[names.index(setup.z)], :]
    return DIST["std_n"] * z_rms_exact(G, Gz, ctrl)


def _run_youla(
    plant,
    fe,
    setup,
    f1,
    profile,
    lines,
    measured,
    rms_factors,
    scan_factor=None,
    band_f1=None,
    k_std=3.0,
):
    """pid-notch and the Youla band-peak designs around it (one per rms factor, the band at
    the updated model's f1; with ``scan_factor`` the scan's error at z on the model at most
    that x pid-notch's), all evaluated as in _run (z at the updated model's ``f1``). The band
    is at ``band_f1`` (default ``f1``; the prior model's own f1 for a design on the prior).
    ``measured``: the true loop (StateSpace) or an FRF of it (``k_std`` its spread)."""
    t = time.perf_counter()
    K0, _ = design_point(fe, setup, "pid-notch")
    out = {"pid-notch": _evaluate(plant, fe, K0, setup, f1, profile, lines,
                                  time.perf_counter() - t)}  # fmt: skip
    out["pid-notch"]["z_rms_exact_m"] = _exact_z_rms(plant, setup, K0)
    scan = None
    if scan_factor is not None:  # the records _evaluate runs, the holding force kept at the end
        ff = suspension_feedforward(fe, setup.measured, profile)
        ff = np.vstack(
            [ff[setup.loop_delay_samples :], ff[-1:].repeat(setup.loop_delay_samples, 0)]
        )
        scan = (profile.position, ff)
    for rho in rms_factors:
        t = time.perf_counter()
        try:
            K, settings = design_youla_band(
                fe, setup, K0, measured, rms_factor=rho, f1_hz=f1 if band_f1 is None else band_f1,
                scan=scan, scan_factor=scan_factor or 1.0, k_std=k_std,
            )  # fmt: skip
        except Exception as e:  # an infeasible program: the row says so
            print(f"   youla rms {rho:g}: no design ({type(e).__name__}: {e}) after "
                  f"{time.perf_counter() - t:.1f} s")  # fmt: skip
            continue
        name = f"youla rms {rho:g}" + ("" if scan is None else f" scan {scan_factor:g}")
        out[name] = _evaluate(plant, fe, K, setup, f1, profile, lines, time.perf_counter() - t)
        out[name]["settings"] = settings
        if out[name]["stable"]:
            out[name]["z_rms_exact_m"] = _exact_z_rms(plant, setup, K)
    return out


def _line(name, r):
    loops = r["analysis"]["loops"]
    sp = 20 * np.log10(max(lp["s_peak"] for lp in loops))
    fc = min(lp["crossover_hz"] for lp in loops)
    if not r["stable"]:
        return f"   {name:<12} unstable on the true beam (|S|max {sp:.2f} dB)"
    return (
        f"   {name:<12} |S|max {sp:5.2f} dB  fc min {fc:6.2f} Hz  z@f1 "
        f"{r['disturbance']['z_mode1_asd_m_rthz'] * 1e9:7.2f} nm/rtHz  |d->z|@f1 "
        f"{r['dz_band_peak_db']:6.2f} dB  z rms {r['disturbance']['z_rms_m'] * 1e9:7.1f} nm  "
        f"scan z rms {r['scan']['z_rms_m'] * 1e9:7.1f} nm  (design {r['design_s']:.1f} s)"
    )


def _ratio(res, other="inferential"):
    a, b = res["pid-notch"], res[other]
    if not (a["stable"] and b["stable"]):
        return "   a design is unstable on the true beam"
    da, db = a["disturbance"], b["disturbance"]
    f1 = reduction_db(da["z_mode1_asd_m_rthz"], db["z_mode1_asd_m_rthz"])
    rms = reduction_db(da["z_rms_m"], db["z_rms_m"])
    sc = reduction_db(a["scan"]["z_rms_m"], b["scan"]["z_rms_m"])
    exact = a["dz_band_peak_db"] - b["dz_band_peak_db"]
    return (
        f"   {other} vs pid-notch: z at f1 {f1:+.1f} dB (exact {exact:+.1f} dB), "
        f"z rms {rms:+.1f} dB, scan z rms {sc:+.1f} dB"
    )


def main(
    parts="12", rms_factors=(1.0,), scan_factor=None, models=("updated",), measured_specs=("truth",)
):
    from controllers.inferential import analysis_lines, point_model

    plant = beam()
    fes = _models(plant)
    f_modes = solve_modes(*fes["updated"].matrices(), 6).freq_hz
    f1 = float(f_modes[f_modes > 10.0][0])
    limits = ScanLimits(0.02, 2.0, 400.0, 1e5)
    profile = scan(0.02, 0.002, limits, plant.fs, lead_s=0.05, settle_s=0.3)
    print(f"first flexible mode (updated FE) {f1:.3f} Hz; band +-10 %; loop delay 1 sample")
    for z in ("s3", "s4") if "1" in parts else ():
        full = point_model(
            fes["updated"], measured=MEASURED, z=z, max_freq_hz=1024, rigid_threshold_hz=1e-3
        )
        lines = analysis_lines(plant.fs, full, n_log=2000)
        for model, fe in fes.items():
            setup = PointSetup(MEASURED, z, plant.fs, 1, 2.0)
            res = _run(plant, fe, setup, f1, profile, lines)
            print(f"1. z = {z}, {model} FE model, |S_ii| <= 2 on the model")
            for name, r in res.items():
                print(_line(name, r))
            print(_ratio(res))
    full = point_model(
        fes["updated"], measured=MEASURED, z="s3", max_freq_hz=1024, rigid_threshold_hz=1e-3
    )
    lines = analysis_lines(plant.fs, full, n_log=2000)
    for ms in (2.5,) if "2" in parts else ():
        setup = PointSetup(MEASURED, "s3", plant.fs, 1, ms)
        res = _run(plant, fes["updated"], setup, f1, profile, lines)
        print(f"2. z = s3, updated FE model, |S_ii| <= {ms:g} ({20 * np.log10(ms):.2f} dB)")
        for name, r in res.items():
            print(_line(name, r))
        print(_ratio(res))
    if "4" in parts:
        setup = PointSetup(MEASURED, "s3", plant.fs, 1, 2.0)
        t = time.perf_counter()
        k_ref, _ = design_point(fes["updated"], setup, "pid-notch")
        ref = _evaluate(plant, fes["updated"], k_ref, setup, f1, profile, lines,
                        time.perf_counter() - t)  # fmt: skip
        ref["z_rms_exact_m"] = _exact_z_rms(plant, setup, k_ref)
        print(_line("pid-notch (updated FE, reference)", ref))
        for spec in measured_specs:
            for model in models:
                fe = fes[model]
                measured, k_std, label = _measured(plant, setup, spec, fe)
                fm = solve_modes(*fe.matrices(), 6).freq_hz
                band_f1 = float(fm[fm > 10.0][0])
                res = _run_youla(plant, fe, setup, f1, profile, lines, measured, rms_factors,
                                 scan_factor, band_f1=band_f1, k_std=k_std)  # fmt: skip
                print(f"4. z = s3, {model} FE model (band at its f1 {band_f1:.2f} Hz), youla band "
                      f"peak around pid-notch on the same model, measured loop: {label}, "
                      "broadband z rms <= rms_factor x pid-notch's on the model")  # fmt: skip
                k0 = res["pid-notch"]["z_rms_exact_m"]
                for name, r in res.items():
                    print(_line(name, r))
                    if "z_rms_exact_m" in r:
                        zr = r["z_rms_exact_m"]
                        print(f"   z rms exact (Lyapunov, true beam) {zr * 1e9:.1f} nm, "
                              f"{reduction_db(k0, r['z_rms_exact_m']):+.2f} dB vs pid-notch, "
                              f"{reduction_db(ref['z_rms_exact_m'], r['z_rms_exact_m']):+.2f} dB "
                              "vs pid-notch on the updated FE")  # fmt: skip
                    if name != "pid-notch":
                        print("   on the model:", r["settings"])
                        if r["stable"]:
                            print(_ratio(res, name))
                            both = {"pid-notch": ref, name: r}
                            print(_ratio(both, name).replace("vs pid-notch",
                                  "vs pid-notch on the updated FE"))  # fmt: skip


def _measured(plant, setup, spec: str, fe=None):
    """(measured, k_std, label) of a ``--measured`` item: ``truth`` (the true discrete loop,
    a study), ``model`` (the design model's own loop: no model error, the design trusts
    ``fe``; what a design without a measurement of the loop does) or
    ``frf:NOISE:FMAX[:KSTD]`` (a simulated FRF of the measured loop, 0.25 Hz lines to FMAX
    Hz, NOISE relative per element as simulated_frf's, seed 17, its spread KSTD (default 3)
    sigma). The FRF is the sampled loop's (the true discrete loop's
    response with the hold and the loop delay divided out, spec 1b), as a measurement in
    the running loop sees it: simulated_frf's continuous response times the hold differs
    from it by aliasing (2e-4 at 200 Hz, 0.6 % at 500 Hz, 24 % at 900 Hz)."""
    if spec == "truth":
        return _true_measured_loop(plant, setup), 3.0, "true loop (exact)"
    if spec == "model":
        from controllers.inferential import measured_model, point_model
        from workbench.loop import discrete_plant

        full = point_model(fe, measured=setup.measured, z=setup.z, max_freq_hz=setup.fs / 2,
                           rigid_threshold_hz=1e-3)  # fmt: skip
        G = discrete_plant(measured_model(full, setup.measured).to_lti(), setup.fs,
                           setup.loop_delay_samples)  # fmt: skip
        return G, 3.0, "the design model's own (no measurement: the model trusted)"
    kind, noise, fmax, *rest = spec.split(":")
    if kind != "frf":
        raise SystemExit(
            f"--measured: expected truth, model or frf:NOISE:FMAX[:KSTD], got {spec!r}"
        )
    k_std = float(rest[0]) if rest else 3.0
    data = simulated_loop_frf(plant, setup, np.random.default_rng(17), df_hz=0.25,
                              f_max_hz=float(fmax), noise_rel=float(noise))  # fmt: skip
    return data, k_std, f"FRF {float(noise) * 100:g} % to {data.freq[-1]:g} Hz, k_std {k_std:g}"


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="12", help="parts to run, e.g. 12 or 4 (slow: ~min each)")
    ap.add_argument("--rms-factors", default="1", help="part 4: comma-separated, e.g. 1,1.5,2,3")
    ap.add_argument("--scan-factor", type=float, default=None, help="part 4: bound the scan too")
    ap.add_argument("--models", default="updated", help="part 4: FE models, e.g. updated,prior")
    ap.add_argument("--measured", default="truth",
                    help="part 4: the measured loop(s): truth, model, frf:NOISE:FMAX[:KSTD], e.g. "
                         "frf:0.01:1024:3 (comma-separated)")  # fmt: skip
    a = ap.parse_args()
    main(a.parts, tuple(float(x) for x in a.rms_factors.split(",")), a.scan_factor,
         tuple(a.models.split(",")), tuple(a.measured.split(",")))  # fmt: skip
