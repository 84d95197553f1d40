"""Plant contract (both plants) and the wafer stage's physics and effects."""

from __future__ import annotations

import numpy as np
import pytest

import plants
from plants import Effects, ExtraMode, Plant
from plants.wafer_stage import stage_geometry
from workbench import sim
from workbench.core import lti
from workbench.core.errors import InputError

# Stage parameters of the nominal machine (plants.wafer_stage.StageConfig; seed 000
# gives 913.8 Hz / 0.0091 and 1032 Hz / 0.0095, 5 kHz, 0.15 nm resolution).
STAGE_MASS_KG = 20.0
STAGE_INERTIA_KGM2 = (0.38, 0.46, 0.58)
STAGE_FLEX_HZ = (913.8, 1032.0)
STAGE_FLEX_DAMPING = (0.0091, 0.0095)
INTERFEROMETER_RESOLUTION_M = 0.15e-9


def quiet(plant):
    """The same plant without noise and quantization (for exact comparisons)."""
    return plant.with_effects(noise_std=0.0, quantization=0.0)


@pytest.fixture(scope="module")
def stage():
    return plants.wafer_stage()


def discrete_frf(plant, freq_hz: np.ndarray) -> np.ndarray:
    """Exact FRF of the ZOH-sampled plant: C (zI - Ad)^-1 (B0 + B1 z^-1) z^-m, (n_f, n_y, n_u).

    Written here from the discretization, independently of the simulator.
    """
    Ad, B0, B1, m = plant.discrete.zoh
    C = plant.chain.matrices["C"]
    z = np.exp(2j * np.pi * np.asarray(freq_hz) / plant.fs)
    eye = np.eye(Ad.shape[0])
    return np.array([C @ np.linalg.solve(zi * eye - Ad, B0 + B1 / zi) * zi ** (-m) for zi in z])


def multisine(n_period: int, lines: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One period of a random-phase multisine with unit amplitude on ``lines`` (DFT bins)."""
    U = np.zeros(n_period // 2 + 1, complex)
    U[lines] = np.exp(2j * np.pi * rng.random(lines.size))
    return np.fft.irfft(U, n_period) * n_period / 2


# --------------------------------------------------------------------------------------------
# contract, parametrized over every registered plant
# --------------------------------------------------------------------------------------------
PLANT_NAMES = sorted(plants.PLANTS)


@pytest.mark.parametrize("name", PLANT_NAMES, ids=PLANT_NAMES)
def test_contract_shapes_and_names(name):
    plant = plants.get_plant(name)
    assert isinstance(plant, Plant)
    assert len(plant.input_names) == plant.n_u and len(plant.output_names) == plant.n_y
    sys = plant.linear_model()
    assert (sys.ninputs, sys.noutputs) == (plant.n_u, plant.n_y)
    assert sys.dt == 0
    G = plant.frf(np.array([1.0, 10.0, 100.0]))
    assert G.shape == (3, plant.n_y, plant.n_u)
    y = plant.simulate(np.zeros((50, plant.n_u)), rng=np.random.default_rng(0))
    assert y.shape == (50, plant.n_y) and np.all(np.isfinite(y))


@pytest.mark.parametrize("name", PLANT_NAMES, ids=PLANT_NAMES)
def test_contract_frf_matches_state_space(name):
    """The modal-sum FRF equals C (sI - A)^-1 B e^{-s tau} of the state-space model (a direct
    solve per line: independent of the modal sum)."""
    plant = plants.get_plant(name, actuator_cutoff_hz=700.0, sensor_cutoff_hz=900.0, delay_s=3e-4)
    f = np.geomspace(0.5, plant.fs / 2, 200)
    G = plant.frf(f)
    sys = plant.linear_model()
    A, B, C = (np.asarray(m) for m in (sys.A, sys.B, sys.C))
    eye = np.eye(A.shape[0])
    G_ref = np.array(
        [
            C @ np.linalg.solve(2j * np.pi * fi * eye - A, B) * np.exp(-2j * np.pi * fi * 3e-4)
            for fi in f
        ]
    )
    assert np.max(np.abs(G - G_ref) / np.abs(G_ref).max(axis=(1, 2), keepdims=True)) < 1e-9


@pytest.mark.parametrize("name", PLANT_NAMES, ids=PLANT_NAMES)
def test_contract_randomness_only_through_rng(name):
    plant = plants.get_plant(name)
    u = np.random.default_rng(1).standard_normal((200, plant.n_u))
    y1 = plant.simulate(u, rng=np.random.default_rng(5))
    y2 = plant.simulate(u, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(y1, y2)
    with pytest.raises(InputError, match="rng"):
        plant.simulate(u, rng=None)
    with pytest.raises(InputError, match="u: expected"):
        plant.simulate(u[:, :1], rng=np.random.default_rng(0))


def test_contract_refuses_unknown_names():
    with pytest.raises(InputError, match="unknown name"):
        plants.get_plant("crane")
    with pytest.raises(InputError, match="unknown field"):
        plants.get_plant("wafer_stage", dealy_s=1e-4)
    with pytest.raises(InputError, match="no rigid-body modes"):
        plants.beam(suspension_freq_hz=5.0)
    with pytest.raises(InputError, match="extra_modes"):
        plants.wafer_stage(extra_modes=(ExtraMode(1000.0, 0.01, [1.0] * 3, [1.0] * 6),))


@pytest.mark.parametrize("name", PLANT_NAMES, ids=PLANT_NAMES)
def test_simulation_matches_plain_state_recursion(name):
    """Fast block simulator == workbench.sim.simulate_zoh (plain loop) with every linear effect
    on, including a fractional delay (0.65 samples + 1)."""
    fs = plants.get_plant(name).fs
    plant = quiet(
        plants.get_plant(
            name,
            delay_s=1.65 / fs,
            actuator_cutoff_hz=fs / 3,
            sensor_cutoff_hz=fs / 2.5,
            residual_max_hz=3 * fs,
            crosstalk_output=0.01 * np.ones((plants.get_plant(name).n_y,) * 2),
        )
    )
    u = np.random.default_rng(2).standard_normal((2000, plant.n_u))
    y = plant.simulate(u, rng=np.random.default_rng(0))
    y_ref = sim.simulate_zoh(plant.linear_model(), u, plant.fs, delay_s=plant.delay_s)
    assert np.max(np.abs(y - y_ref)) < 1e-9 * np.max(np.abs(y_ref))


@pytest.mark.parametrize("name", PLANT_NAMES, ids=PLANT_NAMES)
def test_simulated_multisine_matches_sampled_frf(name):
    """Steady-state multisine response / input = the exact discrete-time FRF of the ZOH model;
    at low frequency it is the continuous FRF times the ZOH factor (aliasing negligible)."""
    base = plants.get_plant(name)
    # a well-damped suspension lets the transient die out within a few periods
    if name == "wafer_stage":
        extra = {"suspension_freq_hz": 5.0, "suspension_damping": 0.5}
    else:
        extra = {"config": plants.BeamConfig(suspension_damping=0.5)}
    plant = quiet(
        plants.get_plant(name, delay_s=1.4 / base.fs, actuator_cutoff_hz=base.fs / 4, **extra)
    )
    P = 1024
    lines = np.arange(1, 400)
    j = 0  # excite the first input
    u1 = multisine(P, lines, np.random.default_rng(3))
    n_per = 12 if name == "wafer_stage" else 30  # beam: first bending mode 35 Hz, z = 0.0054
    u = np.zeros((P * n_per, plant.n_u))
    u[:, j] = np.tile(u1, n_per)
    y = plant.simulate(u, rng=np.random.default_rng(0))
    Y = np.fft.rfft(y[-P:], axis=0)[lines]
    U = np.fft.rfft(u[-P:, j])[lines]
    G_sim = Y / U[:, None]
    f = lines * plant.fs / P
    G_d = discrete_frf(plant, f)[:, :, j]
    scale = np.abs(G_d).max(axis=1, keepdims=True)
    assert np.max(np.abs(G_sim - G_d) / scale) < 1e-6
    low = f < plant.fs / 20
    G_c = plant.frf(f[low])[:, :, j] * lti.zoh_frf(f[low], plant.fs)[:, None]
    rel = np.abs(G_sim[low] - G_c) / np.abs(G_c).max(axis=1, keepdims=True)
    assert np.max(rel) < 0.02


@pytest.mark.parametrize("name", PLANT_NAMES, ids=PLANT_NAMES)
@pytest.mark.parametrize("nonlinear", [False, True], ids=["linear", "friction"])
def test_step_equals_simulate(name, nonlinear):
    base = plants.get_plant(name)
    fx = {"friction_force": 0.5, "friction_velocity": 1e-3} if nonlinear else {}
    plant = quiet(plants.get_plant(name, delay_s=1.3 / base.fs, sensor_cutoff_hz=base.fs / 3, **fx))
    u = np.random.default_rng(4).standard_normal((150, plant.n_u))
    y = plant.simulate(u, rng=np.random.default_rng(0))
    state = plant.init(np.random.default_rng(0))
    ys = []
    for uk in u:
        yk, state = plant.step(state, uk)
        ys.append(yk)
    np.testing.assert_allclose(np.array(ys), y, rtol=0, atol=1e-12 * np.abs(y).max())


def test_linear_simulate_long_record(stage):
    """A 300,000-sample record runs on the linear path (its speed: benchmarks/bench_speed.py)."""
    u = np.random.default_rng(0).standard_normal((300_000, 6))
    y = stage.simulate(u, rng=np.random.default_rng(0))
    assert y.shape == (300_000, 6) and np.all(np.isfinite(y))


# --------------------------------------------------------------------------------------------
# wafer stage: rigid body, geometry, flexible modes
# --------------------------------------------------------------------------------------------
def test_stage_rigid_body_asymptote(stage):
    """|G_jj| -> 1/(m w^2) for x, y, z and 1/(J w^2) for Rx, Ry, Rz well below the modes."""
    f = np.array([0.5, 2.0, 10.0])
    G = stage.frf(f)
    w2 = (2 * np.pi * f) ** 2
    masses = (STAGE_MASS_KG,) * 3 + STAGE_INERTIA_KGM2
    for j, m in enumerate(masses):
        np.testing.assert_allclose(np.abs(G[:, j, j]), 1 / (m * w2), rtol=1e-5)
        # a double integrator: phase -180 deg (plus the small delay phase)
        np.testing.assert_allclose(
            np.angle(-G[:, j, j] * np.exp(2j * np.pi * f * 2e-4)), 0, atol=1e-4
        )
    off = G * (1 - np.eye(6))
    assert np.max(np.abs(off)) < 1e-6 * np.max(np.abs(G))


def test_stage_balancing_and_decoupling_matrices():
    geo = stage_geometry()
    assert geo["W"].shape == (8, 6) and geo["T"].shape == (6, 9)
    np.testing.assert_allclose(geo["Gamma"] @ geo["W"], np.eye(6), atol=1e-12)
    np.testing.assert_allclose(geo["T"] @ geo["M_s"], np.eye(6), atol=1e-12)


def test_stage_flexible_modes_where_seed_000_puts_them(stage):
    lam = np.linalg.eigvals(stage.linear_model().A)
    lam = lam[np.imag(lam) > 1]
    wn = np.abs(lam)
    order = np.argsort(wn)
    np.testing.assert_allclose(wn[order] / (2 * np.pi), STAGE_FLEX_HZ, rtol=1e-9)
    np.testing.assert_allclose(-np.real(lam[order]) / wn[order], STAGE_FLEX_DAMPING, rtol=1e-9)
    # each mode shows in z, Rx, Ry (out-of-plane chuck deformation) and a little in-plane
    c = stage.nominal_modes.c[6:]
    b = stage.nominal_modes.b[6:]
    for k in range(2):
        assert np.count_nonzero(np.abs(c[k, 2:5]) > 1e-2) >= 2
        assert np.count_nonzero(np.abs(b[k, 2:5]) > 1e-3) >= 2
        assert 0 < np.max(np.abs(c[k, :2])) < np.max(np.abs(c[k, 2:5]))


# --------------------------------------------------------------------------------------------
# effects act as physics says
# --------------------------------------------------------------------------------------------
def test_delay_adds_phase_not_magnitude():
    tau = 3.7e-4
    f = np.linspace(10, 2400, 50)
    G0 = plants.wafer_stage(delay_s=0.0).frf(f)
    G1 = plants.wafer_stage(delay_s=tau).frf(f)
    np.testing.assert_allclose(np.abs(G1), np.abs(G0), rtol=1e-12)
    ratio = G1[:, 2, 2] / G0[:, 2, 2]
    np.testing.assert_allclose(np.unwrap(np.angle(ratio)), -2 * np.pi * f * tau, atol=1e-9)


def test_delay_of_one_sample_shifts_the_sampled_output():
    p0 = quiet(plants.wafer_stage(delay_s=0.0))
    p1 = quiet(plants.wafer_stage(delay_s=2e-4))  # one sample at 5 kHz
    u = np.random.default_rng(0).standard_normal((500, 6))
    y0 = p0.simulate(u, rng=np.random.default_rng(0))
    y1 = p1.simulate(u, rng=np.random.default_rng(0))
    np.testing.assert_allclose(y1[1:], y0[:-1], atol=1e-12 * np.abs(y0).max())


def test_actuator_lag_is_minus_3_db_and_45_degrees_at_cutoff():
    fc = np.array([300.0, 400.0, 500.0, 600.0, 700.0, 800.0])
    p0 = plants.wafer_stage(delay_s=0.0)
    p1 = plants.wafer_stage(delay_s=0.0, actuator_cutoff_hz=fc)
    for j in range(6):
        r = p1.frf([fc[j]])[0] / p0.frf([fc[j]])[0]
        # column j only: every output sees the same factor 1/(1 + j)
        np.testing.assert_allclose(r[:, j], 1 / (1 + 1j), rtol=1e-9)
        np.testing.assert_allclose(20 * np.log10(abs(r[0, j])), -3.0103, atol=1e-3)
        np.testing.assert_allclose(np.degrees(np.angle(r[0, j])), -45.0, atol=1e-9)


def test_sensor_lag_acts_on_rows():
    fc = 1500.0
    p0 = plants.wafer_stage(delay_s=0.0)
    p1 = plants.wafer_stage(
        delay_s=0.0, sensor_cutoff_hz=(np.inf, np.inf, fc, np.inf, np.inf, np.inf)
    )
    r = p1.frf([fc])[0] / p0.frf([fc])[0]
    np.testing.assert_allclose(r[2], 1 / (1 + 1j), rtol=1e-9)  # row z
    np.testing.assert_allclose(r[[0, 1, 3, 4, 5]], 1.0, rtol=1e-12)


def test_suspension_flattens_low_frequency_magnitude_at_one_over_k():
    fs_hz, zeta = 6.0, 0.05
    p = plants.wafer_stage(delay_s=0.0, suspension_freq_hz=fs_hz, suspension_damping=zeta)
    G = p.frf([1e-3, 0.01])
    masses = np.array((STAGE_MASS_KG,) * 3 + STAGE_INERTIA_KGM2)
    k = masses * (2 * np.pi * fs_hz) ** 2  # N/m or N m/rad
    np.testing.assert_allclose(np.abs(np.diagonal(G[0])), 1 / k, rtol=1e-3)
    # resonance at the suspension frequency: |G| = 1/(2 zeta k)
    Gs = p.frf([fs_hz])[0]
    np.testing.assert_allclose(np.abs(np.diagonal(Gs)), 1 / (2 * zeta * k), rtol=1e-3)


def test_modal_frequency_and_damping_errors():
    p = plants.wafer_stage(delay_s=0.0, mode_freq_error=(0.03, -0.02), mode_damping_error=-0.5)
    flex = [k == "flexible" for k in p.modes.kind]
    np.testing.assert_allclose(p.modes.freq_hz[flex], np.array(STAGE_FLEX_HZ) * (1.03, 0.98))
    np.testing.assert_allclose(p.modes.damping[flex], np.array(STAGE_FLEX_DAMPING) * 0.5)


def test_extra_mode_is_a_resonance_antiresonance_pair_in_a_collocated_channel():
    """A collocated mode (b = c) on z adds a pole pair and, below it, a zero pair."""
    fm = 1800.0
    mode = ExtraMode(fm, 0.01, b=[0, 0, 0.1, 0, 0, 0], c=[0, 0, 0.1, 0, 0, 0])
    p0 = plants.wafer_stage(delay_s=0.0)
    p1 = plants.wafer_stage(delay_s=0.0, extra_modes=(mode,))
    f = np.linspace(1100, 2400, 2601)
    r = np.abs(p1.frf(f)[:, 2, 2] / p0.frf(f)[:, 2, 2])
    f_peak, f_dip = f[np.argmax(r)], f[np.argmin(r)]
    assert abs(f_peak - fm) < 5 and r.max() > 10
    assert 1300 < f_dip < fm and r.min() < 0.2
    # the other channels are untouched
    np.testing.assert_allclose(p1.frf(f)[:, 0, 0], p0.frf(f)[:, 0, 0])


def test_residual_modes_add_static_compliance():
    p0 = plants.wafer_stage(delay_s=0.0)
    p1 = plants.wafer_stage(delay_s=0.0, residual_max_hz=1e4)
    res = p1.residual_modes
    static = np.einsum("ky,k,ku->yu", res.c, 1 / (2 * np.pi * res.freq_hz) ** 2, res.b)
    dG = p1.frf([20.0])[0] - p0.frf([20.0])[0]
    assert np.linalg.norm(static) > 0
    np.testing.assert_allclose(dG.real, static, atol=1e-3 * np.abs(static).max())
    assert p1.modes.freq_hz.max() > p1.fs / 2


def test_crosstalk_creates_static_off_diagonal_coupling():
    X = plants.frame_rotation_crosstalk([0.0, 0.0, 1e-3])  # metrology frame 1 mrad about z
    p = plants.wafer_stage(delay_s=0.0, crosstalk_output=X)
    G = p.frf([1.0])[0]
    # to 1e-3: the flexible modes add a tiny static coupling of their own
    np.testing.assert_allclose(G[0, 1] / G[1, 1], X[0, 1], rtol=1e-3)
    np.testing.assert_allclose(G[1, 0] / G[0, 0], X[1, 0], rtol=1e-3)
    Xu = np.zeros((6, 6))
    Xu[2, 3] = 0.02  # Tx command leaks into the z force (misaligned vertical motors)
    G2 = plants.wafer_stage(delay_s=0.0, crosstalk_input=Xu).frf([1.0])[0]
    np.testing.assert_allclose(G2[2, 3] / G2[2, 2], 0.02, rtol=1e-3)


def test_saturation_clips_the_commands():
    p = quiet(plants.wafer_stage(saturation=2.0))
    u = 3 * np.random.default_rng(0).standard_normal((400, 6))
    y = p.simulate(u, rng=np.random.default_rng(0))
    y_ref = quiet(plants.wafer_stage()).simulate(np.clip(u, -2, 2), rng=np.random.default_rng(0))
    np.testing.assert_allclose(y, y_ref, atol=1e-14)


@pytest.mark.parametrize(
    "nonlinearity",
    [
        {"friction_force": (3.0, 0, 0, 0, 0, 0), "friction_velocity": 1e-4},
        {"cubic_stiffness": (5e15, 0, 0, 0, 0, 0)},
    ],
    ids=["coulomb_friction", "cubic_spring"],
)
def test_nonlinearity_puts_power_at_unexcited_lines(nonlinearity):
    """Odd multisine on Fx with lines 1, 5, 9, ... excited: an odd nonlinearity (Coulomb
    friction, cubic spring) puts power at the unexcited odd lines 3, 7, 11, ... far above the
    noise; the linear plant leaves them at the noise floor (Pintelon & Schoukens 2012, ch. 4)."""
    # a stiff, damped suspension: the transient is gone after 3 of 6 periods (0.3 s)
    susp = {"suspension_freq_hz": 10.0, "suspension_damping": 0.7, "delay_s": 0.0}
    P, n_per = 500, 6
    lines = np.arange(1, 80, 4)  # 10 Hz spacing: 10, 50, 90, ... Hz excited
    detect = lines + 2
    u1 = 4.0 * multisine(P, lines, np.random.default_rng(7))
    u = np.zeros((P * n_per, 6))
    u[:, 0] = np.tile(u1, n_per)

    def line_power(plant):
        y = plant.simulate(u, rng=np.random.default_rng(11))
        Y = np.fft.rfft(y[-2 * P :, 0].reshape(2, P), axis=1).mean(axis=0)
        return np.abs(Y[lines]) ** 2, np.abs(Y[detect]) ** 2

    exc_lin, det_lin = line_power(plants.wafer_stage(**susp))
    exc_nl, det_nl = line_power(plants.wafer_stage(**susp, **nonlinearity))
    assert np.mean(det_nl) > 1e3 * np.mean(det_lin)
    assert np.mean(det_nl) > 1e-6 * np.mean(exc_nl)


def test_quantization_and_noise_on_the_interferometer_axes():
    """The 9 axes are quantized at 0.15 nm (seed 000) and carry white noise; the decoupled
    outputs then show (sigma^2 + q^2/12) * |row of T|^2 in variance."""
    u = 50 * np.random.default_rng(0).standard_normal((20000, 6))
    p_q = plants.wafer_stage(noise_std=0.0, suspension_freq_hz=20.0)
    y_clean = quiet(p_q).simulate(u, rng=np.random.default_rng(0))
    y_q = p_q.simulate(u, rng=np.random.default_rng(0))
    T = p_q.decouple
    q = INTERFEROMETER_RESOLUTION_M
    assert p_q.measurement_quantization == q
    expected = q / np.sqrt(12) * np.linalg.norm(T, axis=1)
    np.testing.assert_allclose(np.std(y_q - y_clean, axis=0), expected, rtol=0.1)
    sigma = 0.5e-9  # StageConfig.noise_std
    p_n = plants.wafer_stage(suspension_freq_hz=20.0)
    y_n = p_n.simulate(u, rng=np.random.default_rng(0))
    expected = np.sqrt(sigma**2 + q**2 / 12) * np.linalg.norm(T, axis=1)
    np.testing.assert_allclose(np.std(y_n - y_clean, axis=0), expected, rtol=0.1)


def test_effects_are_frozen_and_validated():
    e = Effects(delay_s=1e-4)
    with pytest.raises(AttributeError):
        e.delay_s = 0.0
    with pytest.raises(InputError, match="delay_s"):
        Effects(delay_s=-1.0)
    with pytest.raises(InputError, match="actuator_cutoff_hz"):
        Effects(actuator_cutoff_hz=0.0)
    with pytest.raises(InputError, match="crosstalk_input"):
        plants.wafer_stage(crosstalk_input=np.zeros((3, 3)))
    # scenario files may give extra modes as mappings
    m = Effects(extra_modes=({"freq_hz": 1320.0, "damping": 0.012, "b": [0] * 6, "c": [0] * 6},))
    assert isinstance(m.extra_modes[0], ExtraMode)
