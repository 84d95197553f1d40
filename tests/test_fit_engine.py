"""The fitting engine and its modal model: oracles from closed forms and from workbench.core.lti."""

from __future__ import annotations

from dataclasses import replace

import control
import numpy as np
import pytest
from test_diagnose_gen import beam, frf_case, stage

from workbench import sim
from workbench.core import lti
from workbench.diagnosis.effects import MissingMode, TimeDelay
from workbench.diagnosis.fit import fit, fit_joint
from workbench.diagnosis.modal import decompose
from workbench.diagnosis.problem import make_problem
from workbench.modal.model import ModalModel, Mode
from workbench.modal.simulate import zoh_filter


@pytest.mark.parametrize("make", [stage, beam], ids=["stage", "beam"])
def test_decompose_reproduces_frf_and_realization(make):
    sys = make().build()
    em = decompose(sys)
    f = np.geomspace(0.5, 3000, 300)
    G = lti.frf(sys, f)
    assert np.max(np.abs(em.frf(f) - G)) < 1e-9 * np.max(np.abs(G))
    assert isinstance(em, ModalModel) and em.delay_s == 0.0
    ss = em.to_statespace()
    assert np.max(np.abs(lti.frf(ss, f) - G)) < 1e-9 * np.max(np.abs(G))


def test_decompose_finds_rigid_and_flexible_modes():
    em = decompose(stage().build())
    assert em.kinds == ("rigid", "flexible", "flexible")
    # closed form: the template's modes (913.8 Hz, zeta 0.0091; 1032 Hz, 0.0095)
    assert em.modes[1].freq_hz == pytest.approx(913.8, rel=1e-9)
    assert em.modes[1].damping == pytest.approx(0.0091, rel=1e-6)


def test_discrete_model_is_converted_exactly():
    sys = stage().build()
    sysd = control.c2d(sys, 1 / 5000, "zoh")
    em = decompose(sysd)
    f = np.geomspace(1, 2000, 100)
    G = lti.frf(sys, f)
    assert np.max(np.abs(em.frf(f) - G)) < 1e-6 * np.max(np.abs(G))


@pytest.mark.parametrize("delay_s", [0.0, 2e-4, 1.3e-4])
def test_modal_simulation_equals_lti(delay_s):
    sys = beam().build()
    em = replace(decompose(sys), delay_s=delay_s)
    u = np.random.default_rng(0).standard_normal((3000, 3))
    y_ref = sim.simulate_zoh(control.ss(sys.A, sys.B, sys.C, 0 * sys.D), u, 5000.0, delay_s=delay_s)
    em0 = replace(em, D=0 * em.D)
    y = em0.simulate(u, 5000.0)
    assert np.max(np.abs(y - y_ref)) < 1e-7 * np.max(np.abs(y_ref))


def test_zoh_filter_first_order_closed_form():
    # 1/(1 + s T): a unit step held from k = 0 gives 1 - exp(-k dt / T) at the samples
    T, dt = 1e-3, 2e-4
    y = zoh_filter([1.0], [T, 1.0], np.ones((50, 1)), dt)[:, 0]
    k = np.arange(50)
    assert np.allclose(y, 1 - np.exp(-k * dt / T), atol=1e-12)


def test_lags_and_coupling_in_state_space_match_frf():
    em = decompose(stage().build())
    em = replace(
        em,
        tau_in=np.array([1e-4, 0, 0, 2e-4, 0, 0]),
        tau_out=np.array([0, 3e-4, 0, 0, 0, 0]),
        T_out=np.eye(6) + 0.01 * np.eye(6, k=1),
    )
    ss = em.to_statespace()
    f = np.geomspace(1, 2500, 200)
    assert np.allclose(lti.frf(ss, f), em.frf(f), rtol=1e-8, atol=1e-20)


def test_missing_mode_fit_recovers_frequency_damping_and_residue():
    p = stage()
    b = np.array([0.0, 0.0, 0.5, -0.3, 0.2, 0.0])
    c = np.array([0.0, 0.0, 0.45, -0.35, 0.25, 0.0])
    truth = {"freq_hz": 1320.0, "damping": 0.012, "b": b, "c": c}
    case = frf_case(p, "missing_mode", truth, rel=0.005, rng=np.random.default_rng(0))
    prob = make_problem(case.data)
    fr = fit(MissingMode(), prob, decompose(case.nominal))
    f, z = np.exp(fr.theta)
    assert f == pytest.approx(1320.0, rel=1e-3)
    assert z == pytest.approx(0.012, rel=0.05)
    # residue N0 = c b^T within 3 % of its norm; the std from the Jacobian is honest (< 1 % here)
    N0 = fr.realized.linear["N0"]
    assert np.linalg.norm(N0 - np.outer(c, b)) < 0.03 * np.linalg.norm(np.outer(c, b))
    assert fr.theta_std[0] < 0.01
    # chi-square per real residual about 1/2 (complex G_var splits over real and imaginary parts)
    assert 0.4 < fr.sigma2 < 0.7


def test_joint_fit_removes_the_bias_of_sequential_fits():
    p = stage()
    truth = {
        "freq_hz": 1320.0,
        "damping": 0.012,
        "b": np.array([0, 0, 0.5, -0.3, 0.2, 0.0]),
        "c": np.array([0, 0, 0.45, -0.35, 0.25, 0.0]),
    }
    case = frf_case(p, "missing_mode", truth, rel=0.005, rng=np.random.default_rng(1))
    from workbench.io.formats import FrfData

    _, true, _ = __import__("test_diagnose_gen").true_plant(p, "missing_mode", truth)
    G = lti.frf(true, case.data.freq, delay_s=5e-5)
    data = FrfData(freq=case.data.freq, G=G, G_var=case.data.G_var)
    prob = make_problem(data)
    base = decompose(case.nominal)
    m = fit(MissingMode(), prob, base)
    d = fit(TimeDelay(), prob, m.model)
    fits, _ = fit_joint([MissingMode(), TimeDelay()], [m.theta, d.theta], prob, base)
    assert fits[1].theta[0] * 1e-3 == pytest.approx(5e-5, rel=1e-3)
    assert np.exp(fits[0].theta[0]) == pytest.approx(1320.0, rel=1e-4)
    assert fits[1].error < 1e-6


def test_moved_mode_keeps_its_numerator():
    """Mode.moved (modal mismatch, suspension): the numerator over the new denominator,
    closed form N0 / (s^2 + 2 z w s + w^2); a rigid mode becomes flexible."""
    rng = np.random.default_rng(3)
    b, c = rng.standard_normal(2), rng.standard_normal(3)
    s = 2j * np.pi * np.geomspace(1, 1000, 50)
    w = 2 * np.pi * 100.0
    want = np.outer(c, b)[None] / (s**2 + 2 * 0.02 * w * s + w * w)[:, None, None]
    for kind in ("rigid", "flexible"):
        m = Mode(kind, 0.0 if kind == "rigid" else 40.0, 0.0, b, c).moved(100.0, 0.02)
        assert (m.kind, m.freq_hz, m.damping) == ("flexible", 100.0, 0.02)
        assert np.max(np.abs(m.response(s) - want)) < 1e-12 * np.max(np.abs(want))
