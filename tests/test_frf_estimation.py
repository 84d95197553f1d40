"""FRF estimation (workbench.signals.frf): multisine and H1 estimators against
closed-form mass-spring FRFs, their own variance, closed-loop bias, nonlinear
detection on left-out lines, zero-order-hold compensation and file round trips."""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
import pytest

from controllers import tune_pid
from plants.base import LinearPlant
from workbench import sim
from workbench.cli.main import main
from workbench.core import lti
from workbench.core.errors import InputError
from workbench.experiments import run_multisine, run_noise
from workbench.io.formats import TimeData, load_measurement, save_measurement
from workbench.signals.excitation import multisine
from workbench.signals.frf import EVEN_FREE, ODD_FREE, frf_h1, frf_multisine

FS = 1000.0  # Hz, sampling of the synthetic experiments (any rate well above the modes)
# A 3-mass chain: 2 kg masses, 4e4 N/m grounding springs, 1e4 N/m couplings, 60 N s/m
# dampers (damping ratio ~0.1, transients decay as exp(-15 t/s), < 1e-6 after one 1-s period):
# modes at about 22, 27 and 31 Hz, well inside the excited band.
MASS, K_GROUND, K_COUPLE, DAMP = 2.0, 4e4, 1e4, 60.0
NOISE_STD = 1e-7  # m, sensor noise: about 1 % of the response at 1 N rms


def chain(n: int = 3) -> control.StateSpace:
    M = np.eye(n) * MASS
    K = np.eye(n) * (K_GROUND + 2 * K_COUPLE) - K_COUPLE * (np.eye(n, k=1) + np.eye(n, k=-1))
    C = np.eye(n) * DAMP
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    B = np.vstack([np.zeros((n, n)), np.linalg.inv(M)])
    return control.ss(A, B, np.hstack([np.eye(n), np.zeros((n, n))]), np.zeros((n, n)))


def msd_frf(freq_hz, m, c, k):
    """Closed form of a mass-spring-damper, m/N: 1 / (k - m w^2 + j c w)."""
    w = 2 * np.pi * np.asarray(freq_hz)
    return 1.0 / (k - m * w**2 + 1j * c * w)


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


@pytest.fixture
def plant():
    return LinearPlant(sys=chain(), fs=FS, noise_std=NOISE_STD)


def test_multisine_error_within_own_variance(plant, rng):
    design = multisine(fs=FS, period=1000, band_hz=(2, 300), n_ch=3, rms=1.0, rng=rng)
    exp = run_multisine(plant, design, n_periods=9, rng=rng)  # 8 periods kept per block
    est = frf_multisine(exp)
    G0 = lti.frf(plant.sys, est.frf.freq)
    z = np.abs(est.frf.G - G0) ** 2 / est.frf.G_var
    # With the true variance, |e|^2/var of a circular complex Gaussian error is Exp(1):
    # P(|e| < 2 sigma) = 1 - exp(-4) = 0.982. The variance here is itself estimated (3 blocks
    # x 7 degrees of freedom), which fattens the tail a little: we ask for 95 %.
    frac = np.mean(z < 4.0)
    assert frac >= 0.95, frac
    # and the variance is not inflated either: mean of |e|^2/var near 1 (F-like, mean ~1.1)
    assert 0.8 < z.mean() < 1.4, z.mean()
    assert est.n_blocks == 3 and est.n_averages == 8


def test_orthogonal_design_and_realizations_total_variance(plant, rng):
    design = multisine(
        fs=FS,
        period=500,
        band_hz=(4, 300),
        n_ch=3,
        rms=1.0,
        design="orthogonal",
        n_exp=4,
        n_realizations=3,
        rng=rng,
    )
    exp = run_multisine(plant, design, n_periods=4, rng=rng)
    est = frf_multisine(exp)
    G0 = lti.frf(plant.sys, est.frf.freq)
    # n_blocks = 12, 3 groups of... 12 % 3 == 0: 4 groups of n_u = 3 blocks (not realizations
    # here, but any grouping of complete designs is an independent estimate)
    assert est.G_var_total is not None
    z = np.abs(est.frf.G - G0) ** 2 / est.frf.G_var
    assert np.mean(z < 4.0) >= 0.95


def test_h1_converges_to_mass_spring_damper(rng):
    m, c, k = 1.5, 30.0, 6e4  # kg, N s/m, N/m: resonance 31.8 Hz, damping ratio 0.05
    sys = control.ss(control.tf([1.0], [m, c, k]))
    errors = []
    for n_samples in (2**14, 2**18):
        plant = LinearPlant(sys=sys, fs=FS, noise_std=2e-7)  # m, about 3 % of the response
        data = run_noise(plant, n_samples=n_samples, rms=1.0, rng=rng)
        # 4096-sample segments (0.24 Hz) resolve the 3.2 Hz half-power band: Hann leakage
        # bias ~(0.24/3.2)^2 is below the noise; up to fs/10 the ZOH aliasing is < 0.5 %
        est = frf_h1(data, nperseg=4096)
        sel = (est.frf.freq > 5) & (est.frf.freq < 100)
        G0 = msd_frf(est.frf.freq[sel], m, c, k)
        rel = np.abs(est.frf.G[sel, 0, 0] - G0) / np.abs(G0)
        errors.append(np.median(rel))
        z = np.abs(est.frf.G[sel, 0, 0] - G0) ** 2 / est.frf.G_var[sel, 0, 0]
        assert 0.7 < z.mean() < 1.5, z.mean()  # variance estimate honest within 2x
    # 16 x more data: the random error falls about 4 x (1/sqrt(n)); leakage bias is below it
    assert errors[1] < errors[0] / 2.5, errors
    assert errors[1] < 0.01, errors


def test_closed_loop_indirect_estimate_unbiased_where_h1_is_biased(rng):
    """Noise fed back through the controller biases S_yu S_uu^-1 toward -1/K; S_yr S_ur^-1 not."""
    m = 2.0  # kg, a free mass
    sys = control.ss(control.tf([1.0], [m, 0.0, 0.0]))
    fs = 2000.0
    # sensor noise large enough that, fed back through K (~1e5 N/m), it rivals r in u
    plant = LinearPlant(sys=sys, fs=fs, noise_std=3e-6)  # m
    K = tune_pid([m], crossover_hz=40.0, fs=fs)
    data = run_noise(plant, n_samples=2**17, rms=0.5, controller=K, rng=rng)  # r: 0.5 N rms
    # 4096-sample segments (0.5 Hz): shorter ones leak the steep 1/f^2 spectra at 5-15 Hz
    est_r = frf_h1(data, nperseg=4096, reference="r")
    est_u = frf_h1(data, nperseg=4096, reference="u")
    f = est_r.frf.freq
    sel = (f > 5) & (f < 100)
    G0 = lti.frf(sys, f[sel])[:, 0, 0]
    rel_r = (est_r.frf.G[sel, 0, 0] - G0) / G0
    rel_u = (est_u.frf.G[sel, 0, 0] - G0) / G0
    # bias = mean relative error over lines; its standard error from the spread over lines
    se_r = np.std(rel_r.real) / np.sqrt(sel.sum())
    assert abs(np.mean(rel_r.real)) < 3 * se_r, (np.mean(rel_r.real), se_r)
    assert abs(np.mean(rel_u)) > 0.2, np.mean(rel_u)  # measured: +0.35, toward -1/K
    z = np.abs(est_r.frf.G[sel, 0, 0] - G0) ** 2 / est_r.frf.G_var[sel, 0, 0]
    assert np.mean(z < 4.0) >= 0.9
    z_u = np.abs(est_u.frf.G[sel, 0, 0] - G0) ** 2 / est_u.frf.G_var[sel, 0, 0]
    assert np.mean(z_u < 4.0) < 0.2  # the biased estimate is far outside its own variance


@dataclass(frozen=True)
class CubicOutputPlant:
    """A linear plant followed by a static cubic y = x + a x^3 (x in um), plus sensor noise."""

    lin: LinearPlant
    a: float

    def __getattr__(self, name):  # fs, n_u, n_y, names, delay_s, linear_model, frf
        return getattr(self.lin, name)

    def simulate(self, u, *, rng):
        x = sim.simulate_zoh(self.lin.sys, u, self.lin.fs) * 1e6  # um
        y = (x + self.a * x**3) * 1e-6
        return y + rng.standard_normal(y.shape) * self.lin.noise_std


@pytest.mark.parametrize("a", [0.0, 0.05], ids=["linear", "cubic"])
def test_random_odd_lines_reveal_odd_nonlinearity(a, rng):
    sys = control.ss(control.tf([1.0], [MASS, DAMP, K_GROUND]))  # 1.2 um rms at 1 N rms
    plant = CubicOutputPlant(LinearPlant(sys=sys, fs=FS, noise_std=1e-8), a)
    design = multisine(fs=FS, period=1000, band_hz=(1, 200), n_ch=1, rms=1.0, rng=rng)
    est = frf_multisine(run_multisine(plant, design, n_periods=6, rng=rng))
    odd, even = est.lines.excess_db(ODD_FREE)[0], est.lines.excess_db(EVEN_FREE)[0]
    # even bins: no even distortion from an odd (cubic) map: noise only, about 0 dB
    assert abs(even) < 3.0, even
    if a == 0:
        assert abs(odd) < 3.0, odd
    else:
        assert odd > 20.0, odd  # left-out odd lines far above the noise


def test_zoh_compensated_frf_matches_continuous_model(plant, rng):
    quiet = LinearPlant(sys=plant.sys, fs=FS)  # no noise: the estimator's arithmetic only
    design = multisine(fs=FS, period=1000, band_hz=(1, 450), n_ch=3, kind="full", rng=rng)
    exp = run_multisine(quiet, design, n_periods=4, rng=rng)
    est = frf_multisine(exp, n_transient=2)
    raw = frf_multisine(exp, zoh="none", n_transient=2)
    assert est.frf.G_var.max() < 1e-20  # noise-free: the periods agree to rounding
    f = est.frf.freq
    # the raw DFT ratio is the ZOH-discretized plant's FRF, exactly (oracle: c2d)
    Gd = lti.frf(control.c2d(plant.sys, 1 / FS, "zoh"), f)
    # (to the switching transient left after 2 periods, exp(-30) of the response)
    assert np.max(np.abs(raw.frf.G - Gd)) < 1e-6 * np.max(np.abs(Gd))
    Gc = lti.frf(plant.sys, f)
    low = f < FS / 20
    rel = np.linalg.norm(est.frf.G - Gc, axis=(1, 2)) / np.linalg.norm(Gc, axis=(1, 2))
    rel_raw = np.linalg.norm(raw.frf.G - Gc, axis=(1, 2)) / np.linalg.norm(Gc, axis=(1, 2))
    # aliasing of a 1/f^2 plant below fs/20: (f/(fs-f))^2 sinc ratio ~ 1e-4
    assert rel[low].max() < 1e-3, rel[low].max()
    # without compensation the half-sample ZOH delay shows (pi f / fs rad at f)
    assert rel_raw[low][-1] > 0.1


def test_file_round_trip_recovers_blocks(plant, rng, tmp_path):
    design = multisine(fs=FS, period=500, band_hz=(4, 300), n_ch=3, n_realizations=2, rng=rng)
    exp = run_multisine(plant, design, n_periods=4, rng=rng)
    path = tmp_path / "ms.npz"
    save_measurement(path, exp.to_time_data())
    data = load_measurement(path)
    assert data.period == 500 and data.n_samples == 2 * 3 * 4 * 500
    a, b = frf_multisine(exp), frf_multisine(data)
    assert b.n_blocks == 6
    np.testing.assert_array_equal(a.frf.freq, b.frf.freq)
    np.testing.assert_allclose(b.frf.G, a.frf.G, rtol=1e-12)
    np.testing.assert_allclose(b.frf.G_var, a.frf.G_var, rtol=1e-12)
    out = tmp_path / "frf.npz"
    assert main(["frf", str(path), "--out", str(out)]) == 0
    back = load_measurement(out)
    np.testing.assert_allclose(back.G, a.frf.G, rtol=1e-12)
    assert back.fs == FS and back.G_var is not None
    # never over the input
    assert main(["frf", str(path), "--out", str(path)]) == 2


def test_single_experiment_for_several_inputs_is_refused(plant, rng):
    design = multisine(fs=FS, period=500, band_hz=(4, 300), n_ch=3, n_exp=1, rng=rng)
    data = run_multisine(plant, design, n_periods=3, rng=rng).to_time_data()
    with pytest.raises(InputError, match="independent"):
        frf_multisine(data)


def test_h1_needs_period_free_data_and_segments(rng):
    td = TimeData(fs=FS, u=rng.standard_normal((64, 3)), y=rng.standard_normal((64, 1)))
    with pytest.raises(InputError, match="segments"):
        frf_h1(td, nperseg=32)
    with pytest.raises(InputError, match="period"):
        frf_multisine(td)


def direct_multisine(data: TimeData, n_transient: int = 1):
    """Independent, plain implementation: per block, DFT of every kept period, their mean,
    G = (Y R^H)(U R^H)^-1 per line with numpy's inverse, and the noise variance of G from
    the period-to-period residual e_p = dY_p - G dU_p (module docstring of frf_estimation).
    Blocks are the record's known ones (n_exp experiments of equal length here); the
    reference is r when recorded, else u."""
    P = data.period
    n_blk = 3  # three experiments, 5 periods each (the test's record)
    scale = 2.0 / P

    def per(x):
        return x.reshape(n_blk, -1, P, x.shape[1])[:, n_transient:]

    r = data.u if data.r is None else data.r
    Yp, Up, Rp = (np.fft.rfft(per(x), axis=2) * scale for x in (data.y, data.u, r))
    Ym, Um, Rm = Yp.mean(axis=1), Up.mean(axis=1), Rp.mean(axis=1)  # (b, f, ch)
    pw = np.sum(np.abs(Rm) ** 2, axis=(0, 2))
    pw[0] = 0
    lines = np.flatnonzero(pw > 1e-8 * pw.max())
    G = np.empty((lines.size, data.n_y, data.n_u), complex)
    var = np.empty(G.shape)
    n = Yp.shape[1]
    for i, k in enumerate(lines):
        Y, U, R = Ym[:, k].T, Um[:, k].T, Rm[:, k].T  # (ch, b)
        W = R.conj().T @ np.linalg.inv(U @ R.conj().T)  # (b, u)
        G[i] = Y @ W
        e = (Yp[:, :, k] - Ym[:, None, k]) - (Up[:, :, k] - Um[:, None, k]) @ G[i].T  # (b, p, y)
        var_e = np.sum(np.abs(e) ** 2, axis=1) / (n * (n - 1))  # (b, y)
        var[i] = var_e.T @ np.abs(W) ** 2
    return lines * data.fs / P, G, var


def test_closed_loop_multisine_matches_direct_implementation(rng):
    """Closed loop (u repeats only up to noise: the dU branch), reference r, 3 experiments."""
    plant = LinearPlant(sys=chain(), fs=FS, noise_std=1e-6)
    K = tune_pid([MASS] * 3, crossover_hz=5.0, fs=FS)
    design = multisine(fs=FS, period=200, band_hz=(5, 200), n_ch=3, design="orthogonal", rng=rng)
    data = run_multisine(plant, design, n_periods=5, controller=K, rng=rng).to_time_data()
    est = frf_multisine(data, zoh="none")
    f, G, var = direct_multisine(data)
    np.testing.assert_allclose(est.frf.freq, f)
    np.testing.assert_allclose(est.frf.G, G, rtol=1e-9, atol=1e-12 * np.abs(G).max())
    np.testing.assert_allclose(est.G_var_noise, var, rtol=1e-9)


def test_open_loop_full_multisine_matches_direct_implementation(rng):
    """Open loop (u repeats exactly: only y's spread), every bin excited (the lines form one
    band), 3 experiments: G, its noise variance and the noise of the line analysis."""
    plant = LinearPlant(sys=chain(), fs=FS, noise_std=1e-6)
    design = multisine(
        fs=FS, period=128, band_hz=(1, 499), n_ch=3, kind="full", design="orthogonal", rng=rng
    )
    data = run_multisine(plant, design, n_periods=5, rng=rng).to_time_data()
    est = frf_multisine(data, zoh="none")
    f, G, var = direct_multisine(data)
    assert f.size == 63  # bins 1..63 of a 128-sample period: one band
    np.testing.assert_allclose(est.frf.freq, f)
    np.testing.assert_allclose(est.frf.G, G, rtol=1e-9, atol=1e-12 * np.abs(G).max())
    np.testing.assert_allclose(est.G_var_noise, var, rtol=1e-9)
    # line analysis: mean over blocks of the output's period spread, as sine amplitude^2
    yp = np.fft.rfft(data.y.reshape(3, -1, 128, 3)[:, 1:], axis=2) * 2 / 128
    n = yp.shape[1]
    spread = np.sum(np.abs(yp - yp.mean(axis=1, keepdims=True)) ** 2, axis=1) / (n * (n - 1))
    np.testing.assert_allclose(est.lines.noise_var, spread.mean(axis=0)[1:64], rtol=1e-9)


def test_input_matrix_inverse_equals_numpy_and_refuses_singular(rng):
    from workbench.signals.frf import _inverse

    B = rng.standard_normal((50, 4, 4)) + 1j * rng.standard_normal((50, 4, 4))
    B = B * np.array([1e-3, 1.0, 1e4, 10.0])[:, None] * np.array([1.0, 1e5, 1e-2, 3.0])  # scales
    np.testing.assert_allclose(_inverse(B, "B"), np.linalg.inv(B), rtol=1e-8)
    B[7, :, 3] = 2.0 * B[7, :, 1]  # rank lost at one line
    with pytest.raises(InputError, match="does not separate the 4 inputs at 1 of 50 lines"):
        _inverse(B, "B")
