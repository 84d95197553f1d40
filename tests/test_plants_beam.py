"""The FE beam against closed-form Euler-Bernoulli results, and the beam plant's physics."""

from __future__ import annotations

import numpy as np
import pytest

import plants
from plants import BeamConfig, beam_fe

# Closed-form free-free roots beta_n L of cos(bL) cosh(bL) = 1 (Blevins, Formulas for Natural
# Frequency and Mode Shape, 1979, table 8-1).
FREE_FREE_BETA_L = np.array([4.7300407, 7.8532046, 10.9956078, 14.1371655, 17.2787596])
# Beam of seed 001: 500 x 20 x 2 mm; structural steel (BeamConfig defaults).
L, B, H = 0.5, 0.02, 0.002
E, RHO = 210e9, 7850.0
EI = E * B * H**3 / 12
RHO_A = RHO * B * H


def free_free_hz(n_elements: int) -> np.ndarray:
    fe = beam_fe.parameter_matrices(length_m=L, width_m=B, thickness_m=H, n_elements=n_elements)
    K, M = beam_fe.assemble(fe, [E, RHO, 0.0, 0.0])
    return beam_fe.solve_modes(K, M)[0]


def closed_form_hz(beta_l: np.ndarray) -> np.ndarray:
    """w = (beta L)^2 sqrt(EI / (rho A L^4))."""
    return beta_l**2 * np.sqrt(EI / (RHO_A * L**4)) / (2 * np.pi)


def test_free_free_frequencies_match_closed_form():
    f = free_free_hz(40)
    assert np.all(f[:2] < 1e-3 * f[2])  # two rigid-body modes
    rel = f[2:7] / closed_form_hz(FREE_FREE_BETA_L) - 1
    assert np.max(np.abs(rel)) < 5e-5  # measured: 1.5e-7 ... 2.4e-5 with 40 elements


def test_pinned_pinned_frequencies_match_closed_form():
    """Stiff springs at both ends pin the beam: w_n = (n pi)^2 sqrt(EI / (rho A L^4))."""
    fe = beam_fe.parameter_matrices(
        length_m=L, width_m=B, thickness_m=H, n_elements=40, flexure_positions_m=(0.0, L)
    )
    K, M = beam_fe.assemble(fe, [E, RHO, 1e10, 1e10])
    f = beam_fe.solve_modes(K, M)[0]
    expected = closed_form_hz(np.pi * np.arange(1, 5))
    np.testing.assert_allclose(f[:4], expected, rtol=1e-4)


def test_mesh_convergence_is_fourth_order():
    """Hermite cubic elements: frequency error ~ h^4 (Petyt 2010, sec. 3.3)."""
    exact = closed_form_hz(FREE_FREE_BETA_L[2])  # third flexible mode
    err = np.array(
        [abs(free_free_hz(n)[4] / exact - 1) for n in (8, 16, 32)]
    )  # 4 elements: pre-asymptotic
    assert np.all(np.diff(err) < 0)
    order = np.log2(err[:-1] / err[1:])
    assert np.all((order > 3.5) & (order < 4.5)), order


def test_in_plane_bending_is_width_over_thickness_stiffer():
    """I_in / I_out = (b/h)^2 = 100, so in-plane free-free frequencies are 10x higher."""
    kw = dict(length_m=L, width_m=B, thickness_m=H, n_elements=20)
    Ko, Mo = beam_fe.assemble(beam_fe.parameter_matrices(**kw), [E, RHO, 0, 0])
    Ki, Mi = beam_fe.assemble(beam_fe.parameter_matrices(**kw, in_plane=True), [E, RHO, 0, 0])
    fo, fi = beam_fe.solve_modes(Ko, Mo)[0], beam_fe.solve_modes(Ki, Mi)[0]
    np.testing.assert_allclose(fi[2:6] / fo[2:6], B / H, rtol=1e-9)


def test_parameter_matrices_are_affine():
    fe = plants.beam_fe_model()
    cfg = BeamConfig()
    K, M = beam_fe.assemble(fe, cfg.alpha)
    K2, M2 = beam_fe.assemble(fe, cfg.alpha * [2.0, 1.0, 1.0, 1.0])
    K_i, M_i = fe.K_i, fe.M_i
    np.testing.assert_allclose(K2 - K, cfg.alpha[0] * K_i[0])
    np.testing.assert_allclose(M2, M)
    np.testing.assert_allclose(M, fe.M0 + cfg.alpha[1] * M_i[1], rtol=1e-12)
    np.testing.assert_allclose(
        K, fe.K0 + sum(a * k for a, k in zip(cfg.alpha, K_i)), rtol=1e-12, atol=1e-9
    )
    # E only scales the flexible frequencies of the free-free beam by sqrt(2)
    f1 = free_free_hz(20)[2:6]
    fe0 = beam_fe.parameter_matrices(length_m=L, width_m=B, thickness_m=H, n_elements=20)
    f2 = beam_fe.solve_modes(*beam_fe.assemble(fe0, [2 * E, RHO, 0, 0]))[0][2:6]
    np.testing.assert_allclose(f2 / f1, np.sqrt(2), rtol=1e-9)


def test_mode_shapes_are_mass_normalized():
    K, M = beam_fe.assemble(plants.beam_fe_model(), BeamConfig().alpha)
    f, Phi = beam_fe.solve_modes(K, M)
    n = Phi.shape[0]
    np.testing.assert_allclose(Phi.T @ M @ Phi, np.eye(n), atol=1e-9)
    np.testing.assert_allclose(
        Phi.T @ K @ Phi, np.diag((2 * np.pi * f) ** 2), atol=1e-6 * f.max() ** 2
    )


def test_suspension_modes_match_a_rigid_beam_on_two_springs():
    """Soft flexures: the two lowest modes are those of the rigid beam (mass m, inertia J about
    the centre, lumped coil masses included) on springs k1, k2 (flexibility lowers them < 1 %)."""
    cfg = BeamConfig()
    m_beam = RHO_A * L
    xs = np.array(cfg.actuator_positions_m) - L / 2
    m = m_beam + 3 * cfg.actuator_mass_kg
    J = m_beam * L**2 / 12 + cfg.actuator_mass_kg * np.sum(xs**2)
    Mr = np.array([[m, cfg.actuator_mass_kg * xs.sum()], [cfg.actuator_mass_kg * xs.sum(), J]])
    Kr = np.zeros((2, 2))
    for x, k in zip(cfg.flexure_positions_m, cfg.flexure_stiffness_npm):
        r = np.array([1.0, x - L / 2])
        Kr += k * np.outer(r, r)
    import scipy.linalg

    f_rigid = np.sqrt(scipy.linalg.eigh(Kr, Mr, eigvals_only=True)) / (2 * np.pi)
    f = plants.beam_modes(cfg).freq_hz[:2]
    np.testing.assert_allclose(f, f_rigid, rtol=1e-2)


@pytest.fixture(scope="module")
def beam():
    return plants.beam()


def test_beam_has_nine_modes_below_nyquist(beam):
    assert beam.fs == 2048.0
    nominal = beam.nominal_modes
    assert nominal.n_modes >= 9
    assert np.all(nominal.freq_hz < beam.fs / 2)
    assert nominal.kind[:2] == ("suspension", "suspension") and nominal.freq_hz[1] < 10
    flex = nominal.damping[2:]
    assert np.all((flex >= 0.005) & (flex <= 0.02))  # realistic modal damping, 0.5-2 %


def test_sensor_1_is_collocated_with_actuator_1(beam):
    cfg = BeamConfig()
    m = beam.nominal_modes
    np.testing.assert_allclose(m.c[:, 0] * np.cos(cfg.actuator_tilt_rad[0]), m.b[:, 0], rtol=1e-12)
    # a collocated pair is passive: Im G11 <= 0 at every frequency (no delay in the beam)
    f = np.linspace(1, 1020, 3000)
    G11 = beam.frf(f)[:, 0, 0]
    assert np.all(G11.imag <= 1e-15)


def test_prior_model_is_stiffer(beam):
    """The prior FE model overestimates the eigenfrequencies (seed 001, sec. 7.5):
    E +8 % gives flexible modes sqrt(1.08) higher, nearly."""
    prior = plants.beam_prior_model()
    lam = np.linalg.eigvals(prior.A)
    f_prior = np.sort(np.abs(lam[lam.imag > 0])) / (2 * np.pi)
    f_true = beam.nominal_modes.freq_hz
    ratio = f_prior[2:7] / f_true[2:7]
    assert np.all(ratio > 1.02) and np.all(ratio < np.sqrt(1.08) + 1e-3)
    assert np.all(f_prior[:2] > f_true[:2])


def test_tilted_sensor_sees_the_in_plane_mode():
    """Seed 001: a tilted sensor picks up the in-plane bending mode. Sensor 3 tilted 10 degrees,
    coils 3 degrees (they excite the in-plane mode); the untilted probes do not see it."""
    coils = (np.radians(3.0),) * 3
    cfg = BeamConfig(
        sensor_tilt_rad=(0.0, 0.0, np.radians(10.0), 0.0, 0.0), actuator_tilt_rad=coils
    )
    p = plants.beam(config=cfg)
    ref = plants.beam(config=BeamConfig(actuator_tilt_rad=coils))
    extra = p.modes.select([k == "extra" for k in p.modes.kind])
    f_ip = extra.freq_hz[extra.freq_hz > 200][0]  # first in-plane bending mode
    assert 200 < f_ip < 1024
    f = np.linspace(0.98 * f_ip, 1.02 * f_ip, 401)
    ratio = np.abs(p.frf(f) / ref.frf(f))
    assert ratio[:, 2].max() > 1.1  # sensor 3 shows the resonance
    np.testing.assert_allclose(ratio[:, [0, 1, 3, 4]], 1.0, rtol=1e-9)  # the others do not


def test_beam_quantization_grid(beam):
    u = 0.2 * np.random.default_rng(0).standard_normal((2000, 3))
    y = beam.simulate(u, rng=np.random.default_rng(1))
    q = BeamConfig().quantization
    np.testing.assert_allclose(y / q, np.round(y / q), atol=1e-6)


def test_beam_residual_modes_are_above_nyquist(beam):
    res = beam.residual_modes
    assert res.n_modes > 10 and np.all(res.freq_hz >= beam.fs / 2)
    p = plants.beam(residual_max_hz=10e3)
    assert p.modes.n_modes == beam.nominal_modes.n_modes + np.sum(res.freq_hz <= 10e3)
