"""Simulated experiments (workbench.experiments) and the decentralized PID (controllers)."""

from __future__ import annotations

import control
import numpy as np
import pytest

from controllers import tune_pid
from plants.base import LinearPlant
from workbench import sim
from workbench.core.errors import InputError
from workbench.experiments import (
    ExperimentConfig,
    default_controller,
    run_experiment,
    run_multisine,
    run_step,
    simulate_closed_loop,
    wafer_stage_closed_loop_record,
)
from workbench.signals.excitation import multisine
from workbench.signals.frf import frf_multisine

FS = 5000.0  # Hz, the wafer stage's sampling rate
# Rigid-body masses and inertias of the shared example stage (answer_true_model.npz):
# 20 kg in x, y, z; 0.38, 0.46, 0.58 kg m^2 about x, y, z.
STAGE_MASS = np.array([20.0, 20.0, 20.0, 0.38, 0.46, 0.58])


def rigid_stage(mass=STAGE_MASS, *, f_flex=900.0, zeta=0.01) -> control.StateSpace:
    """Six free rigid bodies plus one flexible mode at 900 Hz (the example stage: 914 Hz)."""
    n = mass.size
    wn = 2 * np.pi * f_flex
    A = np.zeros((2 * n + 2, 2 * n + 2))
    A[:n, n : 2 * n] = np.eye(n)
    A[2 * n, 2 * n + 1] = 1.0
    A[2 * n + 1, 2 * n : 2 * n + 2] = [-(wn**2), -2 * zeta * wn]
    B = np.zeros((2 * n + 2, n))
    B[n : 2 * n] = np.diag(1 / mass)
    B[2 * n + 1] = 0.01 * np.linspace(1, 0.3, n)
    C = np.zeros((n, 2 * n + 2))
    C[:, :n] = np.eye(n)
    C[:, 2 * n] = np.linspace(0.5, 1, n)
    return control.ss(A, B, C, np.zeros((n, n)))


@pytest.fixture
def stage():
    # one-sample computation delay and 1 nm sensor noise, as the nominal wafer stage
    return LinearPlant(sys=rigid_stage(), fs=FS, delay_s=2e-4, noise_std=1e-9)


def test_linear_and_step_paths_agree(stage):
    K = default_controller(stage, crossover_hz=100.0)
    r = np.random.default_rng(1).standard_normal((2000, 6)) * STAGE_MASS * 0.3
    u1, y1 = simulate_closed_loop(stage, K, r, rng=7, method="linear")
    u2, y2 = simulate_closed_loop(stage, K, r, rng=7, method="step")
    np.testing.assert_allclose(u1, u2, atol=1e-9 * np.abs(u1).max())
    np.testing.assert_allclose(y1, y2, atol=1e-9 * np.abs(y1).max())
    # u = r + K e with e = -y (set point 0): the controller's own discrete model replays it
    uc = sim.simulate_zoh(K.statespace(), -y1, FS)
    np.testing.assert_allclose(u1 - r, uc, atol=1e-9 * np.abs(uc).max())
    assert np.all(u1[0] == r[0])  # one-sample controller delay: nothing fed back at k = 0


def test_fractional_delay_closed_loop_agrees_with_step_path():
    plant = LinearPlant(sys=rigid_stage(), fs=FS, delay_s=1.4 / FS, noise_std=1e-9)
    K = default_controller(plant, crossover_hz=80.0)
    r = np.random.default_rng(2).standard_normal((500, 6)) * STAGE_MASS * 0.3
    u1, y1 = simulate_closed_loop(plant, K, r, rng=3, method="linear")
    u2, y2 = simulate_closed_loop(plant, K, r, rng=3, method="step")
    np.testing.assert_allclose(y1, y2, atol=1e-9 * np.abs(y1).max())


def test_wafer_stage_record_matches_the_paper_layout(stage):
    td = wafer_stage_closed_loop_record(stage, rng=11)
    assert td.n_samples == 10_000 and td.period == 2000 and td.loop == "closed"
    assert td.r is not None and td.n_u == 6 and td.fs == FS
    per = td.r.reshape(5, 2000, 6)
    assert np.all(per == per[0])  # r exactly periodic
    # r rms = 0.3 m/s^2 x mass: 6 N on 20 kg, 0.114 N m on 0.38 kg m^2, as the example
    np.testing.assert_allclose(td.r.std(axis=0), 0.3 * STAGE_MASS, rtol=0.01)
    assert np.all((td.y.std(axis=0) > 1e-8) & (td.y.std(axis=0) < 1e-5))  # nm to um
    again = wafer_stage_closed_loop_record(stage, rng=11)
    np.testing.assert_array_equal(again.y, td.y)


def test_wafer_stage_record_on_the_project_plant():
    import plants

    td = wafer_stage_closed_loop_record(plants.wafer_stage(), rng=0)
    assert td.n_samples == 10_000 and td.period == 2000
    assert np.all((td.y.std(axis=0) > 1e-8) & (td.y.std(axis=0) < 1e-5))


def test_closed_loop_multisine_frf_within_its_variance(stage):
    K = default_controller(stage, crossover_hz=100.0)
    design = multisine(fs=FS, period=1000, band_hz=(10, 1000), n_ch=6, rms=0.3 * STAGE_MASS, rng=4)
    exp = run_multisine(stage, design, n_periods=6, controller=K, rng=5)
    est = frf_multisine(exp)
    assert est.reference == "r"
    G0 = stage.frf(est.frf.freq)
    diag = np.arange(6)
    z = np.abs(est.frf.G - G0)[:, diag, diag] ** 2 / est.frf.G_var[:, diag, diag]
    # |e|^2/var ~ Exp(1) with the true variance: P(< 4) = 0.982; estimated variance: >= 95 %
    assert np.mean(z < 4.0) >= 0.95, np.mean(z < 4.0)


def test_pid_tuning_crossover_and_margin(stage):
    K = tune_pid(STAGE_MASS, crossover_hz=100.0, fs=FS)
    f = np.linspace(20, 400, 3801)
    L = np.einsum("fij,fjk->fik", stage.frf(f), K.frf(f))  # loop gain G K, K: e -> u
    l = L[:, np.arange(6), np.arange(6)]
    for j in range(6):
        i = np.argmin(np.abs(np.abs(l[:, j]) - 1))
        assert abs(f[i] - 100.0) < 10.0  # crossover within 10 % (Tustin, delays)
        pm = 180 + np.degrees(np.angle(l[i, j]))
        assert pm > 20.0, pm  # lead 53 deg minus integrator, low-pass and 2.5 samples delay
    unstable = tune_pid(STAGE_MASS, crossover_hz=700.0, fs=FS)
    with pytest.raises(InputError, match="unstable"):
        simulate_closed_loop(stage, unstable, np.zeros((100, 6)), rng=0, method="linear")


def test_open_loop_step_settles_at_static_gain():
    k, m, c = 1e4, 1.0, 200.0  # N/m, kg, N s/m: 16 Hz, damping ratio 1
    plant = LinearPlant(sys=control.ss(control.tf([1.0], [m, c, k])), fs=1000.0)
    td = run_step(plant, n_samples=1000, amplitude=2.0, start_sample=100, rng=0)
    assert td.loop == "open" and td.r is None
    np.testing.assert_allclose(td.y[-1, 0], 2.0 / k, rtol=1e-6)


def test_configured_runs_and_refusals(stage):
    cfg = ExperimentConfig.from_table(
        {"kind": "open_loop_multisine", "period": 500, "periods": 3, "band_hz": [10, 1000]}
    )
    td = run_experiment(stage, cfg, rng=1)
    assert td.period == 500 and td.n_samples == 6 * 3 * 500 and td.loop == "open"
    est = frf_multisine(td)
    assert est.n_blocks == 6
    noise = run_experiment(
        stage, ExperimentConfig(kind="noise", n_samples=4000, loop="closed"), rng=1
    )
    assert noise.loop == "closed" and noise.r is not None
    with pytest.raises(InputError, match="unknown key 'perod'"):
        ExperimentConfig.from_table({"kind": "noise", "perod": 3})
    with pytest.raises(InputError, match="kind"):
        ExperimentConfig.from_table({"kind": "chirp"})


def test_cli_simulate_scenario(tmp_path):
    from workbench.cli.main import main
    from workbench.io.formats import load_measurement

    toml = tmp_path / "s.toml"
    toml.write_text(
        '[scenario]\nname = "t"\nseed = 3\n[plant]\nname = "wafer_stage"\n'
        '[experiment]\nkind = "closed_loop_multisine"\n'
    )
    out = tmp_path / "m.npz"
    assert main(["simulate", str(toml), "--out", str(out)]) == 0
    td = load_measurement(out)
    assert td.n_samples == 10_000 and td.period == 2000 and td.loop == "closed"
    assert main(["simulate", str(toml), "--out", str(toml)]) == 2
