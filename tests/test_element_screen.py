"""The first-order screen of the port elements (nonlinear.first_order_errors, diagnose's
``_fit_element(screen=...)``): an element hypothesis is fitted only when its signature at
level zero can come near the error it must reach.

Oracles: records made by the nonlinear simulation model with friction at the ports (the
element's first-order signature spans most of the residual) and by a linear model with a
static compliance the nominal model lacks (a residual compliance: no element's signature
spans it), each against the nominal model.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from workbench import sim
from workbench.diagnosis.diagnose import (
    ERROR_RATIO,
    _fit_element,
    _misfit_evidence,
    _nonlinearity_finding,
    _screen_passes,
)
from workbench.diagnosis.nonlinear import (
    PortNonlinearity,
    first_order_errors,
    simulate_nonlinear,
)
from workbench.io.formats import TimeData
from workbench.modal.model import ModalModel, Mode

FS = 1000.0
N = 4000


def _model() -> ModalModel:
    """Two collocated suspended modes on two ports (square: the outputs are the ports)."""
    b1, b2 = np.array([1.0, 0.3]), np.array([-0.2, 1.0])
    modes = (
        Mode(kind="flexible", freq_hz=8.0, damping=0.05, b=b1, c=b1),
        Mode(kind="flexible", freq_hz=13.0, damping=0.05, b=b2, c=b2),
    )
    return ModalModel(modes=modes, D=np.zeros((2, 2)))


def _input() -> np.ndarray:
    rng = np.random.default_rng(3)
    t = np.arange(N) / FS
    u = np.zeros((N, 2))
    for f in (1.0, 3.0, 7.0, 11.0, 19.0):
        u += np.outer(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)), rng.normal(size=2))
    return u


def _noisy(y: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return y + 1e-3 * np.std(y) * rng.standard_normal(y.shape)


@pytest.fixture(scope="module")
def records():
    """(nominal model, input, friction record, linear record)."""
    m, u = _model(), _input()
    lin = m.to_lti()
    vel = float(np.sqrt(np.mean(np.gradient(sim.simulate_zoh(lin, u, FS), 1 / FS, axis=0) ** 2)))
    friction = PortNonlinearity(
        friction_force=np.array([0.3, 0.2]), friction_velocity=1e-3 * vel, substeps=16
    )
    y_f = _noisy(simulate_nonlinear(lin, u, FS, friction), 1)
    # a static compliance the nominal model lacks: linear, no element's signature
    compliant = replace(m, D=np.array([[4e-5, 1e-5], [1e-5, 3e-5]]))
    y_l = _noisy(sim.simulate_zoh(compliant.to_lti(), u, FS), 2)
    return m, u, y_f, y_l


def test_friction_signature_spans_a_friction_record(records):
    m, u, y_f, _ = records
    e_lin, fo = first_order_errors(m.to_lti(), u, y_f, FS)
    assert set(fo) == {"saturation", "coulomb_friction", "cubic_stiffness"}
    assert min(fo, key=fo.get) == "coulomb_friction"
    assert fo["coulomb_friction"] < 0.1 * e_lin  # most of the residual is friction's signature
    assert all(e <= e_lin * (1 + 1e-9) for e in fo.values())  # a projection never adds


def test_no_signature_spans_a_linear_misfit(records):
    m, u, _, y_l = records
    e_lin, fo = first_order_errors(m.to_lti(), u, y_l, FS)
    assert all(e > 0.9 * e_lin for e in fo.values())


def test_screen_rejects_the_element_on_a_linear_record(records):
    m, u, _, y_l = records
    data = TimeData(fs=FS, u=u, y=y_l)
    e_lin = first_order_errors(m.to_lti(), u, y_l, FS)[0]
    needed = ERROR_RATIO * e_lin
    ef, model, pair = _fit_element(data, [m], screen=needed, errors=[e_lin])
    assert ef.parameters["screened"] is True
    assert ef.error_after == pytest.approx(e_lin)
    assert ef.error_after > needed  # rejected as a finding
    assert model is m and pair is None
    # the finding: none, with the screen's reason
    ev = _misfit_evidence(e_lin, 0.0, (1.0, 20.0))
    finding, alt = _nonlinearity_finding(ev, data, e_lin, [m], e_lin, direct=False)
    assert finding is None
    assert "first order" in alt["rejected"]


def test_screen_passes_the_element_on_a_friction_record(records):
    m, u, y_f, _ = records
    data = TimeData(fs=FS, u=u, y=y_f)
    e_lin = first_order_errors(m.to_lti(), u, y_f, FS)[0]
    needed = ERROR_RATIO * e_lin
    ef, model, _ = _fit_element(data, [m], screen=needed, errors=[e_lin])
    assert "screened" not in ef.parameters
    assert ef.element == "coulomb_friction"
    assert ef.error_after < 0.05 * e_lin


def test_screen_rule():
    # the signature removes a good share of what must go: passes
    assert _screen_passes(0.5, 0.3, 0.4, 0.5)
    # it removes almost none of what must go (a linear misfit)
    assert not _screen_passes(0.5, 0.499, 0.42, 0.5)
    # the record's start is most of the from-rest error (a record that starts moving)
    assert not _screen_passes(0.5, 0.1, 0.01, 0.01)
    # a drift (the from-rest simulation off by more than the record): first order says
    # little about friction that holds it, the element is fitted
    assert _screen_passes(200.0, 190.0, 0.4, 200.0)
    # a linear model already below what is needed has nothing to remove
    assert _screen_passes(0.5, 0.5, 0.6, 0.5)
    # a mode's spring: the start only, not the first order
    assert _screen_passes(0.5, 0.499, 0.42, 0.5, first_order=False)
    assert not _screen_passes(0.5, 0.1, 0.01, 0.01, first_order=False)


def test_a_spring_on_a_mode_is_not_fitted_where_the_linear_model_drifts(monkeypatch):
    """A spring on a flexible mode's coordinate changes only that mode's output: on a linear
    model whose from-rest simulation drifts far past the record (a free body where the
    record's is suspended) it cannot come near the error needed, and is not fitted; on the
    model that does not drift it is."""
    import workbench.diagnosis.nonlinear as nonlinear
    from workbench.diagnosis.diagnose import _mode_share

    b, c_rigid = np.array([1.0]), np.array([1.0, 0.2])
    flex = Mode(kind="flexible", freq_hz=13.0, damping=0.02, b=np.array([0.5]),
                c=np.array([0.3, -0.8]))  # fmt: skip
    free = ModalModel(modes=(Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=b, c=c_rigid), flex),
                      D=np.zeros((2, 1)))  # fmt: skip
    hung = ModalModel(
        modes=(Mode(kind="flexible", freq_hz=2.0, damping=0.05, b=b, c=c_rigid), flex),
        D=np.zeros((2, 1)),
    )
    u = _input()[:, :1]
    y = _noisy(sim.simulate_zoh(hung.to_lti(), u, FS), 4)
    data = TimeData(fs=FS, u=u, y=y)
    # the premise: the free model drifts, its flexible mode is a small part of the record
    e_free = float(np.linalg.norm(y - sim.simulate_zoh(free.to_lti(), u, FS)) / np.linalg.norm(y))
    port = nonlinear.ModalPort(free, 1)
    share = _mode_share(port, data)
    assert e_free > 10 and share < 1
    y_k = sim.simulate_zoh(replace(free, modes=(flex,)).to_lti(), u, FS)
    assert share == pytest.approx(np.linalg.norm(y_k) / np.linalg.norm(y), rel=1e-12)
    fitted = []
    original = nonlinear.fit_port_element
    monkeypatch.setattr(
        nonlinear,
        "fit_port_element",
        lambda sys, *a, **k: fitted.append(type(sys).__name__) or original(sys, *a, **k),
    )
    _fit_element(data, [free], band_hz=(1.0, 30.0), screen=0.01, errors=[e_free])
    assert "ModalPort" not in fitted
    e_hung = float(np.linalg.norm(y - sim.simulate_zoh(hung.to_lti(), u, FS)) / np.linalg.norm(y))
    _fit_element(data, [hung], band_hz=(1.0, 30.0), screen=0.5 * e_hung, errors=[e_hung])
    assert "ModalPort" in fitted


def test_a_slight_clipping_of_a_free_body_passes_the_screen():
    """An open-loop record of a free body whose inputs each have one spike, clipped by 10 %
    and 30 % of its excess over the input's next peak: the clipped impulse drifts the body
    far above the noise, which no common quantile of |u| follows (one sample's share clips
    each spike down to the next peak, several times too much), while each input's level at
    its peaks does. The oracle clips the input and simulates the body's exactly sampled
    double integrators (scipy)."""
    import scipy.signal

    from workbench.diagnosis.nonlinear import (
        _saturation_scan,
        fit_saturation,
        saturation_first_order,
    )

    rng = np.random.default_rng(11)
    n, fs = 10000, 2000.0
    t = np.arange(n) / fs
    u = np.zeros((n, 2))
    for f in (23.0, 37.0, 53.0, 71.0, 97.0):  # above the body's motion, the drift shows
        u += np.outer(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)), rng.normal(size=2))
    second = np.abs(u).max(axis=0)
    u[2000, 0], u[6000, 1] = 2.0 * second[0], -1.5 * second[1]  # a spike on each input
    top = np.abs(u).max(axis=0)
    level = top - np.array([0.1, 0.3]) * (top - second)
    # two masses (2 and 3 kg) on two inputs, three position outputs (not square: no port)
    b = np.array([[1 / 2, 0.0], [0.0, 1 / 3]])
    c = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, -0.5]])
    A = np.kron(np.eye(2), np.array([[0.0, 1.0], [0.0, 0.0]]))
    B = np.zeros((4, 2))
    B[[1, 3]] = b
    C = np.zeros((3, 4))
    C[:, [0, 2]] = c
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, B, C, np.zeros((3, 2))), 1 / fs)
    _, y_true, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, 1 / fs), np.clip(u, -level, level))
    y = y_true + 1e-5 * np.std(y_true) * np.random.default_rng(5).standard_normal(y_true.shape)
    model = ModalModel(
        modes=tuple(
            Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=b[k], c=c[:, k]) for k in range(2)
        ),
        D=np.zeros((3, 2)),
    )
    lin = model.to_lti()
    meas = np.arange(3)
    e_model = float(np.linalg.norm(y - sim.simulate_zoh(lin, u, fs)) / np.linalg.norm(y))
    scan = _saturation_scan(lin, meas, u, y, fs)[1]
    first = saturation_first_order(lin, meas, u, y, fs)
    assert scan > 0.9 * e_model  # no common share of clipped samples follows it
    assert first < 0.5 * e_model  # the peaks of each input do
    e, fo = first_order_errors(lin, u, y, fs, ports=False)
    assert fo["saturation"] == pytest.approx(first) and e == pytest.approx(e_model)
    assert first_order_errors(lin, u, y, fs, ports=False, saturation=0.123)[1] == {
        "saturation": 0.123
    }
    fitted = fit_saturation(lin, u, y, fs)
    assert fitted.parameters["saturation"] == pytest.approx(level, rel=1e-4)
