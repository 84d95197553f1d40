"""workbench.sim (ZOH, delay, linear/nonlinear/closed-loop simulation) and the Controller protocol.

Oracles are independent of the code under test: closed forms for the ZOH of a
mass, the continuous-time response of a mass to a held input with a
fractional delay, scipy.signal.dlsim / control.forced_response for the linear
recursion, control.feedback / control.sample_system for the closed loop.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.signal

from controllers import Controller, StateSpaceController, StrictlyProper, tune_pid
from plants.base import LinearPlant
from workbench import sim
from workbench.core.errors import InputError

FS = 5000.0  # Hz, the wafer stage's sampling rate
T = 1.0 / FS


def _mass(m: float = 2.0) -> control.StateSpace:
    """Free mass m (kg): force (N) -> position (m)."""
    return control.ss([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0 / m]], [[1.0, 0.0]], [[0.0]])


def _random_stable(rng, n=7, n_u=2, n_y=3, *, dt=T, feedthrough=True) -> control.StateSpace:
    """Random stable discrete system: poles inside radius 0.95 by scaling a random A."""
    A = rng.standard_normal((n, n))
    A *= 0.95 / np.max(np.abs(np.linalg.eigvals(A)))
    D = rng.standard_normal((n_y, n_u)) if feedthrough else np.zeros((n_y, n_u))
    return control.ss(A, rng.standard_normal((n, n_u)), rng.standard_normal((n_y, n)), D, dt)


def _response(sys, u: np.ndarray) -> np.ndarray:
    """python-control's forced response from rest as (N, n_y), never squeezed."""
    out = control.forced_response(sys, U=u.T, squeeze=False).outputs
    return np.asarray(out).reshape(-1, u.shape[0]).T


# ------------------------------------------------------------------ discretization
@pytest.mark.parametrize("tau_frac", [0.0, 0.37])
def test_zoh_of_a_mass_matches_the_closed_form(tau_frac):
    m = 2.0
    tau = tau_frac * T
    delay = 3 * T + tau
    Ad, B0, B1, k = sim.c2d_zoh(_mass(m).A, _mass(m).B, T, delay_s=delay)
    h = T - tau  # the new input acts over [tau, T), the old one over [0, tau)
    assert k == 3
    np.testing.assert_allclose(Ad, [[1.0, T], [0.0, 1.0]], rtol=1e-14, atol=1e-18)
    np.testing.assert_allclose(B0[:, 0], [h**2 / (2 * m), h / m], rtol=1e-12)
    B1_exact = [tau**2 / (2 * m) + h * tau / m, tau / m]
    np.testing.assert_allclose(B1[:, 0], B1_exact, rtol=1e-12, atol=1e-20)


def test_fractional_delay_equals_the_continuous_response_of_a_mass():
    """x(t) of a mass under a held, delayed input is a sum of delayed parabolas (closed form)."""
    m, delay = 2.0, 2.6 * T
    rng = np.random.default_rng(0)
    u = rng.standard_normal((400, 1))
    y = sim.simulate_zoh(_mass(m), u, FS, delay_s=delay)[:, 0]
    t = np.arange(400) * T
    du = np.diff(np.concatenate([[0.0], u[:, 0]]))  # steps of the held input at k T + delay
    ramp = np.maximum(t[:, None] - (np.arange(400) * T + delay)[None, :], 0.0)
    y_exact = (ramp**2 / (2 * m)) @ du
    np.testing.assert_allclose(y, y_exact, rtol=1e-9, atol=1e-9 * np.abs(y_exact).max())


def test_first_order_lag_step_with_fractional_delay():
    tau_c = 7 * T  # time constant, s
    delay = 1.3 * T
    lag = control.ss(control.tf([1.0], [tau_c, 1.0]))
    y = sim.simulate_zoh(lag, np.ones((60, 1)), FS, delay_s=delay)[:, 0]
    t = np.arange(60) * T
    exact = np.where(t >= delay, 1.0 - np.exp(-(t - delay) / tau_c), 0.0)
    np.testing.assert_allclose(y, exact, atol=1e-13)


def test_split_delay_refuses_negative_delays():
    assert sim.split_delay(2 * T, T) == (2, 0.0)
    with pytest.raises(InputError, match="delay_s"):
        sim.split_delay(-1e-6, T)


# ------------------------------------------------------------------ linear simulation
@pytest.mark.parametrize("N", [40, 3001])  # plain recursion (short) and lifted blocks (long)
def test_dlsim_equals_scipy_and_python_control(N):
    rng = np.random.default_rng(N)
    G = _random_stable(rng)
    u = rng.standard_normal((N, 2))
    x0 = rng.standard_normal(7)
    y = sim.dlsim(G.A, G.B, G.C, G.D, u, x0=x0)
    _, y_sp, _ = scipy.signal.dlsim((G.A, G.B, G.C, G.D, T), u, x0=x0)
    np.testing.assert_allclose(y, y_sp, rtol=1e-10, atol=1e-10 * np.abs(y_sp).max())
    resp = control.forced_response(G, U=u.T, X0=x0)
    np.testing.assert_allclose(y, resp.outputs.T, rtol=1e-10, atol=1e-10 * np.abs(y_sp).max())


def test_simulate_zoh_equals_python_control_sampled_system():
    rng = np.random.default_rng(3)
    Gd = _random_stable(rng, dt=T)
    Gc = control.ss(*(np.asarray(a) for a in (Gd.A, Gd.B, Gd.C, Gd.D)))
    Gc = control.ss(Gc.A - 50 * np.eye(7), Gc.B, Gc.C, Gc.D)  # continuous, stable
    u = rng.standard_normal((2000, 2))
    y = sim.simulate_zoh(Gc, u, FS, delay_s=2 * T)
    z = control.tf([1.0], [1.0, 0.0, 0.0], T)  # two whole samples of delay
    ref = control.forced_response(control.sample_system(Gc, T, method="zoh") * z, U=u.T)
    np.testing.assert_allclose(y, ref.outputs.T, atol=1e-10 * np.abs(y).max())


def test_substep_propagation_without_port_force_is_the_delayed_zoh():
    rng = np.random.default_rng(4)
    A = rng.standard_normal((5, 5)) - 3 * np.eye(5)
    B = rng.standard_normal((5, 2))
    delay = 1.45 * T
    prop = sim.substep_zoh(A, B, np.zeros((5, 1)), T, 6, delay_s=delay)
    Ad, B0, B1, m = sim.c2d_zoh(A, B, T, delay_s=delay)
    x, un, uo = rng.standard_normal(5), rng.standard_normal(2), rng.standard_normal(2)
    none = sim.PortLaw(
        Cv=np.ones((1, 5)),
        Cp=np.ones((1, 5)),
        friction_force=0.0,
        friction_velocity=1.0,
        cubic_stiffness=0.0,
    )
    assert prop.m == m == 1
    for engine in ("compiled", "python"):
        x1 = prop.advance(x, un, uo, none, engine=engine)
        np.testing.assert_allclose(x1, Ad @ x + B0 @ un + B1 @ uo, rtol=1e-12)


# ------------------------------------------------------------------ controller protocol
def test_pid_is_a_controller_and_its_statespace_is_its_step():
    K = tune_pid([20.0, 0.4], crossover_hz=100.0, fs=FS)
    assert isinstance(K, Controller) and isinstance(K, StrictlyProper) and K.linear
    ss = K.statespace()
    assert ss.dt == pytest.approx(T) and (ss.ninputs, ss.noutputs) == (K.n_y, K.n_u)
    e = np.random.default_rng(5).standard_normal((300, 2))
    state = K.init()
    u = np.empty((300, 2))
    for k in range(300):
        u[k], state = K.step(state, e[k])
    ref = control.forced_response(ss, U=e.T).outputs.T
    np.testing.assert_allclose(u, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_pid_sign_convention_positive_gain_on_the_error():
    """u = K e: a positive error pushes the plant input up (spec 5); |K| = m w^2 at crossover."""
    K = tune_pid([2.0], crossover_hz=50.0, fs=FS)
    G = K.frf(np.array([50.0]))[0, 0, 0]
    assert abs(abs(G) - 2.0 * (2 * np.pi * 50.0) ** 2) < 0.05 * 2.0 * (2 * np.pi * 50.0) ** 2
    dc = K.frf(np.array([0.01]))[0, 0, 0]
    assert dc.real > 0  # integral action with positive sign


def test_state_space_controller_from_spec_arrays_and_refusals():
    rng = np.random.default_rng(6)
    Kss = _random_stable(rng, n=3, n_u=2, n_y=2)
    arrays = dict(A=Kss.A, B=Kss.B, C=Kss.C, D=Kss.D, dt=np.array(T), role=np.array("controller"))
    K = StateSpaceController.from_arrays(arrays)
    assert isinstance(K, Controller) and K.fs == pytest.approx(FS) and (K.n_u, K.n_y) == (2, 2)
    np.testing.assert_array_equal(K.statespace().A, Kss.A)
    with pytest.raises(InputError, match="role"):
        StateSpaceController.from_arrays({**arrays, "role": np.array("plant")})
    with pytest.raises(InputError, match="discrete"):
        StateSpaceController.from_arrays({**arrays, "dt": np.array(0.0)})
    with pytest.raises(InputError, match="direct feedthrough"):
        K.output(K.init())


# ------------------------------------------------------------------ closed loop
def _plant_and_controller(rng):
    G = control.ss(_mass(2.0).A - np.diag([0.0, 5.0]), _mass(2.0).B, _mass(2.0).C, 0)  # damped
    K = tune_pid([2.0], crossover_hz=60.0, fs=FS, delay_samples=0)
    return G, StateSpaceController.from_statespace(K.statespace())


@pytest.mark.parametrize("delay_samples", [0, 2])
def test_closed_loop_equals_control_feedback(delay_samples):
    rng = np.random.default_rng(7)
    G, K = _plant_and_controller(rng)
    r = rng.standard_normal((3000, 1)) * 1e-6
    u, y = sim.closed_loop(G, K, r=r, delay_samples=delay_samples, method="linear")
    Gd = control.sample_system(G, T, method="zoh")
    z_d = control.tf([1.0], [1.0] + [0.0] * delay_samples, T)
    L = Gd * z_d * K.statespace()
    ref = _response(control.feedback(L, 1), r)
    np.testing.assert_allclose(y, ref, atol=1e-9 * np.abs(ref).max())
    # u is the controller's output on e = r - y, delayed
    e_to_u = _response(K.statespace() * z_d, r - y)
    np.testing.assert_allclose(u, e_to_u, atol=1e-9 * np.abs(u).max())


def test_closed_loop_step_path_equals_linear_path_on_a_noisy_plant():
    rng = np.random.default_rng(8)
    G, K = _plant_and_controller(rng)
    plant = LinearPlant(sys=G, fs=FS, delay_s=0.4 * T, noise_std=1e-9)
    d = rng.standard_normal((1500, 1))
    r = rng.standard_normal((1500, 1)) * 1e-6
    kw = dict(r=r, d=d, delay_samples=1)
    u1, y1 = sim.closed_loop(plant, K, rng=np.random.default_rng(1), method="linear", **kw)
    u2, y2 = sim.closed_loop(plant, K, rng=np.random.default_rng(1), method="step", **kw)
    np.testing.assert_allclose(y1, y2, atol=1e-9 * np.abs(y1).max())
    np.testing.assert_allclose(u1, u2, atol=1e-9 * np.abs(u1).max())
    assert np.all(u1[0] == d[0])  # one sample of loop delay: nothing fed back at k = 0


def test_closed_loop_refusals():
    rng = np.random.default_rng(9)
    G, K = _plant_and_controller(rng)
    plant = LinearPlant(sys=G, fs=FS)
    with pytest.raises(InputError, match="direct feedthrough"):  # D != 0: u[k] needs y[k]
        sim.closed_loop(plant, K, d=np.ones((10, 1)), rng=rng, method="step")
    slow = tune_pid([2.0], crossover_hz=50.0, fs=1000.0)
    with pytest.raises(InputError, match="fs = 5000 Hz like the plant"):
        sim.closed_loop(plant, slow, d=np.ones((10, 1)), rng=rng)
    with pytest.raises(InputError, match="dt = 0.001 s"):
        sim.closed_loop(control.sample_system(G, T), slow, r=np.ones((10, 1)))
    with pytest.raises(InputError, match="r: expected shape"):
        sim.closed_loop(G, K, r=np.ones((10, 2)))
    hot = tune_pid([2.0], crossover_hz=700.0, fs=FS)  # 3 samples of delay: no phase left
    with pytest.raises(InputError, match="unstable"):
        sim.closed_loop(G, hot, r=np.ones((10, 1)), delay_samples=3, method="linear")


def test_simulate_zoh_applies_an_ltimodel_delay():
    from workbench.core.model import LTIModel

    m, delay = 2.0, 1.5 / FS
    sys = _mass(m)
    u = np.random.default_rng(5).standard_normal((200, 1))
    ref = sim.simulate_zoh(sys, u, FS, delay_s=delay)
    model = LTIModel.from_statespace(sys, delay_s=delay)
    np.testing.assert_array_equal(sim.simulate_zoh(model, u, FS), ref)
    # the argument adds to the model's own delay
    np.testing.assert_allclose(
        sim.simulate_zoh(model, u, FS, delay_s=delay),
        sim.simulate_zoh(sys, u, FS, delay_s=2 * delay),
        rtol=1e-12,
        atol=1e-15,
    )


def test_discrete_model_delays_by_whole_samples_only():
    sysd = control.c2d(_mass(1.0), 1 / FS, "zoh")
    u = np.random.default_rng(6).standard_normal((100, 1))
    y0 = sim.simulate_zoh(sysd, u, FS)
    y3 = sim.simulate_zoh(sysd, u, FS, delay_s=3 / FS)
    np.testing.assert_allclose(y3[3:], y0[:-3], rtol=1e-12, atol=1e-12 * np.abs(y0).max())
    np.testing.assert_array_equal(y3[:3], 0.0)
    with pytest.raises(InputError, match="whole samples"):
        sim.simulate_zoh(sysd, u, FS, delay_s=0.5 / FS)


# ------------------------------------------------------------------ compiled closed loop
def _random_plant_and_controller(rng, *, n=9, n_c=7, n_u=2, n_y=3):
    """A random stable continuous plant (fractional delay, noise, quantization) and a random
    stable discrete controller scaled so that the loop gain stays below 1 (small-gain stable)."""
    A = rng.standard_normal((n, n))
    A -= (np.max(np.linalg.eigvals(A).real) + 200.0) * np.eye(n)  # poles left of -200 rad/s
    G = control.ss(A, rng.standard_normal((n, n_u)), rng.standard_normal((n_y, n)), 0.0)
    G = control.ss(G.A, G.B, G.C, rng.standard_normal((n_y, n_u)) * 1e-3)
    quant = 1e-5 * np.abs(G(0)).max()  # about 1e-5 of the static gain: a few hundred levels
    plant = LinearPlant(sys=G, fs=FS, delay_s=1.4 * T, noise_std=3 * quant, quantization=quant)
    Kd = _random_stable(rng, n=n_c, n_u=n_y, n_y=n_u, dt=T, feedthrough=False)
    gain = np.abs(G(0)).sum() * np.abs(control.ss(Kd.A, Kd.B, Kd.C, 0, T)(1.0)).sum()
    K = StateSpaceController(Kd.A, Kd.B, 0.5 * Kd.C / gain, Kd.D, fs=FS)
    return plant, K


@pytest.mark.parametrize("delay_samples", [0, 1, 3], ids=["no-loop-delay", "1", "3"])
def test_compiled_loop_equals_python_step_loop_on_a_random_plant(delay_samples):
    """Kernel vs plant.step / controller.step: same noise draws, quantization, delay; 1e-12."""
    rng = np.random.default_rng(20 + delay_samples)
    plant, K = _random_plant_and_controller(rng)
    N = 3000
    d = rng.standard_normal((N, 2))
    r = rng.standard_normal((N, 3)) * 1e-3
    kw = dict(r=r, d=d, delay_samples=delay_samples, method="step")
    u1, y1 = sim.closed_loop(plant, K, rng=np.random.default_rng(5), engine="compiled", **kw)
    u2, y2 = sim.closed_loop(plant, K, rng=np.random.default_rng(5), engine="python", **kw)
    np.testing.assert_allclose(y1, y2, rtol=0, atol=1e-12 * np.abs(y2).max())
    np.testing.assert_allclose(u1, u2, rtol=0, atol=1e-12 * np.abs(u2).max())
    q = plant.quantization
    assert np.allclose(y1 / q, np.round(y1 / q), atol=1e-6)  # the outputs are quantized


def test_compiled_loop_equals_python_on_the_stage_with_saturation_and_quantization():
    """The true stage (modes above Nyquist, fractional delay, saturation, noise, quantization)."""
    import plants
    from workbench.experiments import default_controller

    stage = plants.wafer_stage(
        residual_max_hz=12e3, delay_s=1.3 / FS, saturation=4.0, quantization=1e-9
    )
    K = default_controller(stage, crossover_hz=80.0)
    rng = np.random.default_rng(30)
    d = rng.standard_normal((2000, 6)) * 3.0
    kw = dict(d=d, delay_samples=1, method="step")
    u1, y1 = sim.closed_loop(stage, K, rng=np.random.default_rng(2), engine="compiled", **kw)
    u2, y2 = sim.closed_loop(stage, K, rng=np.random.default_rng(2), engine="python", **kw)
    assert np.mean(np.abs(u1) > 4.0) > 0.05  # the saturation is active
    np.testing.assert_allclose(y1, y2, rtol=0, atol=1e-12 * np.abs(y2).max())
    # u carries the controller's integrated state over 2000 samples: the kernel's loop and
    # numpy's matmul sum in different orders (numpy 2.4.6: 2.1e-11 of max |u| = 14.7 N on 2 %
    # of the samples, rel. 2.5e-9); a logic error would differ by orders more
    np.testing.assert_allclose(u1, u2, rtol=0, atol=1e-10 * np.abs(u2).max())
    # "auto" takes the compiled loop for this linear controller on a quantized plant
    u3, y3 = sim.closed_loop(stage, K, rng=np.random.default_rng(2), d=d, delay_samples=1)
    np.testing.assert_array_equal(y3, y1)
    # friction needs the substep loop: no sampled step, the compiled engine refuses
    rough = stage.with_effects(friction_force=0.5)
    assert rough.sampled_step() is None
    with pytest.raises(InputError, match="engine: 'compiled'"):
        sim.closed_loop(rough, K, rng=rng, engine="compiled", **kw)


@pytest.mark.parametrize("bit_generator", [np.random.PCG64, np.random.MT19937])
def test_kernel_noise_draws_are_the_generators_standard_normals(bit_generator):
    """The kernel's ziggurat on the generator's bit stream = Generator.standard_normal, bit
    for bit, the generator left in the same state (1.8 M draws: ~13,000 of them take the
    wedge or the tail)."""
    from workbench import _kernels

    g1, g2 = np.random.Generator(bit_generator(41)), np.random.Generator(bit_generator(41))
    w = np.empty((200_000, 9))
    _kernels.standard_normal_fill(g1, w)
    np.testing.assert_array_equal(w, g2.standard_normal(w.shape))
    np.testing.assert_array_equal(g1.random(4), g2.random(4))


def test_compiled_loop_noise_is_drawn_as_plant_step_draws_it():
    """A plant that outputs its noise only (C = 0): y is rng.standard_normal((N, n_y)) * std
    exactly, and the caller's generator continues as after that draw."""
    rng = np.random.default_rng(42)
    plant, K = _random_plant_and_controller(rng)
    G = plant.sys
    quiet = LinearPlant(
        sys=control.ss(G.A, G.B, np.zeros_like(G.C), np.zeros_like(G.D)),
        fs=FS,
        noise_std=[1e-3, 0.0, 2e-3],  # one noise-free sensor: drawn all the same
    )
    d = rng.standard_normal((700, 2))
    g = np.random.default_rng(9)
    _, y = sim.closed_loop(quiet, K, d=d, rng=g, delay_samples=1, engine="compiled")
    ref = np.random.default_rng(9)
    np.testing.assert_array_equal(y, ref.standard_normal((700, 3)) * [1e-3, 0.0, 2e-3])
    np.testing.assert_array_equal(g.random(3), ref.random(3))


def test_compiled_loop_on_a_model_equals_the_linear_path():
    rng = np.random.default_rng(31)
    G, K = _plant_and_controller(rng)
    Ks = StateSpaceController(K.A, K.B, K.C, np.zeros_like(K.D), fs=FS)  # strictly proper
    r = rng.standard_normal((2000, 1)) * 1e-6
    u1, y1 = sim.closed_loop(G, Ks, r=r, delay_samples=0, method="linear")
    u2, y2 = sim.closed_loop(G, Ks, r=r, delay_samples=0, method="step", engine="compiled")
    np.testing.assert_allclose(y2, y1, rtol=0, atol=1e-10 * np.abs(y1).max())
    np.testing.assert_allclose(u2, u1, rtol=0, atol=1e-10 * np.abs(u1).max())


def test_compiled_loop_refusals_and_the_python_engine():
    rng = np.random.default_rng(32)
    G, K = _plant_and_controller(rng)
    plant = LinearPlant(sys=G, fs=FS)
    d = np.ones((10, 1))
    with pytest.raises(InputError, match="direct feedthrough"):  # D != 0 and no loop delay
        sim.closed_loop(plant, K, d=d, rng=rng, method="step", engine="compiled")
    with pytest.raises(InputError, match="engine: expected"):
        sim.closed_loop(plant, K, d=d, rng=rng, engine="numba")

    class Clipped(StateSpaceController):  # a nonlinear controller: the compiled loop refuses
        @property
        def linear(self):
            return False

    hot = tune_pid([2.0], crossover_hz=700.0, fs=FS)  # 3 samples of delay: no phase left
    with pytest.raises(InputError, match="unstable"):  # a linear loop is checked before it runs
        sim.closed_loop(plant, hot, d=d, rng=rng, delay_samples=3, engine="compiled")
    Kn = Clipped(K.A, K.B, K.C, K.D, fs=FS)
    with pytest.raises(InputError, match="engine: 'compiled' needs a linear controller"):
        sim.closed_loop(plant, Kn, d=d, rng=rng, delay_samples=1, engine="compiled")
    u, _ = sim.closed_loop(plant, Kn, d=d, rng=rng, delay_samples=1)  # steps in Python
    assert u.shape == (10, 1)


def test_a_missing_numba_fails_loudly_unless_the_python_engine_is_asked(monkeypatch):
    import sys

    import workbench

    rng = np.random.default_rng(33)
    plant, K = _random_plant_and_controller(rng)
    d = rng.standard_normal((50, 2))
    monkeypatch.setitem(sys.modules, "numba", None)  # as if numba were not installed
    monkeypatch.delitem(sys.modules, "workbench._kernels", raising=False)
    monkeypatch.delattr(workbench, "_kernels", raising=False)  # re-import on the next use
    with pytest.raises(ImportError, match="numba"):
        sim.closed_loop(plant, K, d=d, rng=np.random.default_rng(1), delay_samples=1)
    u, y = sim.closed_loop(
        plant, K, d=d, rng=np.random.default_rng(1), delay_samples=1, engine="python"
    )
    assert np.all(np.isfinite(y))


def test_sparse_realization_is_a_similarity_with_small_blocks():
    from scipy.linalg import block_diag

    from workbench.compiled import sparse_realization

    rng = np.random.default_rng(34)
    # three integrators (a defective triple eigenvalue at 1: one Jordan block) and a random
    # part, states scaled over 9 decades (m vs nm, as a controller's states) and permuted
    J = np.eye(3) + np.diag([1.0, 1.0], 1)
    R = rng.standard_normal((8, 8)) * 0.3
    Dsc = np.diag(10.0 ** rng.uniform(-6, 3, 11))
    A = Dsc @ block_diag(J, R) @ np.linalg.inv(Dsc)
    P = np.eye(11)[rng.permutation(11)]
    A = P @ A @ P.T
    sr = sparse_realization(A)
    np.testing.assert_allclose(
        np.linalg.solve(sr.S, A @ sr.S), sr.A, atol=1e-10 * np.abs(sr.A).max()
    )
    assert sum(sr.blocks) == 11 and max(sr.blocks) <= 3  # the Jordan block stays together
    start = np.cumsum((0,) + sr.blocks)
    mask = np.zeros((11, 11), bool)
    for a, b in zip(start[:-1], start[1:]):
        mask[a:b, a:b] = True
    assert np.all(sr.A[~mask] == 0)
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(sr.A)),
        np.sort_complex(np.linalg.eigvals(A)),
        atol=1e-4,  # a defective eigenvalue moves by eps^(1/3)
    )


def test_banded_storage_holds_the_whole_matrix():
    from workbench.compiled import banded

    rng = np.random.default_rng(35)
    A = np.diag(rng.standard_normal(6)) + np.diag(rng.standard_normal(5), 1)
    A[4, 0], A[1, 5] = 2.0, -3.0  # two rows reach beyond the tridiagonal band
    tri, rows, Er = banded(A)
    assert list(rows) == [1, 4]
    back = np.diag(tri[1]) + np.diag(tri[0, 1:], -1) + np.diag(tri[2, :-1], 1)
    back[rows] += Er
    np.testing.assert_array_equal(back, A)
