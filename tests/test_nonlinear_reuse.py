"""The nonlinear fit's reuse of its simulation runs, and the port kernel's shortcuts.

Oracles: the same fit with nothing reused (every run simulated afresh); the library tanh;
the kept runs themselves (a run from rest over a record's first part is the first part of
the run over the whole record).
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from test_diagnosis_generalizes_nonlinear import _two_masses

from workbench._port_kernel import _tanh
from workbench.diagnosis import nonlinear
from workbench.diagnosis.nonlinear import PortNonlinearity, fit_port_element, simulate_nonlinear

FS = 1000.0


@numba.njit
def _library_tanh(x):
    """The compiled code's tanh (not NumPy's: 19.0 gives 1 - 2^-53 there, 1 here)."""
    return np.tanh(x)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_tanh_shortcut_is_the_compiled_tanh_to_the_bit(sign):
    x = sign * np.concatenate(
        [
            [0.0, 1e-300, 0.3, 5.0, 18.0, 18.9, 19.0, 19.0615, 19.5, 20.0, 21.0, 40.0, 1e300],
            [np.inf],
            np.linspace(19.9, 20.1, 2001),  # about the shortcut's threshold
        ]
    )
    for xi in x:
        assert _tanh(xi) == _library_tanh(xi), xi
    assert np.isnan(_tanh(np.nan))


def test_run_cache_serves_shorter_parts_and_forgets_the_oldest():
    cache = nonlinear._RunCache(2)
    y, p = np.arange(20.0).reshape(10, 2), np.arange(10.0).reshape(10, 1)
    cache.put("a", y, p)
    got = cache.get("a", 4)
    np.testing.assert_array_equal(got[0], y[:4])
    np.testing.assert_array_equal(got[1], p[:4])
    assert cache.get("a", 11) is None  # longer than the run kept
    with pytest.raises(ValueError):  # shared with the callers: read-only
        got[0][0, 0] = 1.0
    cache.put("a", y[:5], p[:5])  # a shorter run does not replace the longer one
    assert cache.get("a", 10) is not None
    cache.put("b", y, p)
    cache.get("a", 1)  # "a" used: "b" is now the oldest
    cache.put("c", y, p)
    assert cache.get("b", 1) is None
    assert cache.get("a", 1) is not None and cache.get("c", 1) is not None


def test_run_key_tells_every_field_of_the_element_apart():
    base = PortNonlinearity(friction_force=np.array([1.0, 0.0]), friction_velocity=1e-5)
    others = [
        PortNonlinearity(friction_force=np.array([1.0, 1e-12]), friction_velocity=1e-5),
        PortNonlinearity(friction_force=np.array([1.0, 0.0]), friction_velocity=2e-5),
        PortNonlinearity(friction_force=np.array([1.0, 0.0]), friction_velocity=1e-5, substeps=9),
        PortNonlinearity(
            friction_force=np.array([1.0, 0.0]), friction_velocity=1e-5, cubic_stiffness=1.0
        ),
        PortNonlinearity(
            friction_force=np.array([1.0, 0.0]), friction_velocity=1e-5, saturation=np.ones(2)
        ),
    ]
    key = nonlinear._run_key(base, None)
    assert key == nonlinear._run_key(base, None)
    assert all(nonlinear._run_key(o, None) != key for o in others)
    assert nonlinear._run_key(base, np.array([0.1])) != key
    assert nonlinear._run_key(base, np.array([0.1])) != nonlinear._run_key(base, np.array([0.2]))


def test_the_fit_reusing_its_runs_is_the_fit_simulating_each_afresh(monkeypatch):
    """Friction on one mass of two (refined: the substeps converged, the levels refitted):
    the same element, levels and errors to the bit, with fewer simulations."""
    rng = np.random.default_rng(3)
    sys = _two_masses()
    u = 20.0 * rng.standard_normal((2000, 2))
    truth = PortNonlinearity(friction_force=np.array([3.0, 0.0]), friction_velocity=1e-5)
    y0 = simulate_nonlinear(sys, u, FS, truth)
    y = y0 + 1e-3 * np.std(y0, axis=0) * rng.standard_normal(y0.shape)
    calls = []
    simulate = nonlinear._simulate

    def counted(*args, **kwargs):
        calls.append(1)
        return simulate(*args, **kwargs)

    monkeypatch.setattr(nonlinear, "_simulate", counted)
    fits = {}
    for size in (nonlinear.SIMULATION_CACHE, 0):
        monkeypatch.setattr(nonlinear, "SIMULATION_CACHE", size)
        calls.clear()
        fits[size] = (fit_port_element(sys, u, y, FS, substeps=2), len(calls))
    (reused, n_reused), (fresh, n_fresh) = fits.values()
    assert n_reused < n_fresh
    assert reused.element == fresh.element == "coulomb_friction"
    assert reused.parameters == fresh.parameters
    assert reused.error_after == fresh.error_after
    assert reused.candidates == fresh.candidates
    # the outputs the fit hands on (its own run) are the element's simulation, to the bit
    for fit in (reused, fresh):
        np.testing.assert_array_equal(fit.output, simulate_nonlinear(sys, u, FS, fit.nonlinearity))


def _full_substeps(sys, u, fs, nl, sens=None):
    """The element's simulation over every state of ``sys`` (no state left to the linear
    response): the substep loop on the whole realization, as before the reduction."""
    from workbench import sim
    from workbench.core import lti

    A, B, C, D, _ = lti.as_matrices(sys)
    Bp, Cp = np.asarray(nl.port_forces, float), np.asarray(nl.port_displacements, float)
    prop = sim.substep_zoh(A, B, Bp, 1.0 / fs, nl.substeps)
    law = sim.PortLaw(
        Cv=Cp @ A,
        Cp=Cp,
        friction_force=nl.friction_force,
        friction_velocity=nl.friction_velocity,
        cubic_stiffness=0.0 if nl.cubic_stiffness is None else nl.cubic_stiffness,
    )
    return prop.simulate(law, u, u, C, D, sens=sens)


def _lagged_modal_model():
    """Actuator lags (their states drive every mode), a rigid body, three flexible modes."""
    from workbench.modal.model import ModalModel, Mode

    rng = np.random.default_rng(7)
    modes = [
        Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=rng.normal(size=2), c=rng.normal(size=3))
    ]
    for f, z in ((35.0, 0.02), (80.0, 0.01), (150.0, 0.03)):
        modes.append(
            Mode(kind="flexible", freq_hz=f, damping=z, b=rng.normal(size=2), c=rng.normal(size=3))
        )
    return ModalModel(modes=tuple(modes), D=np.zeros((3, 2)), tau_in=np.array([2e-4, 5e-4]))


def test_a_spring_on_a_mode_simulates_its_own_states_only_to_rounding():
    """The spring on one mode moves that mode's states only (the lags that drive it are
    linear): those substepped, the rest the linear response, is the whole realization
    substepped, to rounding."""
    from workbench.diagnosis.nonlinear import ModalPort, _port_states

    model = _lagged_modal_model()
    mp = ModalPort(model, 2)
    Bp, Cp = mp.maps
    A = np.asarray(mp.lti.A, float)
    on = _port_states(A, Bp, Cp)
    assert 2 < on.sum() < A.shape[0]  # the mode's 2 states and the lags: a reduction
    rng = np.random.default_rng(1)
    u = 50.0 * rng.standard_normal((1500, 2))
    from dataclasses import replace

    from workbench.sim import simulate_zoh

    y_lin = simulate_zoh(mp.lti, u, FS)
    q = simulate_zoh(replace(mp.lti, C=Cp, D=np.zeros((1, 2)), output_names=()), u, FS)
    w = 2 * np.pi * model.modes[2].freq_hz
    nl = PortNonlinearity(
        friction_force=np.zeros(1),
        cubic_stiffness=np.array([0.3 * w**2 / np.mean(q**2)]),  # +30 % stiffness at the rms
        substeps=4,
        port_forces=Bp,
        port_displacements=Cp,
    )
    y = simulate_nonlinear(mp.lti, u, FS, nl)
    y_ref = _full_substeps(mp.lti, u, FS, nl)[0]
    assert np.linalg.norm(y_ref - y_lin) > 1e-3 * np.linalg.norm(y_lin)  # the spring shows
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-11 * np.abs(y_ref).max())


def test_friction_on_rigid_bodies_simulates_their_states_only_with_its_sensitivities():
    """Smooth friction on two rigid bodies of a square model with actuator lags and a
    flexible mode: the reduced simulation (the bodies and the lags substepped) is the whole
    realization substepped, outputs, port motion and sensitivities, to rounding."""
    from workbench import sim
    from workbench.diagnosis.nonlinear import RigidPorts, _port_states, _simulate
    from workbench.modal.model import ModalModel, Mode

    rb = (np.array([0.5, 0.0]), np.array([0.0, 0.8]))
    modes = tuple(Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=b, c=b) for b in rb)
    flex = Mode(kind="flexible", freq_hz=40.0, damping=0.02, b=np.array([0.3, 0.2]),
                c=np.array([0.1, -0.4]))  # fmt: skip
    model = ModalModel(modes=modes + (flex,), D=np.zeros((2, 2)), tau_in=np.array([1e-3, 2e-3]))
    port = RigidPorts(model)
    Bp, Cp = port.maps
    A = np.asarray(port.lti.A, float)
    assert _port_states(A, Bp, Cp).sum() < A.shape[0]  # the flexible mode left out
    rng = np.random.default_rng(2)
    t = np.arange(800) / FS
    u = np.zeros((800, 2))
    for f in (3.0, 7.0, 17.0):
        u += np.outer(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)), rng.normal(size=2))
    Fc = np.array([0.3, 0.1])
    nl = PortNonlinearity(
        friction_force=Fc, friction_velocity=1e-3, substeps=8, port_forces=Bp,
        port_displacements=Cp,
    )  # fmt: skip
    sens = sim.PortSensitivity(
        friction_force=np.vstack([np.diag(Fc), np.zeros((1, 2))]),
        log_velocity=np.array([0.0, 0.0, 1.0]),
    )
    y, p, dy = _simulate(port.lti, u, FS, nl, sens=sens)
    y_ref, p_ref, dy_ref = _full_substeps(port.lti, u, FS, nl, sens=sens)
    y_lin = sim.simulate_zoh(port.lti, u, FS)
    assert np.linalg.norm(y_ref - y_lin) > 1e-2 * np.linalg.norm(y_lin)  # the friction shows
    for got, ref in ((y, y_ref), (p, p_ref), (dy, dy_ref)):
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
