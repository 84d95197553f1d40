"""Robust band-peak design (controllers.youla.min_band_peak on the measured loop, z_error):
stability and |S_ii| checked on the true plant by its own closed-loop poles and FRF, the
z bound checked against a plant whose z row differs from the model's."""

from __future__ import annotations

import control
import numpy as np
import pytest

from controllers.protocol import StateSpaceController
from controllers.youla import min_band_peak, model_error, relative_error, youla_maps
from workbench.core.errors import InputError
from workbench.core.lti import frf, zoh_frf
from workbench.io.formats import FrfData
from workbench.sim import closed_loop_matrices

FS = 1000.0
DT = 1 / FS
#: the rigid-body part of both plants: two coupled masses (1, 2 kg) behind a ZOH
_B = np.array([[0, 0], [1.0, 0.3], [0, 0], [0.2, 0.5]])
_C = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])


def _plant(mode_hz=None, zeta=0.01, gain=0.05):
    """2 x 2 rigid bodies (+ a mode coupling both outputs), ZOH + one-sample delay, and z."""
    A = np.kron(np.eye(2), [[0, 1], [0, 0]])
    Gc = control.ss(A, _B, _C, np.zeros((2, 2)))
    if mode_hz is not None:
        w = 2 * np.pi * mode_hz
        mode = control.ss([[0, 1], [-(w**2), -2 * zeta * w]], [[0, 0], [gain, -0.6 * gain]],
                          [[1.0, 0], [-0.7, 0]], np.zeros((2, 2)))  # fmt: skip
        Gc = control.parallel(Gc, mode)
    delay = control.ss(np.zeros((2, 2)), np.eye(2), np.eye(2), np.zeros((2, 2)), DT)
    return control.sample_system(Gc, DT, "zoh") * delay


def _pd(fc=20.0):
    wc = 2 * np.pi * fc
    lead = control.tf([1 / (wc / 3), 1], [1 / (wc * 3), 1]) * wc**2 / 3
    Kd = control.ss(control.c2d(lead, DT, "tustin"))
    K = control.append(Kd, 2 * Kd)
    return StateSpaceController(K.A, K.B, K.C, K.D, FS, ("y1", "y2"), ("u1", "u2"))


def _poles(G, ctrl) -> float:
    """Largest |closed-loop pole| of the realized controller on G (negative feedback)."""
    K = ctrl.statespace()
    A = closed_loop_matrices((G.A, G.B, G.C, G.D), (K.A, K.B, K.C, K.D))[0]
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def _s_peak(G, ctrl, f) -> float:
    L = frf(G, f) @ frf(ctrl.statespace(), f)
    S = np.linalg.inv(np.eye(2) + L)
    return float(np.max(np.abs(np.diagonal(S, axis1=1, axis2=2))))


def test_measured_loop_rows_keep_the_band_peak_design_stable_on_the_true_plant():
    """The model lacks a lightly damped mode at 100 Hz; the band-peak design around 30 Hz
    on the model alone is unstable on the true plant; with the model error (exact, or a
    ZOH-compensated FRF with 0.1 % noise and its variance) it is stable with |S_ii| <= 2 on
    the true plant: closed-loop poles of the realized controller and a 20000-line FRF."""
    G, Gt = _plant(), _plant(mode_hz=100.0)
    K0 = _pd()
    Gz = control.ss(G.A, G.B, 0.5 * (G.C[:1] + G.C[1:]), np.zeros((1, 2)), DT)
    f = np.geomspace(0.5, FS / 2, 200)
    fd = np.geomspace(0.5, FS / 2, 20000)
    band = (25.0, 35.0)
    assert _poles(Gt, K0) < 1  # K0 itself is robust
    plain = min_band_peak(youla_maps(G, K0, f, Gz=Gz, n_basis=8, pole=0.7), band)
    assert _poles(Gt, plain.controller) > 1
    fl = np.arange(0.5, FS / 2, 0.5)
    rng = np.random.default_rng(3)
    # the spec's FRF: from the plant input (no loop delay), the hold divided out
    Gm = frf(Gt, fl) / (np.exp(-2j * np.pi * fl * DT) * zoh_frf(fl, FS))[:, None, None]
    sigma = 1e-3 * np.abs(Gm)
    noisy = Gm + sigma / np.sqrt(2) * (rng.standard_normal(Gm.shape)
                                       + 1j * rng.standard_normal(Gm.shape))  # fmt: skip
    for err in (model_error(Gt, G), model_error(FrfData(fl, noisy, sigma**2, FS), G,
                                                 loop_delay_samples=1)):  # fmt: skip
        d = min_band_peak(youla_maps(G, K0, f, Gz=Gz, n_basis=8, pole=0.7, error=err), band)
        assert _poles(Gt, d.controller) < 1
        assert _s_peak(Gt, d.controller, fd) <= 2.0 * 1.02
        assert d.value < 0.5 * _band_peak(Gz, G, K0, band)  # still well below K0's


def _band_peak(Gz, G, ctrl, band, Gz_true=None, f=None):
    """max over the band of ||(Gz Si)(f)|| (200 lines, or the lines ``f`` in the band)."""
    f = np.linspace(*band, 200) if f is None else f[(f >= band[0]) & (f <= band[1])]
    K = frf(ctrl.statespace(), f)
    Si = np.linalg.inv(np.eye(2) + K @ frf(G, f))
    T = frf(Gz if Gz_true is None else Gz_true, f) @ Si
    return float(np.max(np.linalg.norm(T[:, 0], axis=1)))


def test_z_error_bounds_the_peak_of_a_plant_whose_z_row_differs():
    """Gz_true = Gz + eps Gz P (P a rotation of the inputs: ||dGz|| = eps ||Gz|| exactly).
    The plain design cancels the force at z through the model and loses it on the true z;
    with z_error = eps the true band peak stays below the design's value (its bound) and
    below the plain design's true peak."""
    G = _plant()
    K0 = _pd()
    Gz = control.ss(G.A, G.B, 0.5 * (G.C[:1] + G.C[1:]), np.zeros((1, 2)), DT)
    eps = 0.05
    P = control.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), [[0, 1.0], [-1.0, 0]], DT)
    Gz_true = control.parallel(Gz, eps * (Gz * P))
    f = np.geomspace(0.5, FS / 2, 200)
    band = (25.0, 35.0)
    maps = youla_maps(G, K0, f, Gz=Gz, n_basis=8, pole=0.7)
    plain = min_band_peak(maps, band)
    robust = min_band_peak(maps, band, z_error=eps)
    true_plain = _band_peak(Gz, G, plain.controller, band, Gz_true)
    true_robust = _band_peak(Gz, G, robust.controller, band, Gz_true)
    # the bound holds on the design grid's lines (between them the response may rise)
    on_grid = _band_peak(Gz, G, robust.controller, band, Gz_true, robust.maps.f)
    assert on_grid <= robust.value * (1 + 1e-4)  # the realization against the grid: 1e-4
    assert true_robust < 0.7 * true_plain
    assert true_plain > 3 * plain.value  # the cancellation does not survive
    assert _s_peak(G, robust.controller, np.geomspace(0.5, FS / 2, 20000)) <= 2.0 * 1.02


def test_relative_error_and_refusals():
    """relative_error is (||Delta|| + ||spread||) / ||G||: zero for an exact model; bad
    z_error is refused in one line."""
    G = _plant()
    f = np.geomspace(1, 400, 30)
    assert np.allclose(relative_error(model_error(G, G), G)(f), 0.0)
    Gt = _plant(mode_hz=100.0)
    eps = relative_error(model_error(Gt, G), G)(f)
    d = frf(Gt, f) - frf(G, f)
    assert np.allclose(eps, np.linalg.norm(d, axis=(1, 2)) / np.linalg.norm(frf(G, f), axis=(1, 2)))
    Gz = G[:1, :]
    maps = youla_maps(G, _pd(), f, Gz=Gz, n_basis=2, pole=0.5)
    for bad, match in ((-0.1, "z_error"), (lambda x: -np.ones_like(x), "z_error")):
        with pytest.raises(InputError, match=match) as exc:
            min_band_peak(maps, (20.0, 60.0), z_error=bad)
        assert "\n" not in str(exc.value)
