"""workbench.loop against closed forms and python-control on the same discrete loop."""

from __future__ import annotations

import json
import warnings

import control
import numpy as np
import pytest

from workbench.core.errors import InputError
from workbench.core.lti import frf
from workbench.io.formats import FrfData
from workbench.loop import analyze_loop, save_loop_plots, screen_crossover, screen_loops

M = 2.0  # kg


def _lead(fc: float, a: float, fs: float):
    """Continuous lead for 1/(M s^2): zero wc/sqrt(a), pole wc sqrt(a), |L(j wc)| = 1; Tustin."""
    wc = 2 * np.pi * fc
    shape = control.tf([1 / (wc / np.sqrt(a)), 1], [1 / (wc * np.sqrt(a)), 1])
    k = M * wc**2 / abs(shape(1j * wc))
    return control.ss(control.c2d(k * shape, 1 / fs, "tustin"))


def _plant():
    return control.ss(control.tf([1.0], [M, 0, 0]))


def _frf_data(fs: float, n: int = 4000) -> FrfData:
    f = np.logspace(np.log10(fs / 2e4), np.log10(fs / 2 * 0.999), n)
    return FrfData(freq=f, G=frf(_plant(), f))


@pytest.mark.parametrize("a", [4.0, 10.0])
def test_double_integrator_lead_closed_form(a):
    fs, fc = 20000.0, 50.0
    res = analyze_loop(_plant(), _lead(fc, a, fs))
    lp = res.loops[0]
    # closed form: crossover at wc, phase margin asin((a-1)/(a+1)) less the ZOH's half sample
    pm = np.degrees(np.arcsin((a - 1) / (a + 1))) - 180.0 * fc / fs
    assert lp.crossover_hz == pytest.approx(fc, rel=5e-3)
    assert lp.phase_margin_deg == pytest.approx(pm, abs=0.3)
    assert lp.phase_margin_hz == pytest.approx(fc, rel=5e-3)
    assert res.stable
    # the same on FRF data of the continuous plant (ZOH factor applied by the analysis)
    lf = analyze_loop(_frf_data(fs), _lead(fc, a, fs)).loops[0]
    assert lf.crossover_hz == pytest.approx(fc, rel=5e-3)
    assert lf.phase_margin_deg == pytest.approx(pm, abs=0.3)


@pytest.mark.parametrize("delay", [0, 2])
def test_discrete_against_python_control(delay):
    fs = 5000.0
    K = _lead(100.0, 9.0, fs)
    Pd = control.c2d(_plant(), 1 / fs, "zoh")
    zd = control.tf([1], [1] + [0] * delay, 1 / fs)
    Ld = control.tf(Pd) * zd * control.tf(K)
    gm, pm, _sm, wg, wp, _ws = control.stability_margins(Ld, method="poly")
    res = analyze_loop(Pd, K, loop_delay_samples=delay)
    lp = res.loops[0]
    assert lp.phase_margin_deg == pytest.approx(pm, abs=0.05)
    assert lp.phase_margin_hz == pytest.approx(wp / (2 * np.pi), rel=1e-3)
    assert lp.gain_margin == pytest.approx(gm, rel=1e-3)
    assert lp.gain_margin_hz == pytest.approx(wg / (2 * np.pi), rel=1e-3)
    # |S|inf against a dense grid of python-control's own frequency response
    w = np.linspace(1e-3, np.pi * fs * 0.9999, 200001)
    S = control.feedback(1, Ld)
    s_dense = np.max(np.abs(S.frequency_response(w).complex.ravel()))
    assert lp.s_peak == pytest.approx(s_dense, rel=2e-3)
    # the same analysis on the continuous plant: exact ZOH discretization inside
    assert analyze_loop(_plant(), K, loop_delay_samples=delay).loops[0].s_peak == pytest.approx(
        lp.s_peak, rel=1e-6
    )
    # disk margin: python-control's on the model, the formula on FRF lines
    dm, _dgm, dpm = control.disk_margins(Ld, w[::20], skew=0.0)
    assert lp.disk_margin == pytest.approx(dm, rel=1e-3)
    assert lp.disk_phase_margin_deg == pytest.approx(dpm, rel=1e-3)
    lf = analyze_loop(_frf_data(fs, 8000), K, loop_delay_samples=delay).loops[0]
    # FRF path: the plant's response times the ZOH factor, no aliasing: close, not equal
    assert lf.disk_margin == pytest.approx(dm, rel=0.02)


@pytest.mark.parametrize("gain", [0.05, 0.3, 1.0, 3.0, 8.0, 30.0])
def test_stability_against_closed_loop_poles(gain):
    fs = 5000.0
    K = _lead(100.0, 9.0, fs) * gain
    Pd = control.c2d(_plant(), 1 / fs, "zoh")
    zd = control.tf([1], [1, 0], 1 / fs)
    cl = control.feedback(control.ss(Pd) * control.ss(zd) * K, 1)
    stable = bool(np.max(np.abs(cl.poles())) < 1)
    res = analyze_loop(_plant(), K, loop_delay_samples=1)
    assert res.stable == stable
    assert res.max_pole_radius == pytest.approx(np.max(np.abs(cl.poles())), rel=1e-6)
    resf = analyze_loop(_frf_data(fs), K, loop_delay_samples=1)
    assert resf.stable == stable
    assert (resf.loops[0].unstable_poles == 0) == stable


def test_scaled_sigma_max_against_direct_search():
    """min_D sigma(D M D^-1): independent Nelder-Mead search on random 4 x 4 lines, and bounds."""
    from scipy.optimize import minimize

    from workbench.loop import scaled_sigma_max

    rng = np.random.default_rng(3)
    M = rng.standard_normal((40, 4, 4)) + 1j * rng.standard_normal((40, 4, 4))
    M *= np.array([1.0, 1e3, 1.0, 1e-2])[:, None] / np.array([1.0, 1e2, 1e-1, 1.0])
    got = scaled_sigma_max(M)

    def sig(lv, Mk):
        d = np.exp(np.r_[0.0, lv])
        return np.linalg.svd(d[:, None] * Mk / d[None, :], compute_uv=False)[0]

    ref = [minimize(sig, np.zeros(3), args=(Mk,), method="Nelder-Mead",
                    options={"maxiter": 20000, "xatol": 1e-10, "fatol": 1e-12}).fun
           for Mk in M]  # fmt: skip
    # the maximum over the lines is exact; every line is an upper bound of its minimum
    assert got.max() == pytest.approx(max(ref), rel=1e-6)
    assert np.all(got >= np.array(ref) * (1 - 1e-6))
    assert np.all(got <= np.linalg.svd(M, compute_uv=False)[:, 0] * (1 + 1e-12))
    assert np.all(got >= np.max(np.abs(np.linalg.eigvals(M)), axis=1) * (1 - 1e-9))


def test_coupled_mimo_loop_at_a_time_and_outputs(tmp_path):
    """Loop-at-a-time margins from S_ii (FRF path) equal python-control's on feedback-built L_i."""
    fs = 5000.0
    mix = np.array([[1.0, 0.3], [0.2, 1.0]])
    P = control.ss(np.zeros((4, 4)) + np.eye(4, k=2), np.vstack([np.zeros((2, 2)), mix / M]),
                   np.hstack([np.eye(2), np.zeros((2, 2))]), np.zeros((2, 2)))  # fmt: skip
    P.output_labels = ["x", "y"]
    K1 = _lead(80.0, 9.0, fs)
    K = control.append(K1, 1.3 * K1)
    res = analyze_loop(P, K, loop_delay_samples=1)
    f = np.logspace(np.log10(fs / 2e4), np.log10(fs / 2 * 0.999), 6000)
    resf = analyze_loop(FrfData(freq=f, G=frf(P, f)), K, loop_delay_samples=1)
    assert [lp.name for lp in res.loops] == ["x", "y"]
    for a, b in zip(res.loops, resf.loops):
        assert a.disk_margin == pytest.approx(b.disk_margin, rel=0.02)
        assert a.phase_margin_deg == pytest.approx(b.phase_margin_deg, abs=0.5)
        assert a.crossover_hz == pytest.approx(b.crossover_hz, rel=0.01)
    assert res.stable and resf.stable
    # MIMO peak >= every diagonal peak (sigma_max(S) >= |S_ii|)
    assert res.sigma_max_S_inf >= max(lp.s_peak for lp in res.loops) - 1e-12
    # the unit-free MIMO peak: the same when y is in mm instead of m (it scales S_xy, S_yx)
    assert res.scaled_sigma_max_S_inf <= res.sigma_max_S_inf + 1e-12
    assert res.scaled_sigma_max_S_inf >= max(lp.s_peak for lp in res.loops) - 1e-12
    Pmm = control.ss(P.A, P.B, np.diag([1.0, 1e3]) @ P.C, P.D)
    Kmm = control.append(K1, 1.3e-3 * K1)
    res_mm = analyze_loop(Pmm, Kmm, loop_delay_samples=1)
    assert res_mm.sigma_max_S_inf > 10 * res.sigma_max_S_inf
    assert res_mm.scaled_sigma_max_S_inf == pytest.approx(res.scaled_sigma_max_S_inf, rel=1e-6)
    d = json.loads(res.to_json())
    assert len(d["loops"]) == 2 and d["stable"] is True
    assert "x" in res.table()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        paths = save_loop_plots(res, tmp_path)
    assert len(paths) == 3
    for p in paths:
        with open(p, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"


def test_a_stable_loop_can_show_a_gain_margin_below_one():
    """PID on a double integrator: conditionally stable, GM < 1 (negative dB) yet stable.

    What the odd per-loop figures of a stable loop (GM -9.5 dB) can legitimately be: a
    lower gain margin. The figure equals python-control's, and the loop goes unstable
    just below that gain and stays stable just above it.
    """
    fs, fc, a = 5000.0, 100.0, 9.0
    wc = 2 * np.pi * fc
    shape = control.tf([1 / (wc / np.sqrt(a)), 1], [1 / (wc * np.sqrt(a)), 1])
    shape = shape * control.tf([1, wc / 2], [1, 0])  # PI corner at fc/2: phase < -180 below
    K = control.ss(control.c2d(M * wc**2 / abs(shape(1j * wc)) * shape, 1 / fs, "tustin"))
    Ld = control.tf(control.c2d(_plant(), 1 / fs)) * control.tf([1], [1, 0], 1 / fs)
    gm, pm, _sm, wg, _wp, _ws = control.stability_margins(Ld * control.tf(K), method="poly")
    res = analyze_loop(_plant(), K, loop_delay_samples=1)
    lp = res.loops[0]
    assert res.stable and gm < 1
    assert lp.gain_margin == pytest.approx(gm, rel=1e-4)
    assert lp.gain_margin_hz == pytest.approx(wg / (2 * np.pi), rel=1e-3)
    assert lp.phase_margin_deg == pytest.approx(pm, abs=0.05)
    assert not analyze_loop(_plant(), K * (0.9 * gm), loop_delay_samples=1).stable
    assert analyze_loop(_plant(), K * (1.1 * gm), loop_delay_samples=1).stable


def test_screen_loops_equals_analyze_loop_and_flags_instability():
    """The scans' fast score: the same |S_ii| peaks and crossovers as analyze_loop."""
    fs = 5000.0
    mix = np.array([[1.0, 0.3], [0.2, 1.0]])
    P = control.ss(np.zeros((4, 4)) + np.eye(4, k=2), np.vstack([np.zeros((2, 2)), mix / M]),
                   np.hstack([np.eye(2), np.zeros((2, 2))]), np.zeros((2, 2)))  # fmt: skip
    K1 = _lead(80.0, 9.0, fs)
    K = control.append(K1, 1.3 * K1)
    res = analyze_loop(P, K, loop_delay_samples=1)
    stable, peak, fc = screen_loops(P, K, loop_delay_samples=1)
    assert stable == res.stable is True
    np.testing.assert_allclose(peak, [lp.s_peak for lp in res.loops], rtol=1e-12)
    np.testing.assert_allclose(fc, [lp.crossover_hz for lp in res.loops], rtol=1e-12)
    assert screen_crossover(P, K, loop_delay_samples=1, ms_max=10.0) == pytest.approx(min(fc))
    assert screen_crossover(P, K, loop_delay_samples=1, ms_max=0.99 * max(peak)) == 0.0
    # 30x the gain: unstable (closed-loop poles), no figures
    bad = control.append(30 * K1, 30 * K1)
    assert np.max(np.abs(control.feedback(control.c2d(P, 1 / fs) * bad, np.eye(2)).poles())) > 1
    stable, peak, fc = screen_loops(P, bad)
    assert not stable and np.all(np.isinf(peak)) and np.all(np.isnan(fc))
    assert screen_crossover(P, bad) == 0.0


def test_bad_input():
    with pytest.raises(InputError, match="discrete"):
        analyze_loop(_plant(), control.ss(control.tf([1], [1, 1])))
    K2 = control.append(_lead(50.0, 4.0, 5000.0), _lead(50.0, 4.0, 5000.0))
    with pytest.raises(InputError, match="controller: expected 1 inputs"):
        analyze_loop(_plant(), K2)
    with pytest.raises(InputError, match="loop_delay_samples"):
        analyze_loop(_plant(), _lead(50.0, 4.0, 5000.0), loop_delay_samples=-1)
