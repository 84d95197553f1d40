"""Modal parameter estimation (workbench.modal.fit) and Theorem 2 scaling (workbench.modal.scaling).

Oracles: the FRF of a known modal model (closed form), and the beam's FE model solved
here with scipy.linalg.eigh (mass-normalized shapes), independently of workbench.fe.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import scipy.linalg

from plants.beam import BeamConfig, beam_fe_file
from workbench.core.errors import DataWarning, InputError
from workbench.io.formats import FrfData
from workbench.modal.fit import fit_modal, lscf, select_poles
from workbench.modal.model import ModalModel, Mode
from workbench.modal.scaling import collocation_scale, scale_modes

FREQ = (42.0, 118.0, 123.0, 310.0)  # two close modes: 4 % apart
DAMP = (0.01, 0.02, 0.015, 0.008)
LINES = np.arange(20.0, 500.0, 0.5)


def known_model(*, rigid: bool = False, above: bool = False) -> ModalModel:
    """2 inputs x 3 outputs, four flexible modes with rank-one residues, D; optional rigid
    body and a mode above the band (700 Hz)."""
    rng = np.random.default_rng(3)
    B = rng.standard_normal((4, 2))
    C = rng.standard_normal((4, 3))
    modes = [
        Mode("flexible", f, z, B[k], C[k] * (2 * np.pi * f) ** 2 * 1e-6)
        for k, (f, z) in enumerate(zip(FREQ, DAMP, strict=True))
    ]
    if rigid:
        modes.insert(0, Mode("rigid", 0.0, 0.0, np.array([1.0, 0.5]), np.array([0.3, -0.2, 0.1])))
    if above:
        modes.append(Mode("flexible", 700.0, 0.01, np.array([1.0, -1.0]), np.array([5, 4, 3.0])))
    return ModalModel(
        modes=tuple(modes),
        D=1e-7 * rng.standard_normal((3, 2)),
        input_names=("F1", "F2"),
        output_names=("s1", "s2", "s3"),
    )


def frf_data(model: ModalModel, *, noise: float = 0.0, seed: int = 0) -> FrfData:
    G = model.frf(LINES)
    var = None
    if noise:
        rng = np.random.default_rng(seed)
        sig = noise * np.abs(G)
        # spec 1b: G_var is E|G - G0|^2 of the complex element
        G = G + sig / np.sqrt(2) * (
            rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape)
        )
        var = sig**2
    return FrfData(LINES, G, var, 2000.0, model.input_names, model.output_names)


def flexible_residues(model: ModalModel) -> list[np.ndarray]:
    return [np.outer(m.c, m.b) for m in model.modes if m.kind == "flexible" and not m.effect]


@pytest.mark.parametrize("rigid", [False, True], ids=["flexible", "with-rigid"])
def test_noise_free_fit_recovers_the_modal_model(rigid):
    truth = known_model(rigid=rigid)
    fit = fit_modal(frf_data(truth), rigid=rigid)
    assert fit.status == "ok" and fit.n_modes == 4
    np.testing.assert_allclose(fit.freq_hz, FREQ, rtol=1e-9)
    np.testing.assert_allclose(fit.damping, DAMP, rtol=1e-7)
    for k, R in enumerate(flexible_residues(truth)[:4]):
        np.testing.assert_allclose(np.outer(fit.c[k], fit.b[k]), R, atol=1e-8 * np.abs(R).max())
    # b_k is 1 at its largest entry: the scale shared with c_k is removed
    assert np.allclose(np.max(np.abs(fit.b), axis=1), 1.0)
    if rigid:
        rb = truth.modes[0]
        np.testing.assert_allclose(fit.L, np.outer(rb.c, rb.b), atol=1e-9)
    else:
        assert fit.L is None
    np.testing.assert_allclose(fit.D, truth.D, atol=1e-12)
    G = truth.frf(LINES)
    assert np.max(np.abs(fit.model.frf(LINES) - G)) < 1e-9 * np.max(np.abs(G))


def test_mode_above_the_band_needs_the_upper_residual():
    data = frf_data(known_model(above=True))
    fit = fit_modal(data)
    np.testing.assert_allclose(fit.freq_hz, FREQ, rtol=1e-9)
    assert fit.upper_hz == pytest.approx(700.0, rel=1e-6)
    # with D alone the 700 Hz mode's growth over the band biases the poles
    plain = fit_modal(data, upper=False)
    assert np.max(np.abs(plain.freq_hz / FREQ - 1)) > 1e-6
    assert plain.error > 1e4 * fit.error


def test_noisy_fit_std_is_calibrated():
    """At 1 % noise the spread of the estimates over seeds matches the reported std."""
    truth = known_model()
    est, std = [], []
    for seed in range(12):
        fit = fit_modal(frf_data(truth, noise=0.01, seed=seed))
        assert fit.n_modes == 4
        # G_var is the complex variance: a model at the noise floor gives sigma2 = 1/2
        # per real observation
        assert 0.4 < fit.result.sigma2 < 0.6
        est.append(np.r_[fit.freq_hz, fit.damping])
        std.append(np.r_[fit.freq_std_hz, fit.damping_std])
    est, std = np.array(est), np.array(std)
    ratio = est.std(axis=0, ddof=1) / std.mean(axis=0)
    assert np.all((ratio > 0.4) & (ratio < 2.5)), ratio
    bias = (est.mean(axis=0) - np.r_[FREQ, DAMP]) / (std.mean(axis=0) / np.sqrt(len(est)))
    assert np.all(np.abs(bias) < 4.5), bias
    # 1 % noise: frequencies within 0.05 %, damping within 5 %
    assert np.max(np.abs(est[:, :4] / FREQ - 1)) < 5e-4
    assert np.max(np.abs(est[:, 4:] / DAMP - 1)) < 0.05


def test_stabilization_diagram_marks_the_physical_poles():
    data = frf_data(known_model(), noise=0.01)
    dg = lscf(data, max_order=20)
    f0, z0 = select_poles(dg)
    np.testing.assert_allclose(f0, FREQ, rtol=2e-3)
    np.testing.assert_allclose(z0, DAMP, rtol=0.3)
    assert np.all(dg.order >= 1) and np.all(dg.order <= 20)
    with pytest.raises(InputError, match="at most"):
        select_poles(dg, n_modes=500)


def test_bad_input_is_refused():
    data = frf_data(known_model())
    with pytest.raises(InputError, match="expected an FRF"):
        fit_modal(known_model())
    with pytest.raises(InputError, match="modes: expected an integer >= 1"):
        fit_modal(data, n_modes=0)
    with pytest.raises(InputError, match="at least 8 lines"):
        fit_modal(data, band_hz=(100.0, 101.0))
    with pytest.raises(InputError, match="max_order"):
        lscf(data, max_order=0)


# ------------------------------------------------------ Theorem 2 on the beam
@pytest.fixture(scope="module")
def beam():
    """The aligned beam (no tilts: probe 1 and coil 1 are exactly collocated), its FE
    modes from scipy's generalized eigensolver, and its FRF from those modes."""
    cfg = dataclasses.replace(
        BeamConfig(), sensor_tilt_rad=(0.0,) * 5, actuator_tilt_rad=(0.0,) * 3
    )
    fe = beam_fe_file(cfg)
    K = fe.K0 + np.tensordot(fe.alpha, fe.K_i, axes=1)
    M = fe.M0 + np.tensordot(fe.alpha, fe.M_i, axes=1)
    lam, Phi = scipy.linalg.eigh(K, M)  # Phi^T M Phi = I
    freq = np.sqrt(lam[:9]) / (2 * np.pi)
    assert freq[-1] < 1000.0 < np.sqrt(lam[9]) / (2 * np.pi)
    shapes_s = (fe.C @ Phi).T  # (n_modes, 5)
    shapes_a = (fe.B.T @ Phi).T  # (n_modes, 3)
    f = np.arange(1.0, 1000.0, 0.5)
    s = 2j * np.pi * f
    z = 0.01
    h = 1.0 / (s[:, None] ** 2 + 2 * z * np.sqrt(lam) * s[:, None] + lam)
    # noise-free: the 9 modes below 1 kHz and the static part of the others (the fit's
    # model structure exactly); noisy: every mode, as a measurement has them
    static = np.einsum("ky,ku,k->yu", shapes_s[9:], shapes_a[9:], 1.0 / lam[9:])
    G_exact = np.einsum("fk,ky,ku->fyu", h[:, :9], shapes_s[:9], shapes_a[:9]) + static
    G_all = np.einsum("fk,ky,ku->fyu", h, shapes_s, shapes_a)
    return f, {0.0: G_exact, 0.01: G_all}, freq, shapes_s[:9], shapes_a[:9], fe


def _aligned(phi, ref):
    """phi with each row's sign matching ref's."""
    return phi * np.sign(np.sum(phi * ref, axis=1))[:, None]


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_theorem2_scaling_gives_the_fe_mass_normalized_shapes(beam, noise):
    f, G, freq, phi_s, phi_a, fe = beam
    G, var = G[noise], None
    if noise:
        rng = np.random.default_rng(5)
        sig = noise * np.abs(G) + 1e-12
        G = G + sig / np.sqrt(2) * (
            rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape)
        )
        var = sig**2
    data = FrfData(f, G, var, 2048.0, fe.input_names, fe.output_names)
    fit = fit_modal(data)
    assert fit.n_modes == 9
    np.testing.assert_allclose(fit.freq_hz, freq, rtol=1e-8 if not noise else 5e-4)
    ext = scale_modes(fit.model, sensor="s1", actuator="F1")
    # sign convention: positive at the collocated pair
    assert np.all(ext.phi_sensors[:, 0] > 0) and np.all(ext.phi_actuators[:, 0] > 0)
    tol = 1e-6 if not noise else 0.02
    for est, ref in ((ext.phi_sensors, phi_s), (ext.phi_actuators, phi_a)):
        err = np.abs(est - _aligned(ref, est)) / np.max(np.abs(ref), axis=1)[:, None]
        assert np.max(err) < tol, np.max(err, axis=1)
    # the scaled model has the same response as the fitted one
    G_fit = fit.model.frf(f)
    assert np.max(np.abs(ext.model.frf(f) - G_fit)) < 1e-9 * np.max(np.abs(G_fit))
    assert ext.point_names == ("s1", "s2", "s3", "s4", "s5", "F2", "F3")
    assert ext.shapes.shape == (9, 7)


def test_collocation_scale_closed_form_and_node_warning():
    phi_a = np.array([[0.5, 1.0], [2.0, -1.0]])
    phi_s = np.array([[0.5, 3.0], [2.0, 0.25]])
    beta_true = np.array([4.0, 0.5])
    b, c = phi_a * beta_true[:, None], phi_s / beta_true[:, None]
    np.testing.assert_allclose(collocation_scale(b, c, sensor=0, actuator=0), beta_true)
    model = ModalModel(
        modes=(
            Mode("flexible", 10.0, 0.01, np.array([1.0, 0.3]), np.array([2.0, 1.0])),
            # a node at the collocated pair: no driving-point residue
            Mode("flexible", 20.0, 0.01, np.array([0.0, 1.0]), np.array([0.0, 1.0])),
        ),
        D=np.zeros((2, 2)),
        input_names=("F1", "F2"),
        output_names=("s1", "s2"),
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ext = scale_modes(model, sensor="s1", actuator="F1")
    assert any(issubclass(w.category, DataWarning) and "20 Hz" in str(w.message) for w in caught)
    assert np.all(np.isnan(ext.phi_sensors[1])) and np.all(np.isfinite(ext.phi_sensors[0]))
    np.testing.assert_allclose(ext.phi_sensors[0, 0], ext.phi_actuators[0, 0])
    with pytest.raises(InputError, match="collocated sensor: expected one of s1, s2"):
        scale_modes(model, sensor="s9", actuator="F1")
