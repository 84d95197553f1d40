"""Youla-parameter designs (controllers.youla): the affine maps against the realized
controller's loop, internal stability for any stable Q, the H-inf optimum against the
Riccati synthesis, the figures of the two programs re-checked on dense grids, refusals."""

from __future__ import annotations

import control
import numpy as np
import pytest

from controllers.hinf import design_hinf_mixed, weight
from controllers.protocol import StateSpaceController
from controllers.youla import (
    _basis_frf,
    closed_loop_error,
    interaction_bound,
    laguerre_basis,
    max_bandwidth,
    min_band_peak,
    min_mixed_sensitivity,
    model_error,
    reduce_loop,
    unmeasured_bound,
    youla_controller,
    youla_maps,
)
from workbench.core.errors import InputError
from workbench.core.lti import frf, zoh_frf
from workbench.io.formats import FrfData
from workbench.loop import loop_frf, screen_loops
from workbench.sim import closed_loop_matrices

FS = 1000.0
DT = 1 / FS


def _static(D, ny, nu):
    return StateSpaceController(np.zeros((0, 0)), np.zeros((0, ny)), np.zeros((nu, 0)),
                                np.reshape(D, (nu, ny)), FS)  # fmt: skip


def _mimo_rigid():
    """2 x 2: two coupled double integrators (masses 1, 2 kg) behind ZOH + one-sample delay."""
    Gc = control.ss(np.kron(np.eye(2), [[0, 1], [0, 0]]),
                    np.array([[0, 0], [1.0, 0.3], [0, 0], [0.2, 0.5]]),
                    np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), np.zeros((2, 2)))  # fmt: skip
    G = control.sample_system(Gc, DT, "zoh")
    delay = control.ss(np.zeros((2, 2)), np.eye(2), np.eye(2), np.zeros((2, 2)), DT)
    return G * delay


def _pd(G, fc=20.0):
    """A decentralized lead (PD + low-pass) that stabilizes _mimo_rigid (checked)."""
    wc = 2 * np.pi * fc
    lead = control.tf([1 / (wc / 3), 1], [1 / (wc * 3), 1]) * wc**2 / 3
    Kd = control.ss(control.c2d(lead, DT, "tustin"))
    K = control.append(Kd, 2 * Kd)
    return StateSpaceController(K.A, K.B, K.C, K.D, FS, ("y1", "y2"), ("u1", "u2"))


def test_laguerre_chain_matches_the_closed_form():
    f = np.geomspace(1, FS / 2, 50)
    for pole in (0.0, 0.6, -0.3):
        A, B, M = laguerre_basis(6, pole)
        chain = frf(control.ss(A, B[:, None], M, np.zeros((6, 1)), DT), f)[:, :, 0]
        assert np.allclose(chain, _basis_frf(6, pole, f, FS)[:, 1:], atol=1e-12)
    # orthonormal on the unit circle: the Gram matrix of the impulse responses is I
    A, B, M = laguerre_basis(5, 0.7)
    x, h = B.copy(), []
    for _ in range(400):
        h.append(M @ x)
        x = A @ x
    h = np.array(h)
    assert np.allclose(h.T @ h, np.eye(5), atol=1e-10)


def test_affine_maps_equal_the_realized_controllers_loop():
    G = _mimo_rigid()
    K0 = _pd(G)
    assert screen_loops(G, K0)[0]
    Gz = control.ss(G.A, G.B, 0.5 * (G.C[:1] + G.C[1:]), np.zeros((1, 2)), DT)  # the midpoint
    f = np.geomspace(0.5, FS / 2, 300)
    maps = youla_maps(G, K0, f, Gz=Gz, n_basis=8, pole=0.5)
    rng = np.random.default_rng(3)
    for scale in (0.0, 1.0, 30.0):
        theta = scale * rng.standard_normal(int(np.prod(maps.shape_q)))
        K = youla_controller(maps, theta)
        # internal stability for ANY stable Q (here random, large)
        Ks = K.statespace()
        Acl = closed_loop_matrices((G.A, G.B, G.C, G.D), (Ks.A, Ks.B, Ks.C, Ks.D))[0]
        assert np.max(np.abs(np.linalg.eigvals(Acl))) < 1.0
        _, L = loop_frf(G, K, f)
        S = np.linalg.inv(np.eye(2) + L)
        assert np.allclose(S, maps.sensitivity(theta), atol=1e-9)
        # T_dz = Gz (I + K G)^-1 from the realized controller, independently
        Kf, Gf = frf(K.statespace(), f), frf(G, f)
        Tdz = frf(Gz, f) @ np.linalg.inv(np.eye(2) + Kf @ Gf)
        assert np.allclose(Tdz, maps.z_response(theta), atol=1e-9)
        for i in range(2):
            c0, C = maps.sensitivity_affine(i)
            assert np.allclose(c0 + C @ theta, S[:, i, i], atol=1e-9)
        c0, C = maps.z_affine(0)
        assert np.allclose(c0 + C @ theta, Tdz[:, 0, :], atol=1e-9)


def test_mixed_sensitivity_optimum_equals_the_riccati_gamma():
    """The same H-inf problem two ways: Q on an FIR basis (grid) and SB10AD (state space)."""
    wn = 2 * np.pi * 100
    Gc = control.tf([2 * np.pi * 30], [1, 2 * np.pi * 30]) * control.tf(
        [wn**2], [1, 2 * 0.05 * wn, wn**2]
    )
    G = control.ss(control.c2d(Gc, DT, "zoh"))
    W1, W3 = weight(100.0, 20.0, 0.5, FS), weight(0.5, 150.0, 100.0, FS)
    _, rep = design_hinf_mixed(G, W1, None, W3)
    f = np.geomspace(0.1, FS / 2, 800)
    maps = youla_maps(G, _static(0.0, 1, 1), f, n_basis=40, pole=0.0)
    d = min_mixed_sensitivity(maps, frf(W1, f)[:, 0, 0], frf(W3, f)[:, 0, 0])
    # the basis and the grid restrict Q: from above, to 1e-3 (measured 1e-5 at n = 40)
    assert d.value == pytest.approx(rep.gamma_opt, rel=1e-3)
    assert d.value >= rep.gamma_opt * (1 - 1e-3)
    assert screen_loops(G, d.controller)[0]


def _template_fb(f, S, slope):
    """Largest grid line fb with |S(f)| <= (f/fb)^slope for every f <= fb (independent)."""
    a = np.abs(S)
    ok = [fb for fb in f if np.all(a[f <= fb] <= (f[f <= fb] / fb) ** slope)]
    return max(ok) if ok else 0.0


def test_max_bandwidth_meets_its_template_and_beats_k0():
    G = _mimo_rigid()
    K0 = _pd(G)
    f = np.geomspace(0.5, FS / 2, 150)
    maps = youla_maps(G, K0, f, n_basis=8, pole=0.6)
    _, L0 = loop_frf(G, K0, f)
    S0 = np.linalg.inv(np.eye(2) + L0)
    d = max_bandwidth(maps, ms_max=2.0, slope=2.0, level=1.0, target=0)
    fb0 = _template_fb(f, S0[:, 0, 0], 2.0)
    assert d.value > 1.5 * fb0  # K0 is a slow lead: Q has room
    fd = np.geomspace(0.5, FS / 2, 4000)  # a 25x denser grid than the design's
    stable, peak, fc = screen_loops(G, d.controller, freq_hz=fd)
    assert stable and np.max(peak) <= 2.0 * 1.02
    _, L = loop_frf(G, d.controller, f)
    S = np.linalg.inv(np.eye(2) + L)
    low = f <= d.value
    assert np.all(np.abs(S[low, 0, 0]) <= (f[low] / d.value) ** 2 * (1 + 1e-6))
    # -3 dB bandwidth (flat template) on both loops, loop 1 at half loop 0's: each meets it
    d3 = max_bandwidth(maps, ms_max=2.0, ratios=[1.0, 0.5])
    _, L = loop_frf(G, d3.controller, f)
    S = np.linalg.inv(np.eye(2) + L)
    for i, fb in enumerate((d3.value, 0.5 * d3.value)):
        assert np.all(np.abs(S[f <= fb, i, i]) <= 1 / np.sqrt(2) * (1 + 1e-4))


def test_min_band_peak_lowers_the_peak_within_the_bound():
    G = _mimo_rigid()
    K0 = _pd(G)
    Gz = control.ss(G.A, G.B, 0.5 * (G.C[:1] + G.C[1:]), np.zeros((1, 2)), DT)
    f = np.geomspace(0.5, FS / 2, 150)
    maps = youla_maps(G, K0, f, Gz=Gz, n_basis=8, pole=0.6)
    band = (7.0, 13.0)
    sel = (f >= band[0]) & (f <= band[1])
    peak0 = np.max(np.linalg.norm(maps.z_response(np.zeros(maps.theta_size))[sel][:, 0], axis=1))
    d = min_band_peak(maps, band, ms_max=2.0)
    assert d.value < 0.5 * peak0
    stable, peak, _ = screen_loops(G, d.controller, freq_hz=np.geomspace(0.5, FS / 2, 4000))
    assert stable and np.max(peak) <= 2.0 * 1.02
    # never worse than K0 outside the band: costs some of the gain in it, holds on the grid
    e = min_band_peak(maps, band, ms_max=2.0, elsewhere=1.0)
    assert d.value * (1 - 1e-6) <= e.value < peak0
    Kf, Gf = frf(e.controller.statespace(), f), frf(G, f)
    T = np.linalg.norm((frf(Gz, f) @ np.linalg.inv(np.eye(2) + Kf @ Gf))[:, 0], axis=1)
    T0 = np.linalg.norm(maps.z_response(np.zeros(maps.theta_size))[:, 0], axis=1)
    out = (f < band[0]) | (f > band[1])
    assert np.all(T[out] <= T0[out] * (1 + 1e-5))


def test_refusals_are_one_line():
    G = _mimo_rigid()
    f = np.geomspace(1, FS / 2, 50)
    calls = [
        ("stabilizes", lambda: youla_maps(G, _static(np.zeros(4), 2, 2), f)),  # rigid: K0 = 0
        ("expected 2 inputs", lambda: youla_maps(G, _static(0.0, 1, 1), f)),
        ("grid", lambda: youla_maps(G, _pd(G), np.array([1.0, FS]))),
        ("pole", lambda: laguerre_basis(4, 1.0)),
        ("Gz", lambda: min_band_peak(youla_maps(G, _pd(G), f), (10, 20))),
        ("2 grid lines", lambda: min_band_peak(youla_maps(G, _pd(G), f, Gz=G[0, :]), (10, 10.1))),
    ]
    for match, call in calls:
        with pytest.raises(InputError, match=match) as exc:
            call()
        assert "\n" not in str(exc.value)


def test_t_bound_holds_where_the_model_is_not_trusted():
    """|T_ii| = |1 - S_ii| <= t_max above f_from: costs template bandwidth, holds on the grid."""
    G = _mimo_rigid()
    K0 = _pd(G)
    f = np.geomspace(0.5, FS / 2, 100)
    maps = youla_maps(G, K0, f, n_basis=6, pole=0.6)
    free = max_bandwidth(maps, ms_max=2.0, slope=2.0, level=1.0, target=0)
    d = max_bandwidth(maps, ms_max=2.0, slope=2.0, level=1.0, target=0, t_bound=(150.0, 0.3))
    assert d.value <= free.value * (1 + 1e-9)
    _, L = loop_frf(G, d.controller, f)
    T = np.eye(2) - np.linalg.inv(np.eye(2) + L)
    hi = f >= 150.0
    for i in range(2):
        assert np.all(np.abs(T[hi, i, i]) <= 0.3 * (1 + 1e-4))


def _mimo_rigid_with_mode(f_mode=620.0, zeta=0.01, gain=0.3):
    """_mimo_rigid plus a mode the model lacks, above Nyquist (aliased to 380 Hz), coupling both."""
    Gc = control.ss(np.kron(np.eye(2), [[0, 1], [0, 0]]),
                    np.array([[0, 0], [1.0, 0.3], [0, 0], [0.2, 0.5]]),
                    np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), np.zeros((2, 2)))  # fmt: skip
    w = 2 * np.pi * f_mode
    mode = control.ss([[0, 1], [-(w**2), -2 * zeta * w]], [[0, 0], [gain, 0.5 * gain]],
                      [[1.0, 0], [0.8, 0]], np.zeros((2, 2)))  # fmt: skip
    delay = control.ss(np.zeros((2, 2)), np.eye(2), np.eye(2), np.zeros((2, 2)), DT)
    return control.sample_system(control.parallel(Gc, mode), DT, "zoh") * delay


def test_model_error_keeps_the_bounds_on_the_measured_plant():
    """Designed on a model without the mode: unstable on the plant; with the model error
    (the plant known exactly, or as a ZOH-compensated FRF): stable, |S_ii| <= 2 on it."""
    G, Gt = _mimo_rigid(), _mimo_rigid_with_mode()
    K0 = _pd(G)
    f = np.geomspace(0.5, FS / 2, 120)
    fd = np.geomspace(0.5, FS / 2, 4000)
    assert screen_loops(Gt, K0, freq_hz=fd)[0]  # K0 itself is robust
    plain = max_bandwidth(youla_maps(G, K0, f, n_basis=6, pole=0.6), ms_max=2.0, slope=2.0,
                          level=1.0, target=0)  # fmt: skip
    assert not screen_loops(Gt, plain.controller, freq_hz=fd)[0]
    exact = model_error(Gt, G)
    d = max_bandwidth(youla_maps(G, K0, f, n_basis=6, pole=0.6, error=exact), ms_max=2.0,
                      slope=2.0, level=1.0, target=0)  # fmt: skip
    stable, peak, _ = screen_loops(Gt, d.controller, freq_hz=fd)
    assert stable and np.max(peak) <= 2.0 * 1.02
    assert d.value > 1.5 * _template_fb(f, np.linalg.inv(np.eye(2) + loop_frf(G, K0, f)[1])
                                        [:, 0, 0], 2.0)  # fmt: skip
    # the same error from a measured FRF: the spec's FRF has the hold divided out
    fl = np.arange(1.0, FS / 2, 1.0)
    meas = FrfData(fl, frf(Gt, fl) / zoh_frf(fl, FS)[:, None, None], fs=FS,
                   G_var=np.full((fl.size, 2, 2), 1e-12))  # fmt: skip
    e = model_error(meas, G, k_std=3.0)
    d_exact, _ = exact.at(fl)
    assert np.allclose(e.delta, d_exact, rtol=1e-9, atol=1e-15)
    assert np.allclose(e.spread, 3e-6 * np.abs(zoh_frf(fl, FS))[:, None, None])
    _, col = e.at(fl)  # per input column: ||spread[:, a]|| over the outputs
    assert np.allclose(col, 3e-6 * np.sqrt(2) * np.abs(zoh_frf(fl, FS))[:, None])
    # one-sample-shifted: an FRF from the plant input lacks the loop delay G holds
    e1 = model_error(FrfData(fl, meas.G * np.exp(2j * np.pi * fl / FS)[:, None, None], fs=FS),
                     G, loop_delay_samples=1)  # fmt: skip
    assert np.allclose(e1.delta, d_exact, rtol=1e-9, atol=1e-15)
    with pytest.raises(InputError, match="expected an FRF of shape") as exc:
        model_error(FrfData(fl, meas.G[:, :1]), G)
    assert "\n" not in str(exc.value)


def test_interaction_bound_keeps_the_decentralized_loop_stable():
    """t(f) = gamma / rho(|E|): for 2 x 2, rho(|E|) = sqrt|G12 G21 / (G11 G22)| (closed form);
    two SISO designs, each on its channel with its error and |T_ii| <= t, make a stable
    MIMO loop on the measured plant, |S_ii| near the channels' bound (this plant's
    interaction is mild: the stage's, where it matters, is in benchmarks/bench_bandwidth)."""
    G, Gt = _mimo_rigid(), _mimo_rigid_with_mode()
    err = model_error(Gt, G)
    f = np.geomspace(0.5, FS / 2, 120)
    Ft = frf(Gt, f)
    rho = np.sqrt(np.abs(Ft[:, 0, 1] * Ft[:, 1, 0] / (Ft[:, 0, 0] * Ft[:, 1, 1])))
    t = interaction_bound(err, gamma=0.7)
    assert np.allclose(t(f), 0.7 / rho, rtol=1e-9)
    K0 = _pd(G).statespace()
    fd = np.geomspace(0.5, FS / 2, 4000)

    def decentralized(t_bound):
        blocks = []
        for i in range(2):
            Gi = control.minreal(G[i, i], verbose=False)
            Ki = StateSpaceController(*control.ssdata(K0[i, i]), FS)
            maps = youla_maps(Gi, Ki, f, n_basis=6, pole=0.6, error=err.channel(i))
            d = max_bandwidth(maps, ms_max=2.0, slope=2.0, level=1.0, t_bound=t_bound)
            blocks.append(d.controller.statespace())
        K = control.append(*blocks)
        return StateSpaceController(K.A, K.B, K.C, K.D, FS)

    stable, peak, _ = screen_loops(Gt, decentralized(t), freq_hz=fd)
    assert stable and np.max(peak) <= 2.0 * 1.25  # the interaction moves |S_ii| a little
    with pytest.raises(InputError, match="gamma"):
        interaction_bound(err, gamma=1.0)


def test_closed_loop_error_is_what_one_loop_sees_of_the_mimo_loop():
    """g_i = G_model,ii + closed_loop_error: 1 / (1 + k_i g_i) is S_ii of the MIMO loop on the
    measured plant, (I + Gt K)^-1 inverted directly (1e-9); from an FRF the spread carries the
    other elements' noise through the closed loop (the 2 x 2 closed form); one loop re-designed
    on it (the other fixed) holds its |S_ii| <= 2 on the measured MIMO loop, stable."""
    G, Gt = _mimo_rigid(), _mimo_rigid_with_mode()
    K0 = _pd(G).statespace()
    blocks = [K0[0, 0], K0[1, 1]]
    f = np.geomspace(0.5, FS / 2, 300)
    S = np.linalg.inv(np.eye(2) + frf(Gt, f) @ frf(K0, f))
    for i in range(2):
        ce = closed_loop_error(model_error(Gt, G), i, blocks, f)
        g = frf(G[i, i], f)[:, 0, 0] + ce.delta[:, 0, 0]
        assert np.allclose(1 / (1 + frf(blocks[i], f)[:, 0, 0] * g), S[:, i, i], rtol=1e-9)
        assert not np.any(ce.spread)  # an exact measurement
    fl = np.arange(1.0, FS / 2, 1.0)
    var = np.full((fl.size, 2, 2), 1e-10)
    meas = FrfData(fl, frf(Gt, fl) / zoh_frf(fl, FS)[:, None, None], fs=FS, G_var=var)
    fm = fl[::7]  # on the measured lines: no interpolation
    ce = closed_loop_error(model_error(meas, G, k_std=3.0), 1, blocks, fm)
    own = 3e-5 * np.abs(zoh_frf(fm, FS))  # every element's: 3 std, hold put back
    Gf, k0 = frf(Gt, fm), frf(blocks[0], fm)[:, 0, 0]
    Y = np.abs(Gf[:, 1, 0] * k0 / (1 + Gf[:, 0, 0] * k0))  # G_10 k_0 (1 + G_00 k_0)^-1
    X = np.abs(k0 * Gf[:, 0, 1] / (1 + Gf[:, 0, 0] * k0))
    assert np.allclose(ce.spread[:, 0, 0], own * (1 + Y) * (1 + X), rtol=1e-9)
    # loop 1 re-designed on what it sees, loop 0 fixed: the MIMO |S_11| holds the bound
    ce = closed_loop_error(model_error(Gt, G), 1, blocks, np.geomspace(0.5, FS / 2, 2000))
    K1 = StateSpaceController(*control.ssdata(blocks[1]), FS)
    d = max_bandwidth(youla_maps(control.minreal(G[1, 1], verbose=False), K1, f, n_basis=6,
                                 pole=0.6, error=ce), ms_max=2.0, slope=2.0, level=1.0)  # fmt: skip
    K = control.append(blocks[0], d.controller.statespace())
    fd = np.geomspace(0.5, FS / 2, 4000)
    stable, peak, _ = screen_loops(Gt, StateSpaceController(K.A, K.B, K.C, K.D, FS), freq_hz=fd)
    assert stable and peak[1] <= 2.0 * 1.02, peak


def test_reduce_loop_keeps_the_measured_bound_at_a_lower_order():
    """A robust SISO design cut by balanced truncation: the order falls, and the cut
    controller's loop on the measured plant is stable with |S| <= 2 (screen_loops on a
    dense grid, not the certificate's lines); a bound the full design does not meet
    returns the full design."""
    Gt = control.minreal(_mimo_rigid_with_mode()[0, 0], verbose=False)
    G = control.minreal(_mimo_rigid()[0, 0], verbose=False)
    K0 = _pd(_mimo_rigid()).statespace()
    k0 = StateSpaceController(*control.ssdata(control.minreal(K0[0, 0], verbose=False)), FS)
    f = np.geomspace(0.5, FS / 2, 200)
    d = max_bandwidth(youla_maps(G, k0, f, n_basis=12, pole=0.6, error=model_error(Gt, G)),
                      ms_max=1.9, slope=2.0, level=1.0)  # fmt: skip
    K = d.controller.statespace()
    fl = np.geomspace(0.5, FS / 2, 3000)
    Kr, order = reduce_loop(K, frf(Gt, fl)[:, 0, 0], fl, 2.0)
    assert order == Kr.nstates < K.nstates
    fd = np.geomspace(0.5, FS / 2, 20000)
    stable, peak, _ = screen_loops(Gt, StateSpaceController(*control.ssdata(Kr), FS), freq_hz=fd)
    assert stable and peak[0] <= 2.0 * 1.001, peak
    full_peak = screen_loops(Gt, d.controller, freq_hz=fd)[1][0]
    same, n = reduce_loop(K, frf(Gt, fl)[:, 0, 0], fl, 0.99 * full_peak)
    assert same is K and n == K.nstates


def test_unmeasured_bound_holds_the_baseline_above_the_measured_band():
    """Above the FRF's last line |T| <= |T0| (K0's loop on the model, computed here from the
    loop gain directly); below it the given bound is untouched (here: none, and (f, t)); the
    error of an FRF that stops short is zero above its band (nothing measured), not held."""
    G = control.minreal(_mimo_rigid()[0, 0], verbose=False)
    K0 = _pd(_mimo_rigid()).statespace()
    k0 = StateSpaceController(*control.ssdata(control.minreal(K0[0, 0], verbose=False)), FS)
    f = np.geomspace(1.0, FS / 2, 500)
    L0 = frf(G, f)[:, 0, 0] * frf(k0.statespace(), f)[:, 0, 0]
    T0 = np.abs(L0 / (1 + L0))
    hi = f > 300.0
    t = unmeasured_bound(None, G, k0, 300.0)(f)
    assert np.all(np.isinf(t[~hi])) and np.allclose(t[hi], T0[hi], rtol=1e-9)
    t = unmeasured_bound((100.0, 0.5), G, k0, 300.0)(f)
    assert np.allclose(t[hi], np.minimum(0.5, T0[hi])) and np.all(t[(f >= 100) & ~hi] == 0.5)
    # the error itself: held a line spacing past the FRF's last line, nothing further up
    fl = np.arange(1.0, 301.0, 1.0)
    Gt = _mimo_rigid_with_mode()
    meas = FrfData(fl, frf(Gt, fl) / zoh_frf(fl, FS)[:, None, None], fs=FS,
                   G_var=np.full((fl.size, 2, 2), 1e-12))  # fmt: skip
    e = model_error(meas, _mimo_rigid())
    d, sp = e.at([300.5, 302.0, 450.0])
    assert np.allclose(d[0], e.delta[-1]) and np.all(sp[0] > 0)
    assert not np.any(d[1:]) and not np.any(sp[1:])
