"""A cubic spring on one mode's coordinate (modal Duffing, :class:`ModalPort`).

Oracle: scipy's DOP853 (rtol 1e-11) on the mode's own equation ``q'' + 2 z w q' + w^2 q =
b^T u - k3 q^3``, the input held over each sample, independent of the substep propagation
and of the port kernel. The simulation model with the modal element must approach it at
second order in the substep (the port force is trapezoidal over each substep).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate

from workbench.core.errors import InputError
from workbench.diagnosis.nonlinear import (
    ModalPort,
    PortNonlinearity,
    fit_port_element,
    simulate_nonlinear,
)
from workbench.modal.model import ModalModel, Mode

FS = 1000.0
N = 400
F_HZ, ZETA = 40.0, 0.02
B = np.array([1.0, -0.5])  # modal force per input (2 inputs)
C = np.array([1e-3, 2e-3, -1e-3])  # outputs per modal displacement (3 outputs: not square)


def _model():
    """A rigid body beside the mode (its states come first in the realization) and the mode."""
    rigid = Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=np.array([0.2, 0.1]), c=C[::-1])
    mode = Mode(kind="flexible", freq_hz=F_HZ, damping=ZETA, b=B, c=C)
    return ModalModel(modes=(rigid, mode), D=np.zeros((3, 2)))


def _input():
    rng = np.random.default_rng(3)
    t = np.arange(N) / FS
    u = np.zeros((N, 2))
    for f in (13.0, 31.0, 47.0, 71.0):
        u += np.outer(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)), rng.normal(size=2))
    return 2000.0 * u


def _ode(u, k3):
    """(N, 3) outputs of the rigid body and the Duffing mode, each integrated by DOP853."""
    w = 2 * np.pi * F_HZ
    rb = np.array([0.2, 0.1])
    x = np.zeros(4)  # (rigid displacement, velocity, q, q')
    y = np.zeros((N, 3))
    for k in range(N):
        y[k] = C[::-1] * x[0] + C * x[2]

        def f(_t, x, uk=u[k]):
            q, v = x[2], x[3]
            return [x[1], rb @ uk, v, -(w**2) * q - 2 * ZETA * w * v + B @ uk - k3 * q**3]

        sol = scipy.integrate.solve_ivp(f, (0, 1 / FS), x, method="DOP853", rtol=1e-11, atol=1e-14)
        x = sol.y[:, -1]
    return y


def _k3(u):
    """(k3, the linear response): a spring 0.5 x the mode's linear stiffness at the rms modal
    displacement of the linear response."""
    y_lin = _ode(u, 0.0)
    w = 2 * np.pi * F_HZ
    # the mode's part of output 0 over its c: the modal displacement (the rigid body's removed)
    q = (y_lin[:, 0] - C[2] * _ode_rigid(u)) / C[0]
    return 0.5 * w**2 / float(np.mean(q**2)), y_lin


def _ode_rigid(u):
    """The rigid body's displacement (N,), exact: the held input's double integral."""
    rb = np.array([0.2, 0.1])
    a = u @ rb
    x = v = 0.0
    out = np.zeros(N)
    h = 1 / FS
    for k in range(N):
        out[k] = x
        x, v = x + v * h + 0.5 * a[k] * h * h, v + a[k] * h
    return out


def test_modal_duffing_matches_the_ode_at_second_order():
    u = _input()
    k3, y_lin = _k3(u)
    y_ref = _ode(u, k3)
    rms = np.sqrt(np.mean(y_ref**2))
    # the spring is a real part of the response, far above the errors measured below
    assert np.sqrt(np.mean((y_ref - y_lin) ** 2)) > 0.02 * rms
    port = ModalPort(_model(), 1)
    Bp, Cp = port.maps
    err = {}
    for n in (4, 8, 16):
        nl = PortNonlinearity(
            friction_force=np.zeros(1),
            cubic_stiffness=np.array([k3]),
            substeps=n,
            port_forces=Bp,
            port_displacements=Cp,
        )
        y = simulate_nonlinear(port.lti, u, FS, nl)
        err[n] = np.sqrt(np.mean((y - y_ref) ** 2)) / rms
    assert err[16] < 1e-4, err
    # second order: halving the substep divides the error by ~4 (3 allows the start's terms)
    assert err[4] / err[8] > 3 and err[8] / err[16] > 3, err


def test_the_fit_finds_the_spring_on_the_mode():
    u = _input()
    # a milder spring, 0.02 x the linear stiffness at the rms displacement (the regression's
    # start is first order in it; a stronger one moves the resonance by many half-power widths)
    k3 = 0.04 * _k3(u)[0]
    rng = np.random.default_rng(0)
    y_ref = _ode(u, k3)
    y = y_ref + 1e-3 * np.sqrt(np.mean(y_ref**2)) * rng.standard_normal(y_ref.shape)
    ef = fit_port_element(ModalPort(_model(), 1), u, y, FS)
    assert ef.element == "cubic_stiffness" and ef.ports == ()
    assert ef.parameters["mode"] == 1 and ef.parameters["mode_freq_hz"] == pytest.approx(F_HZ)
    assert ef.parameters["cubic_stiffness"][0] == pytest.approx(k3, rel=0.02)
    assert ef.error_after < 1.2e-3 and ef.error_before > 5 * ef.error_after


def test_the_modes_coordinate_is_read_off_the_record():
    # a strong spring (half the mode's stiffness at the rms displacement): the linear model's
    # coordinate is far from the record's, the one measured through the mode's outputs is it
    from dataclasses import replace

    from workbench.core.model import as_model
    from workbench.diagnosis.nonlinear import _measured_mode
    from workbench.sim import simulate_zoh

    u = _input()
    y = _ode(u, 0.5 * _k3(u)[0])
    q = (y[:, 0] - C[2] * _ode_rigid(u)) / C[0]
    port = ModalPort(_model(), 1)
    lin = as_model(port.lti)
    y_lin = simulate_zoh(lin, u, FS)
    Cp = port.maps[1]
    q_lin = simulate_zoh(replace(lin, C=Cp, D=np.zeros((1, 2)), output_names=()), u, FS)
    assert np.linalg.norm(q_lin[:, 0] - q) > 0.1 * np.linalg.norm(q)
    measured = _measured_mode(lin, port.maps, y - y_lin, q_lin)
    assert measured.shape == (N, 1)
    assert np.linalg.norm(measured[:, 0] - q) < 1e-8 * np.linalg.norm(q)


def test_a_softening_mode_gets_no_spring():
    # the record's mode softens (k3 < 0): no hardening spring regresses above zero on its
    # measured coordinate, and the fit says so (no level, the linear model's error) instead
    # of refining a spring that is not there
    u = _input()
    k3 = -0.04 * _k3(u)[0]
    y = _ode(u, k3)
    y = y + 1e-3 * np.sqrt(np.mean(y**2)) * np.random.default_rng(1).standard_normal(y.shape)
    ef = fit_port_element(ModalPort(_model(), 1), u, y, FS)
    assert ef.parameters["cubic_stiffness"] == [0.0]
    assert ef.error_after == ef.error_before


def test_a_port_on_a_rigid_mode_is_refused():
    with pytest.raises(InputError, match="flexible mode"):
        ModalPort(_model(), 0)


def test_a_mode_without_one_coordinate_is_refused():
    # a residue of rank two: two coordinates share the pole, no single q for the spring
    m = _model()
    mode = m.modes[1]
    N0 = np.outer(C, B) + np.outer([1e-3, -1e-3, 0.0], [0.0, 1.0])
    from dataclasses import replace

    two = replace(m, modes=(m.modes[0], replace(mode, N0=N0, N1=np.zeros_like(N0))))
    with pytest.raises(InputError, match="no single coordinate"):
        ModalPort(two, 1)


def test_own_ports_take_no_port_outputs():
    port = ModalPort(_model(), 1)
    Bp, Cp = port.maps
    nl = PortNonlinearity(
        friction_force=np.zeros(1), cubic_stiffness=[1.0], port_forces=Bp, port_displacements=Cp
    )
    with pytest.raises(InputError, match="takes no outputs"):
        simulate_nonlinear(port.lti, np.zeros((10, 2)), FS, nl, port_outputs=[0, 1])
