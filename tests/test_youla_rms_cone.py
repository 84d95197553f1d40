"""The broadband rms cone of controllers.youla.min_band_peak (``rms_factor``): its figure is
the weighted rms of the realized controller's force -> z response, a design with
rms_factor = 1 is no worse than K0 in rms on the realized loop, bad factors are refused."""

from __future__ import annotations

import control
import numpy as np
import pytest

from controllers.youla import min_band_peak, rms_weights, youla_maps, z_rms, z_rms_exact
from workbench.core.errors import InputError
from workbench.core.lti import frf

FS = 1000.0
DT = 1 / FS
BAND = (25.0, 35.0)


def _loop():
    """(G, Gz, K0): 2 x 2 coupled rigid bodies + a 60 Hz mode behind a ZOH and a one-sample
    delay; z a point between the outputs (G's states); K0 two lead controllers at 20 Hz."""
    A = np.kron(np.eye(2), [[0, 1], [0, 0]])
    B = np.array([[0, 0], [1.0, 0.3], [0, 0], [0.2, 0.5]])
    C = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    w = 2 * np.pi * 60.0
    Gc = control.parallel(
        control.ss(A, B, C, np.zeros((2, 2))),
        control.ss([[0, 1], [-(w**2), -0.02 * w]], [[0, 0], [0.05, -0.03]],
                   [[1.0, 0], [-0.7, 0]], np.zeros((2, 2))),
    )  # fmt: skip
    delay = control.ss(np.zeros((2, 2)), np.eye(2), np.eye(2), np.zeros((2, 2)), DT)
    P = control.sample_system(Gc, DT, "zoh") * delay
    Gz = control.ss(P.A, P.B, 0.5 * (P.C[:1] + P.C[1:]), np.zeros((1, 2)), DT)
    wc = 2 * np.pi * 20.0
    lead = control.tf([1 / (wc / 3), 1], [1 / (wc * 3), 1]) * wc**2 / 3
    Kd = control.ss(control.c2d(lead, DT, "tustin"))
    return P, Gz, control.append(Kd, 2 * Kd)


def _realized_rms(G, Gz, K, f) -> float:
    """sqrt(sum_k w_k ||Gz (I + K G)^-1 (f_k)||^2) from the FRFs of the realized loop on f."""
    Kf = frf(K.statespace() if hasattr(K, "statespace") else K, f)
    T = frf(Gz, f) @ np.linalg.inv(np.eye(2) + Kf @ frf(G, f))
    return float(np.sqrt(np.sum(rms_weights(f, FS) * np.sum(np.abs(T[:, 0]) ** 2, axis=1))))


def test_the_cone_is_the_weighted_rms_of_the_realized_loop():
    """The design's grid figure (the cone's) is the weighted rms of the REALIZED
    controller's Gz Si on the design grid (realization error only: 1e-4), equals the
    exact H2 figure of the realized loop (Lyapunov) to the quadrature's 1 %, and holds its
    bound rms_factor x K0's."""
    G, Gz, K0 = _loop()
    f = np.geomspace(0.5, FS / 2, 400)
    rho = 1.2
    d = min_band_peak(youla_maps(G, K0, f, Gz=Gz, n_basis=8, pole=0.7), BAND, rms_factor=rho)
    got, ref = d.rms
    assert got == pytest.approx(_realized_rms(G, Gz, d.controller, d.maps.f), rel=1e-4)
    assert ref == pytest.approx(_realized_rms(G, Gz, K0, d.maps.f), rel=1e-9)
    assert got == pytest.approx(z_rms(d.maps, d.theta), rel=1e-12)
    assert got == pytest.approx(z_rms_exact(G, Gz, d.controller), rel=1e-2)
    assert ref == pytest.approx(z_rms_exact(G, Gz, K0), rel=1e-2)
    assert got <= rho * ref * (1 + 1e-6)  # the bound, to the solver's tolerance


def test_rms_factor_one_keeps_the_realized_rms_at_k0s():
    """Without the cone the band-peak design's rms of z is well above K0's (the waterbed);
    with rms_factor = 1 the realized loop's rms is not above K0's: exact (Lyapunov) and
    on a dense linear grid (50000 lines, independent of the design's 150), and the band
    peak is still far below K0's."""
    G, Gz, K0 = _loop()
    maps = youla_maps(G, K0, np.geomspace(0.5, FS / 2, 150), Gz=Gz, n_basis=8, pole=0.7)
    k0 = z_rms_exact(G, Gz, K0)
    plain = min_band_peak(maps, BAND)
    assert z_rms_exact(G, Gz, plain.controller) > 1.2 * k0
    d = min_band_peak(maps, BAND, rms_factor=1.0)
    assert z_rms_exact(G, Gz, d.controller) <= k0 * (1 + 1e-9)
    fd = np.linspace(0.01, FS / 2, 50000)
    assert _realized_rms(G, Gz, d.controller, fd) <= _realized_rms(G, Gz, K0, fd) * (1 + 1e-4)
    band = (maps.f >= BAND[0]) & (maps.f <= BAND[1])
    k0_peak = np.max(np.linalg.norm(maps.GzSi0[band, 0], axis=1))
    assert d.value < 0.3 * k0_peak


@pytest.mark.parametrize("bad", [0.5, 0.999, np.nan, np.inf, -1.0])
def test_rms_factor_below_one_or_not_finite_is_refused(bad):
    G, Gz, K0 = _loop()
    maps = youla_maps(G, K0, np.geomspace(1, 400, 30), Gz=Gz, n_basis=2, pole=0.5)
    with pytest.raises(InputError, match="rms_factor: expected a finite factor >= 1") as exc:
        min_band_peak(maps, BAND, rms_factor=bad)
    assert "\n" not in str(exc.value) and f"got {bad}" in str(exc.value)


def test_measured_rows_join_where_the_design_not_k0_meets_the_model_error():
    """_MeasuredDiagonal.extend: lines where K0's ||Delta K0 S0|| is negligible (nominal rows
    only) join the measured-loop rows when a design's ||Delta K S|| is not, centered there
    (the inner bound touches |S_ii| + kappa a m at that design); nothing joins at K0."""
    from controllers.youla import _ERROR_NEGLIGIBLE, _MeasuredDiagonal, _robust_lines, model_error

    G, Gz, K0 = _loop()
    # a 0.1 % gain error of actuator 1: ||Delta K0 S0|| 2e-3 at low frequency, 1e-9 at Nyquist
    Gt = control.ss(G.A, G.B * [1.001, 1.0], G.C, G.D, DT)
    maps = youla_maps(G, K0, np.geomspace(0.5, FS / 2, 120), n_basis=4, pole=0.7,
                      error=model_error(Gt, G))  # fmt: skip
    on = _robust_lines(maps)
    assert 0 < on.sum() < on.size
    md = _MeasuredDiagonal(maps, [0, 1], on.copy())
    assert not md.extend(np.zeros(maps.theta_size))
    theta = np.random.default_rng(5).standard_normal(maps.theta_size) * 1e3
    assert md.extend(theta)
    new = md.on & ~on
    assert new.any()
    m = md.base.coupling(theta, np.flatnonzero(new))
    assert np.all(m >= _ERROR_NEGLIGIBLE)
    a, m_all = md._norms(theta)
    for j, (c0, C) in enumerate(md.diag):  # the centered inner bound is the exact one
        s = np.abs(c0 + C @ theta)[new]
        exact = (s + md.kappa * a[j, new] * m_all[new]) / 2.0
        bound = (s + 0.5 * md.kappa * (md.alpha[j, new] * a[j, new] ** 2
                                       + m_all[new] ** 2 / md.alpha[j, new])) / 2.0  # fmt: skip
        assert np.allclose(bound, exact, rtol=1e-9)


def _scan(G):
    """(r (N,), ff (N, 2)): a 1 mm smoothstep in 0.2 s held to 1 s, the rigid bodies'
    feedforward one sample early (the loop delay)."""
    t = np.arange(0, 1.0, DT)
    s = np.clip(t / 0.2, 0, 1)
    r = 1e-3 * s**2 * (3 - 2 * s)
    acc = np.r_[np.diff(r, 2) * FS**2, 0, 0]
    ff = np.outer(acc, np.linalg.solve([[1.0, 0.3], [0.2, 0.5]], np.ones(2)))
    return r, np.vstack([ff[1:], ff[-1:]])


def _simulated_scan_rms(G, Gz, K, r, ff, n=20000) -> float:
    """sqrt(sum_n e_n^2 / N) of e = r - z, time-stepped on the closed loop (r at both outputs,
    ff at the plant input), the records held at their ends for ``n`` samples (settling)."""
    from workbench.sim import closed_loop_matrices

    Ks = K.statespace() if hasattr(K, "statespace") else K
    A, B, U, W = closed_loop_matrices((G.A, G.B, G.C, G.D), (Ks.A, Ks.B, Ks.C, Ks.D))
    rr = np.r_[r, np.full(n - r.size, r[-1])]
    fr = np.vstack([ff, np.repeat(ff[-1:], n - r.size, axis=0)])
    w = np.column_stack([rr, rr, fr, np.zeros((n, 2))])  # [r; d; v]
    Cz = np.hstack([Gz.C, np.zeros((1, A.shape[0] - Gz.C.shape[1]))]) + Gz.D @ U[:2]
    Dz = Gz.D @ W[:2]
    x, e = np.zeros(A.shape[0]), np.zeros(n)
    for k in range(n):
        e[k] = rr[k] - (Cz @ x + Dz @ w[k])[0]
        x = A @ x + B @ w[k]
    return float(np.sqrt(np.sum(e**2) / r.size))


def test_scan_cone_is_the_simulated_scan_error_and_holds_on_the_realized_loop():
    """scan_error_affine's figure (the scan cone's) is the time-stepped scan error at z of
    the realized controllers (K0's and the design's) to 1 %, and with scan_factor = 1 the
    design's simulated scan error is not above K0's."""
    G, Gz, K0 = _loop()
    r, ff = _scan(G)
    maps = youla_maps(G, K0, np.geomspace(0.5, FS / 2, 200), Gz=Gz, n_basis=8, pole=0.7)
    d = min_band_peak(maps, BAND, rms_factor=1.0, scan=(r, ff), scan_factor=1.0)
    got, ref = d.scan_rms
    k0 = _simulated_scan_rms(G, Gz, K0, r, ff)
    assert ref == pytest.approx(k0, rel=1e-2)
    assert got == pytest.approx(_simulated_scan_rms(G, Gz, d.controller, r, ff), rel=1e-2)
    assert got <= ref * (1 + 1e-6)
    assert _simulated_scan_rms(G, Gz, d.controller, r, ff) <= k0 * (1 + 1e-2)


@pytest.mark.parametrize("bad", [0.5, np.nan])
def test_scan_factor_below_one_or_a_bad_record_is_refused(bad):
    G, Gz, K0 = _loop()
    maps = youla_maps(G, K0, np.geomspace(1, 400, 30), Gz=Gz, n_basis=2, pole=0.5)
    r, ff = _scan(G)
    for kw, match in (
        (dict(scan=(r, ff), scan_factor=bad), "scan_factor: expected a finite factor >= 1"),
        (dict(scan=(r, ff[:, :1])), "scan: expected"),
    ):
        with pytest.raises(InputError, match=match) as exc:
            min_band_peak(maps, BAND, **kw)
        assert "\n" not in str(exc.value)
