"""workbench.signals.periodic: one periodic record, against analytic results.

Constants: P, amplitudes and phases are arbitrary test values; the DFT of a
cosine a cos(2 pi k n / P + phi) over one period is a P/2 exp(j phi) at bin k
(numpy's unnormalized rfft), and the DFT of white noise of variance s^2 has
E|X_k|^2 = P s^2 at every bin.
"""

from __future__ import annotations

import importlib

import control
import numpy as np
import pytest

from plants.base import LinearPlant
from workbench.core.errors import InputError
from workbench.diagnosis import detect
from workbench.experiments import run_multisine
from workbench.io.formats import TimeData
from workbench.signals.excitation import multisine
from workbench.signals.periodic import EXCITED_REL_POWER, periodic_record, split_blocks

compare_mod = importlib.import_module("workbench.validate.compare")

FS = 1000.0


def cosines(P: int, n_per: int, bins, amps, phases) -> np.ndarray:
    """(n_per P, 1) sum of cosines on the given bins, periods identical bit for bit."""
    n = np.arange(P)
    x = sum(a * np.cos(2 * np.pi * k * n / P + ph) for k, a, ph in zip(bins, amps, phases))
    return np.tile(x, n_per)[:, None]


def test_dft_lines_of_a_known_periodic_signal():
    P, bins, amps, phases = 64, [3, 7, 20], [1.0, 0.5, 2.0], [0.3, -1.0, 2.5]
    u = cosines(P, 5, bins, amps, phases)
    rec = periodic_record(TimeData(fs=FS, u=u, y=3.0 * u, period=P))
    assert rec.n_blocks == 1 and list(rec.first) == [1] and list(rec.n_kept) == [4]
    assert list(rec.n_dropped) == [1]
    np.testing.assert_array_equal(rec.lines, bins)
    expected = np.array(amps) * P / 2 * np.exp(1j * np.array(phases))
    np.testing.assert_allclose(rec.U[0, bins, 0], expected, rtol=1e-12)
    np.testing.assert_allclose(rec.Y[0, bins, 0], 3 * expected, rtol=1e-12)
    np.testing.assert_allclose(rec.freq_hz[bins], np.array(bins) * FS / P)
    # a generator's signal repeats bit for bit: no spread at all
    assert rec.repeats["u"][0] and rec.deviation_spectra("u", 0) is None
    np.testing.assert_array_equal(rec.noise_var("u"), 0.0)


def test_weak_designed_line_is_excited_rounding_is_not():
    # a line 60 dB below the strongest (1e-6 in power) is designed excitation;
    # the float32 rounding of a stored signal is not
    P = 128
    u = cosines(P, 3, [5, 11], [1.0, 1e-3], [0.0, 1.0]).astype(np.float32).astype(float)
    rec = periodic_record(TimeData(fs=FS, u=u, y=u, period=P))
    np.testing.assert_array_equal(rec.lines, [5, 11])
    assert 1e-6 > EXCITED_REL_POWER


def test_measured_noisy_reference_keeps_only_the_designed_lines():
    # u measured with 1 % noise (open loop, no r): every bin carries noise far above
    # EXCITED_REL_POWER of the peak; only the designed lines stand out of it
    P, bins = 256, [4, 9, 30, 31, 77]
    rng = np.random.default_rng(11)
    u = cosines(P, 9, bins, [1.0] * 5, [0.0, 1.0, 2.0, 3.0, 4.0])
    u_meas = u + 0.01 * rng.standard_normal(u.shape)
    rec = periodic_record(TimeData(fs=FS, u=u_meas, y=u, period=P))
    assert not rec.repeats["u"][0]
    noise_bins = np.setdiff1d(np.arange(1, P // 2), bins)
    above = rec.ref_power[0, noise_bins] > EXCITED_REL_POWER * rec.ref_power.max()
    assert above.mean() > 0.9  # noise power ~ Exp(P sigma^2 / n), about 20x the threshold
    np.testing.assert_array_equal(rec.lines, bins)


def test_noise_variance_of_white_noise_matches_its_known_variance():
    P, n_per, sigma = 256, 41, 0.2
    rng = np.random.default_rng(7)
    u = cosines(P, n_per, [4, 9, 30], [1.0, 1.0, 1.0], [0.0, 0.5, 1.0])
    y = 2 * u + sigma * rng.standard_normal(u.shape)
    rec = periodic_record(TimeData(fs=FS, u=u, y=y, period=P))
    n = int(rec.n_kept[0])
    assert n == n_per - 1
    var = rec.noise_var("y")[0, :, 0]  # variance of the mean DFT, P sigma^2 / n
    ratio = var * n / (P * sigma**2)
    # 129 bins x 2 (n - 1) = 80 degrees of freedom each: the mean ratio has a 1 % spread
    assert ratio.mean() == pytest.approx(1.0, abs=0.05)
    cov = rec.noise_cov("y", lines=rec.lines)
    np.testing.assert_allclose(cov[0, :, 0, 0].real, var[rec.lines], rtol=1e-10)
    # the mean spectrum holds the periodic part to within that noise
    err = np.abs(rec.Y[0, rec.lines, 0] - 2 * rec.U[0, rec.lines, 0])
    assert np.all(err < 5 * np.sqrt(var[rec.lines]))


def test_spread_power_and_deviation_spectra_match_per_period_dfts():
    """Independent: numpy's DFT of every kept period minus the block's mean, per channel and
    bin; channels 1e6 apart in scale, so that a mix-up of channel and bin layout shows."""
    data, _, _ = two_experiments(P=64, n_per=5)
    rng = np.random.default_rng(3)
    x = rng.standard_normal((data.u.shape[0], 3)) * np.array([1.0, 1e3, 1e-3])
    rec = periodic_record(data)
    for b, p in enumerate(rec.periods(x)):
        D = np.fft.rfft(p - p.mean(axis=0), axis=1)  # (n_kept, bins, ch)
        np.testing.assert_allclose(rec.deviation_spectra(x, b), D, rtol=1e-12, atol=1e-12)
        sq = np.sum(np.abs(D) ** 2, axis=0)
        np.testing.assert_allclose(rec.spread_power(x, b), sq, rtol=1e-12)
        n = p.shape[0]
        np.testing.assert_allclose(rec.noise_var(x)[b], sq / (n * (n - 1)), rtol=1e-12)


def two_experiments(P: int = 100, n_per: int = 4) -> tuple[TimeData, np.ndarray, np.ndarray]:
    a = cosines(P, n_per, [3, 8], [1.0, 1.0], [0.0, 0.0])
    b = cosines(P, n_per, [3, 8], [1.0, 1.0], [2.0, -1.0])  # other phases: another experiment
    u = np.vstack([a, b])
    return TimeData(fs=FS, u=u, y=-u, period=P), a[:P], b[:P]


def test_multi_experiment_blocks_are_found_and_kept_apart():
    data, a, b = two_experiments()
    assert split_blocks(data.u, data.period) == [(0, 4), (4, 4)]
    rec = periodic_record(data)
    assert rec.n_blocks == 2
    np.testing.assert_array_equal(rec.first, [1, 5])
    np.testing.assert_array_equal(rec.n_kept, [3, 3])
    np.testing.assert_allclose(rec.u_mean[0], a, atol=1e-12)
    np.testing.assert_allclose(rec.u_mean[1], b, atol=1e-12)
    np.testing.assert_allclose(rec.U[1], np.fft.rfft(b, axis=0), atol=1e-10)
    assert [p.shape for p in rec.periods(data.y)] == [(3, 100, 1), (3, 100, 1)]


def test_transient_periods_are_dropped_per_block():
    data, a, b = two_experiments()
    y = data.y.copy()
    y[:20] += 5.0  # a transient in the first period of each block
    y[400:420] += 5.0
    data = TimeData(fs=FS, u=data.u, y=y, period=data.period)
    rec = periodic_record(data, n_transient=1)
    np.testing.assert_allclose(rec.y_mean, -np.stack([a, b]), atol=1e-12)
    kept_all = periodic_record(data, n_transient=0)
    assert np.abs(kept_all.y_mean[:, :20] + np.stack([a, b])[:, :20]).min() > 1.0
    # never fewer than min_periods: with 4 periods and min_periods=4 nothing is dropped
    rec4 = periodic_record(data, n_transient=1, min_periods=4)
    np.testing.assert_array_equal(rec4.n_dropped, [0, 0])


@pytest.mark.parametrize(
    "kwargs, period, match",
    [
        ({}, None, "expected a periodic"),
        ({"period": 300}, 100, "whole number of periods"),
        ({"min_periods": 5}, 100, "at least 5 period"),
        ({"n_transient": -1}, 100, "n_transient"),
        ({"reference": "x"}, 100, "reference"),
    ],
    ids=["not-periodic", "not-whole-periods", "too-short", "negative-transient", "reference"],
)
def test_refusals_are_one_line(kwargs, period, match):
    data, _, _ = two_experiments()
    data = TimeData(fs=FS, u=data.u, y=data.y, period=period)
    with pytest.raises(InputError, match=match) as info:
        periodic_record(data, **kwargs)
    assert "\n" not in str(info.value)


def test_zero_excitation_is_refused():
    with pytest.raises(InputError, match="zero excitation"):
        periodic_record(TimeData(fs=FS, u=np.zeros((200, 1)), y=np.ones((200, 1)), period=100))


# ----------------------------------------------- consumers on a multi-experiment record
def two_mass(gain: float = 1.0) -> control.StateSpace:
    """Two coupled, damped mass-spring systems (1 and 2 kg; 10 and 11 Hz)."""
    m, k, c = np.array([1.0, 2.0]), np.array([4e3, 9e3]), np.array([20.0, 32.0])
    A = np.zeros((4, 4))
    A[:2, 2:] = np.eye(2)
    A[2:, :2] = -np.diag(k / m)
    A[2:, 2:] = -np.diag(c / m)
    B = np.zeros((4, 2))
    B[2:] = gain * np.array([[1.0, 0.3], [0.2, 1.0]]) / m[:, None]
    return control.ss(A, B, np.hstack([np.eye(2), np.zeros((2, 2))]), np.zeros((2, 2)))


@pytest.fixture(scope="module")
def two_experiment_record():
    """2x2 plant, orthogonal 2-experiment multisine, 6 periods each, seeded noise."""
    rng = np.random.default_rng(3)
    plant = LinearPlant(sys=two_mass(), fs=FS, noise_std=1e-7)
    design = multisine(
        fs=FS, period=500, band_hz=(2, 200), n_ch=2, kind="random_odd", design="orthogonal", rng=rng
    )
    return run_multisine(plant, design, n_periods=6, rng=rng).to_time_data()


def _block(data: TimeData, k: int) -> TimeData:
    n = data.n_samples // 2
    sl = slice(k * n, (k + 1) * n)
    return TimeData(fs=data.fs, u=data.u[sl], y=data.y[sl], period=data.period)


def test_compare_pools_experiments_instead_of_mixing_them(two_experiment_record):
    """A 2 % gain error shows in the 2-experiment record as strongly as in its first
    experiment alone (same residual there, simulated from rest in both). Averaging the
    periods of both experiments together (the old behaviour) cancelled the model error
    and counted the experiments' difference as noise: z_mean 19 instead of ~2e4."""
    data = two_experiment_record
    right = compare_mod.compare(two_mass(), data)
    assert right.failing_bands == ()
    # F(4, 2 * 2 * 4) for a right model: mean 16 / 14
    assert right.z_mean == pytest.approx(16 / 14, rel=0.2)
    wrong = compare_mod.compare(two_mass(1.02), data)
    first_alone = compare_mod.compare(two_mass(1.02), _block(data, 0))
    assert 0.5 * first_alone.z_mean < wrong.z_mean < 2 * first_alone.z_mean
    assert wrong.failing_bands


def test_periodic_misfit_pools_experiments(two_experiment_record):
    data = two_experiment_record
    sys_wrong = two_mass(1.02)
    ym = control.forced_response(
        control.c2d(sys_wrong, 1 / FS, "zoh"), U=data.u.T, T=np.arange(data.n_samples) / FS
    ).outputs.T
    pooled = detect.periodic_misfit(data, ym)
    half = data.n_samples // 2
    alone = [detect.periodic_misfit(_block(data, k), ym[k * half : (k + 1) * half]) for k in (0, 1)]
    # the second block alone starts from the first one's state: its first period is dropped.
    # Before, the mixed periods gave 28 here (the experiments' difference taken as noise)
    assert pooled == pytest.approx(np.mean(alone), rel=0.25)


def test_linear_multi_experiment_record_shows_no_nonlinearity(two_experiment_record):
    ev = detect.nonlinearity(two_experiment_record, None)
    assert ev is not None and 0.5 < ev.f_stat < 2.0 and ev.level < 1e-4
