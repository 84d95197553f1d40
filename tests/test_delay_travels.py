"""The identified model carries its input delay (issue 7): files, FRF, validation, friction fit.

The truths here are built by hand (a discrete system driven by u[k - 1], the exact
factor exp(-j 2 pi f / fs) of one sample), not by the workbench's simulator.
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench.core import lti
from workbench.core.model import LTIModel
from workbench.ident import identify_subspace
from workbench.ident.validate import simulation_fit
from workbench.io.formats import TimeData, save_measurement

FS = 1000.0  # Hz, sample rate of the records below


def _true_system():
    """A 2x1 discrete system of order 4, poles 0.9 e^(+-j0.6), 0.8 e^(+-j1.9)."""
    A = np.zeros((4, 4))
    for k, (rho, th) in enumerate(((0.9, 0.6), (0.8, 1.9))):
        c, s = rho * np.cos(th), rho * np.sin(th)
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[c, s], [-s, c]]
    B = np.array([[1.0], [0.0], [0.5], [1.0]])
    C = np.array([[1.0, 0.3, 0.0, 1.0], [0.0, 1.0, 1.0, 0.2]])
    D = np.zeros((2, 1))
    return A, B, C, D


def _record(n_samples: int, seed: int, delay: int = 1) -> TimeData:
    """Noise-free record of the true system driven by u[k - delay] (hand-written loop)."""
    A, B, C, D = _true_system()
    u = np.random.default_rng(seed).standard_normal((n_samples, 1))
    ud = np.vstack([np.zeros((delay, 1)), u[: n_samples - delay]])
    x = np.zeros(4)
    y = np.empty((n_samples, 2))
    for k in range(n_samples):
        y[k] = C @ x + D @ ud[k]
        x = A @ x + B @ ud[k]
    return TimeData(fs=FS, u=u, y=y)


def _true_frf(freq_hz, delay: int = 1):
    A, B, C, D = _true_system()
    z = np.exp(2j * np.pi * np.asarray(freq_hz) / FS)
    G = np.stack([C @ np.linalg.solve(zk * np.eye(4) - A, B) + D for zk in z])
    return G * (z ** (-delay))[:, None, None]


def test_subspace_result_lti_model_carries_the_delay():
    res = identify_subspace(_record(2000, 0), method="moesp", order=4, input_delay=1)
    m = res.lti_model
    assert isinstance(m, LTIModel)
    assert m.delay_s == pytest.approx(1 / FS, rel=1e-12)
    assert m.dt == pytest.approx(1 / FS)
    freq = np.linspace(5.0, 450.0, 40)
    # noise-free record of an order-4 system: the identified FRF with its delay is the truth
    G_true = _true_frf(freq)
    assert np.max(np.abs(m.frf(freq) - G_true)) <= 1e-6 * np.max(np.abs(G_true))
    # the rational part alone misses the one-sample phase: it is not the truth
    assert np.max(np.abs(lti.frf(res.model, freq) - G_true)) > 0.1 * np.max(np.abs(G_true))


def test_identify_cli_writes_the_delay_into_the_model_file(tmp_path, capsys):
    from workbench.cli.main import main

    path, out, modal = tmp_path / "d.npz", tmp_path / "m.npz", tmp_path / "modal.npz"
    save_measurement(path, _record(2000, 1))
    argv = ["identify", str(path), "--method", "moesp", "--order", "4", "--block-rows", "10"]
    assert main(argv + ["--input-delay", "1", "--out", str(out), "--modal", str(modal)]) == 0
    assert "input delay 1 samples" in capsys.readouterr().out
    with np.load(out) as f:
        assert float(f["delay_s"]) == pytest.approx(1 / FS, rel=1e-12)
    freq = np.linspace(5.0, 450.0, 40)
    G_true = _true_frf(freq)
    m = LTIModel.read(out)
    assert m.delay_s == pytest.approx(1 / FS, rel=1e-12)
    assert np.max(np.abs(m.frf(freq) - G_true)) <= 1e-6 * np.max(np.abs(G_true))
    # the continuous modal model is the same model's rational part: it keeps the same delay
    mm = LTIModel.read(modal)
    assert mm.dt == 0.0 and mm.delay_s == pytest.approx(1 / FS, rel=1e-12)


def test_simulation_fit_takes_the_delay_from_the_model():
    res = identify_subspace(_record(2000, 2), method="moesp", order=4, input_delay=1)
    val = _record(600, 3)
    with_model = simulation_fit(res.lti_model, val)
    beside = simulation_fit(res.model, val, input_delay=1)
    assert with_model.y_sim.shape == (599, 2)  # the first output is not scored
    np.testing.assert_array_equal(with_model.y_sim, beside.y_sim)
    assert with_model.mean == beside.mean and with_model.mean > 99.99


def test_simulation_fit_refuses_a_fractional_sample_delay():
    from workbench.core.errors import InputError

    res = identify_subspace(_record(2000, 2), method="moesp", order=4)
    half = res.lti_model.replace(delay_s=0.5 / FS)
    with pytest.raises(InputError, match="whole samples"):
        simulation_fit(half, _record(600, 3))


def test_fit_friction_uses_the_models_own_delay():
    """Friction on a mass-spring port recorded with a 3-sample delay: the delay is the model's."""
    from workbench.diagnosis.nonlinear import PortNonlinearity, fit_friction, simulate_nonlinear

    w = 2 * np.pi * 20.0  # rad/s: a 20 Hz suspension of a 1 kg mass
    rational = LTIModel(
        A=[[0.0, 1.0], [-(w**2), -2 * 0.02 * w]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], D=[[0.0]]
    )
    delayed = rational.replace(delay_s=3 / FS)
    t = np.arange(1500) / FS
    u = (5.0 * np.sin(2 * np.pi * 7.0 * t) + 2.0 * np.sin(2 * np.pi * 31.0 * t))[:, None]
    v0 = 1e-5  # m/s, far below the motion's velocities (~0.01 m/s)
    truth = PortNonlinearity(friction_force=np.array([0.4]), friction_velocity=v0, substeps=4)
    y = simulate_nonlinear(rational, u, FS, truth, delay_s=3 / FS)
    nl, before, after = fit_friction(delayed, u, y, FS, friction_velocity=v0)
    assert float(np.ravel(nl.friction_force)[0]) == pytest.approx(0.4, rel=1e-3)
    assert after < 1e-4 * before
