"""The nonlinear fit's reuse of its simulation runs, and the port kernel's shortcuts.

Oracles: the same fit with nothing reused (every run simulated afresh); the library tanh;
the kept runs themselves (a run from rest over a record's first part is the first part of
the run over the whole record).
"""

from __future__ import annotations

import control
import numba
import numpy as np
import pytest

from workbench._port_kernel import _tanh
from workbench.diagnosis import nonlinear
from workbench.diagnosis.nonlinear import PortNonlinearity, fit_port_element, simulate_nonlinear

FS = 1000.0


def _two_masses() -> control.StateSpace:
    """Two masses (1 kg, 2 kg) on springs, a coupling spring; forces and displacements
    collocated (as in test_diagnosis_generalizes_nonlinear)."""
    M = np.diag([1.0, 2.0])
    K = np.array([[6e3, -2e3], [-2e3, 11e3]])
    C = 0.002 * K + 0.5 * M
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-Mi @ K, -Mi @ C]])
    B = np.vstack([np.zeros((2, 2)), Mi])
    return control.ss(A, B, np.hstack([np.eye(2), np.zeros((2, 2))]), 0)


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
