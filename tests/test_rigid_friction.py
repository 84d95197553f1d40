"""Coulomb friction on a square model's rigid-body motion (:class:`RigidPorts`).

Oracle: the event-exact Coulomb motion of each rigid body (tests/indepgen.py's
``_coulomb_step``: stick / slip events in closed form over each held sample) plus the
flexible mode's exact ZOH response, which the friction does not drive (it acts on the rigid
bodies' coordinates only). Independent of the substep propagation and of the port kernel.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from indepgen import _coulomb_step

from workbench import sim
from workbench.core.errors import InputError
from workbench.diagnosis.nonlinear import (
    PortNonlinearity,
    RigidPorts,
    coulomb_port_profile,
    fit_port_element,
    simulate_nonlinear,
)
from workbench.modal.model import ModalModel, Mode

FS = 1000.0
N = 600
#: two rigid bodies in DOF coordinates (collocated: b = c), a flexible mode seen otherwise
RB = (np.array([0.5, 0.0]), np.array([0.0, 0.8]))
FLEX_B, FLEX_C = np.array([0.3, 0.2]), np.array([0.1, -0.4])
FC = np.array([0.6, 0.25])  # friction per port (DOF), in the input's units


def _model(rigid=True):
    modes = [Mode(kind="flexible", freq_hz=40.0, damping=0.02, b=FLEX_B, c=FLEX_C)]
    if rigid:
        modes = [Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=b, c=b) for b in RB] + modes
    return ModalModel(modes=tuple(modes), D=np.zeros((2, 2)))


def _input():
    rng = np.random.default_rng(5)
    t = np.arange(N) / FS
    u = np.zeros((N, 2))
    for f in (3.0, 7.0, 17.0, 41.0):
        u += np.outer(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)), rng.normal(size=2))
    return u


def _exact(u, Fc):
    """(N, 2) outputs: each rigid body's event-exact Coulomb motion (modal deceleration
    ``Fc_j b_j[j]``: the port force through the body's input row, against its velocity) plus
    the flexible mode's exact ZOH response."""
    y = sim.simulate_zoh(_model(rigid=False).to_lti(), u, FS)
    p, v = np.zeros(2), np.zeros(2)
    F = np.array([Fc[j] * RB[j][j] for j in range(2)])
    for k in range(N):
        y[k] += p[0] * RB[0] + p[1] * RB[1]
        a = np.array([RB[j] @ u[k] for j in range(2)])
        p, v = _coulomb_step(p, v, a, F, 1.0 / FS)
    return y


def test_rigid_friction_matches_the_event_exact_motion():
    u = _input()
    y_ref = _exact(u, FC)
    rms = np.sqrt(np.mean(y_ref**2))
    y_free = _exact(u, np.zeros(2))
    # the friction is a real part of the response (sticking included), far above the error
    assert np.sqrt(np.mean((y_ref - y_free) ** 2)) > 0.1 * rms
    port = RigidPorts(_model())
    Bp, Cp = port.maps
    vel = np.sqrt(np.mean(np.gradient(y_ref, 1 / FS, axis=0) ** 2))
    err = {}
    for n in (16, 64):
        nl = PortNonlinearity(
            friction_force=FC,
            friction_velocity=1e-6 * vel,
            substeps=n,
            port_forces=Bp,
            port_displacements=Cp,
        )
        y = simulate_nonlinear(port.lti, u, FS, nl)
        err[n] = np.sqrt(np.mean((y - y_ref) ** 2)) / rms
    assert err[64] < 1e-3 and err[64] < err[16], err
    # through B instead (the ports' friction) drives the flexible mode: a different model
    nl_b = PortNonlinearity(friction_force=FC, friction_velocity=1e-6 * vel, substeps=64)
    y_b = simulate_nonlinear(port.lti, u, FS, nl_b)
    assert np.sqrt(np.mean((y_b - y_ref) ** 2)) / rms > 5 * err[64]


def test_the_hard_law_is_the_event_exact_motion():
    # friction_velocity 0: the hard Coulomb law, simulated event by event (no substeps); the
    # same motion as the oracle's to rounding, sticking included
    u = _input()
    port = RigidPorts(_model())
    Bp, Cp = port.maps
    for Fc in (np.zeros(2), FC, 4 * FC):
        y_ref = _exact(u, Fc)
        nl = PortNonlinearity(
            friction_force=Fc, friction_velocity=0.0, substeps=1, port_forces=Bp,
            port_displacements=Cp,
        )  # fmt: skip
        y = simulate_nonlinear(port.lti, u, FS, nl)
        assert np.max(np.abs(y - y_ref)) < 1e-12 * np.max(np.abs(y_ref))
    # a whole-sample delay of the input delays the forces the input applies, not the friction
    m = 3
    y_d = simulate_nonlinear(port.lti, u, FS, nl, delay_s=m / FS)
    u_d = np.vstack([np.zeros((m, 2)), u[:-m]])
    y_ref = _exact(u_d, 4 * FC)
    assert np.max(np.abs(y_d - y_ref)) < 1e-12 * np.max(np.abs(y_ref))


def test_the_hard_law_needs_free_rigid_bodies():
    # a rigid body on a spring (a suspension) is no free double integrator: refused
    m = _model()
    sprung = ModalModel(
        modes=(Mode(kind="flexible", freq_hz=2.0, damping=0.0, b=RB[0], c=RB[0]),) + m.modes[1:],
        D=np.zeros((2, 2)),
    )
    lti = sprung.to_lti()
    A = np.asarray(lti.A)
    Bp = np.zeros((A.shape[0], 2))
    Bp[:2] = np.asarray(lti.B)[:2]
    Cp = np.zeros((2, A.shape[0]))
    Cp[:, :2] = np.asarray(lti.C)[:, :2]
    nl = PortNonlinearity(
        friction_force=FC, friction_velocity=0.0, port_forces=Bp, port_displacements=Cp
    )
    with pytest.raises(InputError, match="double integrators"):
        simulate_nonlinear(lti, _input(), FS, nl)


def test_a_ports_profile_is_the_event_exact_motions_error():
    # each trial level of one port against the oracle's whole motion at that level (the other
    # port held), sticking included; with a whole-sample delay of the model's input
    u = _input()
    y = _exact(u, FC) + 1e-3 * np.random.default_rng(1).standard_normal((N, 2))
    port = RigidPorts(_model())
    Bp, Cp = port.maps
    held = np.array([0.3, 0.25])
    for j in (0, 1):
        trial = np.array([0.0, 0.5, 1.0, 4.0]) * FC[j]
        errs = coulomb_port_profile(port.lti, u, y, FS, Bp, Cp, held, j)(trial)
        for x, e in zip(trial, errs):
            F = held.copy()
            F[j] = x
            ref = np.linalg.norm(y - _exact(u, F)) / np.linalg.norm(y)
            assert e == pytest.approx(ref, rel=1e-9)
    m = 2
    delayed = dataclasses.replace(port.lti, delay_s=m / FS)
    u_d = np.vstack([np.zeros((m, 2)), u[:-m]])
    errs = coulomb_port_profile(delayed, u, y, FS, Bp, Cp, FC, 1)([FC[1]])
    ref = np.linalg.norm(y - _exact(u_d, FC)) / np.linalg.norm(y)
    assert errs[0] == pytest.approx(ref, rel=1e-9)


def test_the_fit_finds_the_rigid_friction():
    u = _input()
    y_ref = _exact(u, FC)
    rng = np.random.default_rng(0)
    noise = 1e-3 * np.sqrt(np.mean(y_ref**2))
    y = y_ref + noise * rng.standard_normal(y_ref.shape)
    ef = fit_port_element(RigidPorts(_model()), u, y, FS)
    assert ef.element == "coulomb_friction" and ef.parameters["on"] == "rigid_modes"
    assert ef.ports == (0, 1)
    np.testing.assert_allclose(ef.parameters["friction_force"], FC, rtol=0.01)
    floor = np.sqrt(np.mean((y - y_ref) ** 2)) / np.sqrt(np.mean(y**2))
    assert ef.error_after < 2 * floor and ef.error_before > 20 * ef.error_after


def test_rigid_ports_need_a_rigid_mode_and_a_square_model():
    with pytest.raises(InputError, match="no rigid mode"):
        RigidPorts(_model(rigid=False))
    m = _model()
    tall = ModalModel(
        modes=tuple(Mode(kind=md.kind, freq_hz=md.freq_hz, damping=md.damping, b=md.b,
                         c=np.append(md.c, 1.0)) for md in m.modes),
        D=np.zeros((3, 2)),
    )  # fmt: skip
    with pytest.raises(InputError, match="square"):
        RigidPorts(tall)


def test_a_diagnosis_fits_the_same_rigid_friction_once(monkeypatch):
    """The rigid-body friction on one model and one record is fitted once per record (the
    early element test, the final one and a pair rerun ask for the same fit); an equal model
    built anew hits the kept fit, another record or another model does not."""
    import sys

    from workbench.io.formats import TimeData

    module = sys.modules["workbench.diagnosis.diagnose"]
    calls = []
    monkeypatch.setattr(module, "_RIGID_FITS", {})
    monkeypatch.setattr(
        "workbench.diagnosis.nonlinear.fit_port_element",
        lambda *a, **k: calls.append(1) or fit_port_element(*a, **k),
    )
    u = _input()
    y = _exact(u, FC)
    data = TimeData(fs=FS, u=u, y=y)
    first = module._rigid_fit(RigidPorts(_model()), data)
    again = module._rigid_fit(RigidPorts(_model()), data)
    assert again is first and len(calls) == 1
    other_record = TimeData(fs=FS, u=u, y=y.copy())
    module._rigid_fit(RigidPorts(_model()), other_record)
    assert len(calls) == 2
    stiffer = _model()
    modes = list(stiffer.modes)
    modes[-1] = modes[-1].moved(45.0, 0.02)
    module._rigid_fit(RigidPorts(ModalModel(modes=tuple(modes), D=stiffer.D)), data)
    assert len(calls) == 3


def _shared_body_record():
    """A model whose one rigid body both inputs push (no free body per port: the smooth law
    at RIGID_SUBSTEPS and finer), and a record of that body on a spring (linear: friction
    explains little of it)."""
    b = np.array([0.5, 0.5])
    flex = Mode(kind="flexible", freq_hz=40.0, damping=0.02, b=FLEX_B, c=FLEX_C)
    free = ModalModel(modes=(Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=b, c=b), flex),
                      D=np.zeros((2, 2)))  # fmt: skip
    sprung = ModalModel(modes=(Mode(kind="flexible", freq_hz=4.0, damping=0.05, b=b, c=b), flex),
                        D=np.zeros((2, 2)))  # fmt: skip
    u = _input()
    y = sim.simulate_zoh(sprung.to_lti(), u, FS)
    y += 1e-3 * np.sqrt(np.mean(y**2)) * np.random.default_rng(1).standard_normal(y.shape)
    return free, u, y


def test_a_friction_fit_far_above_the_need_is_not_converged(monkeypatch):
    """With ``give_up_above`` far below what the coarse fit reaches, the levels are not
    refitted at finer substep counts: fewer simulations, the coarse count reported, and no
    lower error than the whole fit's."""
    import workbench.diagnosis.nonlinear as nonlinear

    free, u, y = _shared_body_record()
    runs = []
    original = nonlinear._simulate
    monkeypatch.setattr(nonlinear, "_simulate", lambda *a, **k: runs.append(1) or original(*a, **k))
    whole = fit_port_element(RigidPorts(free), u, y, FS)
    n_whole = len(runs)
    runs.clear()
    coarse = fit_port_element(RigidPorts(free), u, y, FS, give_up_above=1e-3 * whole.error_after)
    assert coarse.parameters["substeps"] == nonlinear.RIGID_SUBSTEPS
    assert whole.parameters["substeps"] > nonlinear.RIGID_SUBSTEPS
    assert len(runs) < n_whole
    assert whole.error_after <= coarse.error_after
    # a bound the coarse fit is within COARSE_MARGIN of: the whole fit
    runs.clear()
    again = fit_port_element(RigidPorts(free), u, y, FS, give_up_above=whole.error_after)
    assert again.parameters["substeps"] == whole.parameters["substeps"]
    assert again.error_after == whole.error_after


def test_a_given_up_rigid_fit_serves_only_lower_bounds(monkeypatch):
    import sys

    from workbench.io.formats import TimeData

    module = sys.modules["workbench.diagnosis.diagnose"]
    calls = []
    monkeypatch.setattr(module, "_RIGID_FITS", {})
    monkeypatch.setattr(
        "workbench.diagnosis.nonlinear.fit_port_element",
        lambda *a, **k: calls.append(k.get("give_up_above")) or fit_port_element(*a, **k),
    )
    free, u, y = _shared_body_record()
    data = TimeData(fs=FS, u=u, y=y)
    tiny = 1e-9
    gave_up = module._rigid_fit(RigidPorts(free), data, tiny)
    assert module._rigid_fit(RigidPorts(free), data, tiny / 2) is gave_up
    assert len(calls) == 1
    whole = module._rigid_fit(RigidPorts(free), data, None)  # more than the given-up fit
    assert len(calls) == 2 and whole is not gave_up
    # the whole fit serves every bound
    assert module._rigid_fit(RigidPorts(free), data, tiny) is whole
    assert module._rigid_fit(RigidPorts(free), data, 1.0) is whole
    assert len(calls) == 2
