"""The port-force substep (workbench._port_kernel): converged friction truth of the plants.

Oracles: a stiff ODE solver (scipy Radau, tight tolerances) on a one-mass system with
Coulomb friction; the plants' own simulation at 4x the automatic substep count, measured
against each record's noise (the error a perfect simulation model makes); casegen's
independent friction integrator (implicit Euler in the force with Richardson extrapolation,
tests/casegen.py); the NumPy reference of the compiled kernel; quadrature of the
first-order-hold integrals.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

import casegen
import plants
from plants.effects import Effects
from workbench import sim
from workbench.core.errors import InputError
from workbench.experiments import ExperimentConfig, run_experiment

#: casegen's friction, N, and v0, m/s (the clear size), per plant
FRICTION = {"beam": (2e-3 * 0.2, 1e-5), "wafer_stage": (0.2, 1e-6)}


def test_first_order_hold_matrices_are_the_integrals():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((4, 4)) - 2 * np.eye(4)
    Bp = rng.standard_normal((4, 2))
    h = 0.3
    Phi, G0, G1 = sim.phi_gamma_foh(A, Bp, h)

    def e(s):
        return scipy.linalg.expm(A * s)

    ref0 = scipy.integrate.quad_vec(lambda s: e(s) @ Bp, 0, h, epsabs=1e-14)[0]
    ref1 = scipy.integrate.quad_vec(lambda s: e(s) @ Bp * (1 - s / h), 0, h, epsabs=1e-14)[0]
    np.testing.assert_allclose(Phi, e(h), rtol=1e-12)
    np.testing.assert_allclose(G0, ref0, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(G1, ref1, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize(
    "name,fields",
    [
        ("beam", {"friction_force": 4e-4, "friction_velocity": 1e-5}),
        ("wafer_stage", {"friction_force": 0.2, "friction_velocity": 1e-6}),
        # a fractional delay (the input switching inside a substep), lags, a cubic spring
        (
            "wafer_stage",
            {
                "friction_force": (0.3, 0.1, 0, 0, 0, 0.02),
                "friction_velocity": 1e-5,
                "cubic_stiffness": (5e15, 0, 0, 0, 0, 0),
                "delay_s": 1.37e-4,
                "actuator_cutoff_hz": 2000.0,
                "sensor_cutoff_hz": 1500.0,
                "substeps": 12,
            },
        ),
    ],
    ids=["beam", "stage", "stage_delay_lags_cubic"],
)
def test_compiled_kernel_equals_the_numpy_reference(name, fields):
    plant = plants.get_plant(name, **{"delay_s": 0.0, **fields})
    d = plant.discrete
    u = np.random.default_rng(5).standard_normal((120, plant.n_u))
    u *= 0.05 if name == "beam" else 2.0
    y = d.simulate(u)
    y_ref = d._simulate_nonlinear(u, engine="python")
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-12 * np.abs(y_ref).max())
    # the sample-by-sample path (closed loops) is the same kernel
    x = np.zeros(plant.chain.n_x)
    m = d.substep.m
    um, um1 = sim.delayed(u, m), sim.delayed(u, m + 1)
    for k in range(u.shape[0]):
        x = d.advance_nonlinear(x, um[k], um1[k])
    x_ref = np.zeros(plant.chain.n_x)
    for k in range(u.shape[0]):
        x_ref = d.advance_nonlinear(x_ref, um[k], um1[k], engine="python")
    np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-12 * np.abs(x_ref).max())


def test_automatic_substeps_follow_the_friction_law():
    beam = plants.get_plant("beam", delay_s=0.0, friction_force=4e-4, friction_velocity=1e-5)
    mats = beam.chain.matrices
    mobility = np.diag(mats["Cv"] @ mats["Bp"]).max()  # 1/kg
    # the smallest n with h F_c mobility / v0 <= 1/64, h = 1 / (fs n)
    n = beam.discrete.substeps
    ratio = lambda n: 4e-4 * mobility / (1e-5 * beam.fs * n)  # noqa: E731
    assert ratio(n) <= 1 / 64 < ratio(n - 1)
    assert 32 < n < 128  # 35
    stage = plants.get_plant("wafer_stage", delay_s=0.0, friction_force=0.2, friction_velocity=1e-6)
    assert stage.discrete.substeps == 128  # clamped (the ratio there is 0.84)
    assert plants.get_plant("wafer_stage").discrete.substeps == 8  # no friction
    assert plants.get_plant("wafer_stage", cubic_stiffness=1e15).discrete.substeps == 8
    assert stage.with_effects(substeps=20).discrete.substeps == 20  # an override
    # weak friction: the lower clamp, which resolves the smooth law's transitions
    weak = plants.get_plant("beam", friction_force=1e-9, friction_velocity=1e-3)
    assert weak.discrete.substeps == 32


@pytest.mark.parametrize("bad", [0, -3, 2.5, "8", True])
def test_substeps_refuses_what_is_not_a_positive_integer(bad):
    with pytest.raises(InputError, match=r"Effects.substeps: expected None .* or an integer >= 1"):
        Effects(substeps=bad)


def test_substeps_accepts_none_and_integers():
    assert Effects().substeps is None
    assert Effects(substeps=np.int64(12)).substeps == 12
    assert Effects(substeps=16.0).substeps == 16


def _radau_reference(A, B, law, u, fs):
    """y[k] = position at k / fs: Radau, rtol 1e-11, one solve per held sample."""
    Fc, v0 = law.friction_force[0], law.friction_velocity

    def rhs(_, x, uk):
        return A @ x + B[:, 0] * (uk - Fc * np.tanh(x[1] / v0))

    def jac(_, x, uk):
        J = A.copy()
        J[:, 1] -= B[:, 0] * Fc / v0 / np.cosh(x[1] / v0) ** 2
        return J

    x = np.zeros(2)
    y = np.empty(u.shape[0])
    for k in range(u.shape[0]):
        y[k] = x[0]
        sol = scipy.integrate.solve_ivp(
            rhs, (0, 1 / fs), x, method="Radau", rtol=1e-11, atol=1e-15, args=(u[k, 0],), jac=jac
        )
        x = sol.y[:, -1]
    return y


def test_one_mass_with_coulomb_friction_against_a_stiff_solver():
    """2 kg on a 400 N/m spring, 0.5 N of friction (v0 = 1 mm/s), driven at 3 and 17 Hz: it
    sticks on ~20 % of the samples. The trapezoidal port force is second order: the error
    falls 4x per halving of the substep, 4e-7 of the response at n = 16 (h F_c / (m v0) =
    1/64, the plants' automatic rule); the force held over the substep (explicit) was first
    order."""
    m, k, Fc, v0, fs = 2.0, 400.0, 0.5, 1e-3, 1000.0
    A = np.array([[0.0, 1.0], [-k / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    t = np.arange(400) / fs
    u = (1.5 * np.sin(2 * np.pi * 3 * t) + 0.4 * np.sin(2 * np.pi * 17 * t))[:, None]
    law = sim.PortLaw(
        Cv=np.array([[0.0, 1.0]]),
        Cp=np.array([[1.0, 0.0]]),
        friction_force=Fc,
        friction_velocity=v0,
        cubic_stiffness=0.0,
    )
    y_ref = _radau_reference(A, B, law, u, fs)
    vel = np.diff(y_ref) * fs
    assert 0.1 < np.mean(np.abs(vel) < 10 * v0) < 0.5  # it sticks and slips

    def error(n):
        prop = sim.substep_zoh(A, B, B, 1 / fs, n)
        y = prop.simulate(law, u, u, np.array([[1.0, 0.0]]), np.zeros((1, 1)))[0][:, 0]
        return np.linalg.norm(y - y_ref) / np.linalg.norm(y_ref)

    errors = {n: error(n) for n in (4, 8, 16, 32)}
    print({n: f"{e:.2e}" for n, e in errors.items()})
    assert errors[16] < 1e-6
    for n in (4, 8, 16):
        assert 3.5 < errors[n] / errors[2 * n] < 4.5  # second order


@functools.cache
def _beam_record(scale=1.0):
    fc, v0 = FRICTION["beam"]
    truth = plants.get_plant("beam", delay_s=0.0, friction_force=scale * fc, friction_velocity=v0)
    cfg = ExperimentConfig(kind="open_loop_multisine", n_exp=1, period=2048, periods=5)
    return truth, run_experiment(truth, cfg, rng=np.random.default_rng(1))


def _beam_record_subtle():
    return _beam_record(0.25)  # casegen's subtle size


@functools.cache
def _stage_record():
    fc, v0 = FRICTION["wafer_stage"]
    truth = plants.get_plant("wafer_stage", delay_s=0.0, friction_force=fc, friction_velocity=v0)
    cfg = ExperimentConfig(kind="closed_loop_multisine", period=2000, periods=2)
    return truth, run_experiment(truth, cfg, rng=np.random.default_rng(1))


@pytest.mark.parametrize(
    "record",
    [_beam_record, _beam_record_subtle, _stage_record],
    ids=["beam", "beam_subtle", "stage"],
)
def test_automatic_substeps_are_converged_to_a_fraction_of_the_noise(record):
    """casegen's friction (clear size; subtle on the beam too) on an open-loop beam record
    (10,240 samples) and a closed-loop stage record (4,000): the record's input replayed at the
    automatic substep count and at 4x it differ by a few hundredths of the record's noise (the
    misfit of a perfect simulation model). Measured: 0.039 (beam, 35 substeps), 0.018 (beam
    subtle, 32), 0.019 (stage, 128); with the trapezoid at 8 substeps, 1.6 (beam) and 7.4
    (stage); the subtle beam at the stiffness rule's 9, 0.29."""
    truth, data = record()
    n = truth.discrete.substeps
    y = truth.simulate_noise_free(data.u)
    noise = np.linalg.norm(data.y - y)  # the record is the truth plus its measurement noise
    y_4x = truth.with_effects(substeps=4 * n).simulate_noise_free(data.u)
    ratio = np.linalg.norm(y - y_4x) / noise
    print(f"substeps {n}: |y - y(4x)| / |noise| = {ratio:.3f}")
    assert ratio < 0.1
    # the friction matters: without it the replay misses by far more than the noise
    y_lin = truth.with_effects(friction_force=None).simulate_noise_free(data.u)
    assert np.linalg.norm(y_lin - y_4x) > 100 * noise


@pytest.mark.parametrize("record", [_beam_record, _stage_record], ids=["beam", "stage"])
def test_casegen_friction_truth_agrees_with_the_plants_converged(record):
    """casegen's own scheme (implicit Euler in the force, Richardson) and the plants'
    trapezoid at 4x its automatic count, on the records above: two independent integrators,
    within 0.05 of the record's noise (measured 0.006 beam, 0.010 stage)."""
    truth, data = record()
    name = "beam" if truth.n_y == 5 else "wafer_stage"
    own = casegen.FrictionTruth(truth, casegen.FRICTION_SUBSTEPS[name])
    y_own = own.simulate_noise_free(data.u)
    y_fine = truth.with_effects(substeps=4 * truth.discrete.substeps).simulate_noise_free(data.u)
    noise = np.linalg.norm(data.y - truth.simulate_noise_free(data.u))
    ratio = np.linalg.norm(y_own - y_fine) / noise
    print(f"{name}: |casegen - plants(4x)| / |noise| = {ratio:.4f}")
    assert ratio < 0.05
