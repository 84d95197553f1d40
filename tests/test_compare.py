"""workbench.validate.compare: within noise vs failing bands, on synthetic data with a
known truth (closed-form modal FRFs) and on the shared time example."""

from __future__ import annotations

import json

import control
import numpy as np
import pytest
from conftest import SHARED_EXAMPLES, require_shared

from workbench import sim
from workbench.cli.main import main
from workbench.core import lti
from workbench.io.formats import (
    FrfData,
    TimeData,
    load_measurement,
    load_model,
    save_measurement,
    save_model,
)
from workbench.validate.compare import band_threshold, compare

EXAMPLES = SHARED_EXAMPLES
FREQ = np.arange(1.0, 1000.0, 1.0)  # Hz: 999 lines, 1 Hz apart (a typical multisine grid)


def modal_model(modes, n_y: int, n_u: int, *, rigid: bool = True) -> control.StateSpace:
    """Sum of a rigid-body mode (1/s^2, all channels, unit gains) and flexible modes.

    modes: list of (freq_hz, damping, c (n_y,), b (n_u,)); each contributes
    c b^T / (s^2 + 2 zeta w s + w^2).
    """
    blocks_A, blocks_B, blocks_C = [], [], []
    if rigid:
        blocks_A.append(np.array([[0.0, 1.0], [0.0, 0.0]]))
        blocks_B.append(np.vstack([np.zeros(n_u), np.ones(n_u)]))
        blocks_C.append(np.column_stack([np.ones(n_y) * 0.5, np.zeros(n_y)]))
    for f, zeta, c, b in modes:
        w = 2 * np.pi * f
        blocks_A.append(np.array([[0.0, 1.0], [-(w**2), -2 * zeta * w]]))
        blocks_B.append(np.vstack([np.zeros(n_u), np.asarray(b, float)]))
        blocks_C.append(np.column_stack([np.asarray(c, float), np.zeros(n_y)]))
    from scipy.linalg import block_diag

    return control.ss(
        block_diag(*blocks_A), np.vstack(blocks_B), np.hstack(blocks_C), np.zeros((n_y, n_u))
    )


MODE_A = (150.0, 0.02, [1.0, 0.5, 0.8], [1.0, -0.6])
MODE_B = (420.0, 0.01, [0.7, -0.9, 0.0], [0.8, 0.5])  # not seen by output 2


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def noisy_frf(rng, G: np.ndarray, *, rel: float = 0.02) -> FrfData:
    """Complex Gaussian noise with known variance: |dG|^2 / G_var ~ Exp(1) exactly."""
    var = (rel * np.abs(G)) ** 2 + 1e-30
    noise = np.sqrt(var / 2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    return FrfData(freq=FREQ, G=G + noise, G_var=var)


def test_right_model_is_within_noise(rng):
    true = modal_model([MODE_A, MODE_B], 3, 2)
    data = noisy_frf(rng, lti.frf(true, FREQ))
    res = compare(true, data)
    assert res.z_mean == pytest.approx(1.0, abs=0.06)  # mean of 5994 Exp(1): sd 0.013
    assert res.z_expected == 1.0
    assert res.failing_bands == ()
    assert res.within_noise
    assert res.error == pytest.approx(
        0.02 * np.sqrt(np.pi) / 2, rel=0.1
    )  # E|CN(0,s^2)| = s sqrt(pi)/2


def test_missing_mode_flags_its_band_on_its_channels(rng):
    true = modal_model([MODE_A, MODE_B], 3, 2)
    data = noisy_frf(rng, lti.frf(true, FREQ))
    res = compare(modal_model([MODE_A], 3, 2), data)
    flagged = {(b.output, b.input) for b in res.failing_bands}
    assert flagged == {(0, 0), (0, 1), (1, 0), (1, 1)}  # MODE_B's c is 0 on output 2
    for i, j in flagged:
        bands = [b for b in res.failing_bands if (b.output, b.input) == (i, j)]
        assert any(b.f_lo_hz <= 420.0 <= b.f_hi_hz for b in bands)
    assert res.z_mean > 100


def test_delay_fails_at_high_frequency(rng):
    true = modal_model([MODE_A, MODE_B], 3, 2)
    delay_s = 1e-4  # 100 us: 3.6 deg at 100 Hz, 36 deg at 1 kHz
    data = noisy_frf(rng, lti.frf(true, FREQ, delay_s=delay_s))
    res = compare(true, data)
    assert {(b.output, b.input) for b in res.failing_bands} == {
        (i, j) for i in range(3) for j in range(2)
    }
    # relative error |1 - exp(-j w tau)| ~ w tau vs 2 % noise: fails above a few tens of Hz
    assert min(b.f_lo_hz for b in res.failing_bands) > 5.0
    for i in range(3):
        for j in range(2):  # every channel fails up to the last line
            assert any(
                b.f_hi_hz == FREQ[-1] and b.f_lo_hz < 500
                for b in res.failing_bands
                if (b.output, b.input) == (i, j)
            )
    assert compare(true, data, delay_s=delay_s).failing_bands == ()


def test_without_G_var_uses_relative_error_and_says_so(rng):
    true = modal_model([MODE_A, MODE_B], 3, 2)
    G = lti.frf(true, FREQ)
    res = compare(modal_model([MODE_A], 3, 2), FrfData(freq=FREQ, G=G))
    assert res.z_mean is None and res.frf.z is None
    assert "no G_var" in res.criterion
    assert any(b.f_lo_hz <= 420 <= b.f_hi_hz for b in res.failing_bands)
    assert compare(true, FrfData(freq=FREQ, G=G)).failing_bands == ()


def test_threshold_matches_simulation(rng):
    """Oracle for band_threshold: the running median of 9 Exp(1) exceeds T with
    probability p (checked at p = 0.01 per window by Monte Carlo)."""
    T = band_threshold(9, 0.01, 1, lambda q: -np.log(q))
    med = np.median(rng.exponential(size=(200_000, 9)), axis=1)
    assert np.mean(med > T) == pytest.approx(0.01, abs=0.0015)


def test_6x6_with_2500_lines_has_a_full_error_map(rng):
    """Shape only; its speed is measured in benchmarks/bench_speed.py (no timings in tests)."""
    freq = np.linspace(1.0, 2500.0, 2500)
    modes = [(f, 0.01, rng.standard_normal(6), rng.standard_normal(6)) for f in (300, 700, 1300)]
    sys6 = modal_model(modes, 6, 6)
    G = lti.frf(sys6, freq)
    data = FrfData(freq=freq, G=G * 1.001, G_var=(0.01 * np.abs(G)) ** 2)
    res = compare(sys6, data)
    assert res.error_map.shape == (2500, 6, 6)
    # |G_meas - G_model|^2 / G_var with a 0.1 % gain error and 1 % noise std: z = 0.01 everywhere
    assert res.z_mean == pytest.approx(0.01, rel=1e-6)


# ------------------------------------------------------------- time data
@pytest.fixture(scope="module")
def delay_case():
    require_shared()
    folder = EXAMPLES / "example_stage_delay_time"
    data = load_measurement(folder / "measurement.npz")
    nominal = load_model(folder / "nominal_model.npz")
    true = load_model(folder / "answer_true_model.npz")
    delay_s = float(np.load(folder / "answer_true_model.npz")["delay_s"])
    answer = json.loads((folder / "answer.json").read_text())
    return data, nominal, true, delay_s, answer


def test_time_nominal_fails_true_is_within_noise(delay_case):
    data, nominal, true, delay_s, answer = delay_case
    bad = compare(nominal, data)
    good = compare(true, data, delay_s=delay_s)
    assert bad.error == pytest.approx(answer["nominal_error"], rel=1e-4)
    assert good.error == pytest.approx(answer["noise_floor_error"], rel=1e-3)
    assert {b.output for b in bad.failing_bands} == set(range(6))
    assert good.failing_bands == ()
    # 4 periods after the first: z ~ F(2, 6), mean 6 / 4 = 1.5
    assert good.z_mean == pytest.approx(1.5, abs=0.15)
    assert good.z_expected == pytest.approx(1.5) and bad.z_expected == pytest.approx(1.5)
    assert bad.z_mean > 100
    # one-step prediction corrects part of the delay error but not all of it
    assert np.all(bad.time.pred_error > 5 * good.time.pred_error)


def test_time_residual_correlates_with_r_for_wrong_model(delay_case):
    data, nominal, true, delay_s, _ = delay_case
    bad = compare(nominal, data).time
    good = compare(true, data, delay_s=delay_s).time
    assert bad.xcorr_against == "r"
    assert bad.xcorr_exceeds.all()
    assert bad.xcorr_outside > 0.5
    assert good.xcorr_outside < 0.03  # ~1 % of lags by chance at 99 % bounds
    # residual spectrum: the delay error grows with frequency
    f = bad.psd_freq_hz
    ratio = bad.psd_residual / bad.psd_output
    assert np.median(ratio[(f > 500) & (f < 1500)]) > 10 * np.median(ratio[(f > 5) & (f < 50)])


def test_time_nonperiodic_declares_no_band(rng):
    sys2 = modal_model([MODE_A], 3, 2)
    fs = 5000.0
    u = rng.standard_normal((3000, 2))
    y = sim.simulate_zoh(sys2, u, fs)
    y = y + 1e-3 * np.std(y) * rng.standard_normal(y.shape)
    res = compare(sys2, TimeData(fs=fs, u=u, y=y))
    assert res.z_mean is None and res.failing_bands == ()
    assert "no noise reference" in res.criterion
    assert res.error < 0.01
    assert res.time.xcorr_against == "u"


# --------------------------------------------------------------------- CLI
def test_cli_compare_writes_json_and_plots(tmp_path, rng, capsys):
    true = modal_model([MODE_A, MODE_B], 3, 2)
    freq = FREQ[::4]
    G = lti.frf(true, freq)
    var = (0.02 * np.abs(G)) ** 2
    data = FrfData(freq=freq, G=G + np.sqrt(var / 2) * rng.standard_normal(G.shape), G_var=var)
    save_measurement(tmp_path / "data.npz", data)
    save_model(tmp_path / "model.npz", modal_model([MODE_A], 3, 2))
    out_json = tmp_path / "out" / "cmp.json"
    plots = tmp_path / "plots"
    argv = ["compare", "--model", str(tmp_path / "model.npz"), "--data", str(tmp_path / "data.npz")]
    assert main(argv + ["--json", str(out_json), "--plots", str(plots)]) == 0
    out = capsys.readouterr().out
    assert "error (spec measure)" in out and "failing bands" in out
    summary = json.loads(out_json.read_text())
    assert summary["kind"] == "frf" and not summary["within_noise"]
    assert any(b["band_hz"][0] <= 420 <= b["band_hz"][1] for b in summary["failing_bands"])
    names = sorted(p.name for p in plots.iterdir())
    assert names == ["bode_overlay.png", "error_map.png"]  # no temp files left
    for p in plots.iterdir():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in out_json.parent.iterdir()] == ["cmp.json"]


def test_cli_compare_time_plots_and_delay_from_model_file(tmp_path, delay_case, capsys):
    data, _, _, _, answer = delay_case
    short = TimeData(
        fs=data.fs,
        u=data.u[:4000],
        y=data.y[:4000],
        r=data.r[:4000],
        loop="closed",
        period=data.period,
    )
    save_measurement(tmp_path / "d.npz", short)
    true_file = EXAMPLES / "example_stage_delay_time" / "answer_true_model.npz"
    argv = ["compare", "--model", str(true_file), "--data", str(tmp_path / "d.npz")]
    assert main(argv + ["--json", str(tmp_path / "c.json"), "--plots", str(tmp_path / "p")]) == 0
    out = capsys.readouterr().out
    assert "input delay 0.0002 s" in out
    summary = json.loads((tmp_path / "c.json").read_text())
    assert summary["delay_s"] == 2e-4 and summary["kind"] == "time"
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == [
        "error_map.png",
        "residual_spectra.png",
        "residual_xcorr.png",
        "time_overlay.png",
    ]


def test_cli_compare_refuses_json_over_input(tmp_path, rng, capsys):
    true = modal_model([MODE_A], 3, 2)
    save_measurement(tmp_path / "data.npz", noisy_frf(rng, lti.frf(true, FREQ)))
    save_model(tmp_path / "model.npz", true)
    before = (tmp_path / "data.npz").read_bytes()
    argv = ["compare", "--model", str(tmp_path / "model.npz"), "--data", str(tmp_path / "data.npz")]
    assert main(argv + ["--json", str(tmp_path / "data.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refusing to write the output over an input file" in err[0]
    assert (tmp_path / "data.npz").read_bytes() == before


def test_diagnose_states_the_right_models_z_of_a_periodic_record(delay_case):
    """What is left after a diagnosis quotes F(2, d)'s mean d / (d - 2), not 1."""
    from workbench.diagnosis.diagnose import _remaining
    from workbench.modal.model import ModalModel

    data, nominal, _, _, _ = delay_case
    rem = _remaining(ModalModel.from_statespace(nominal), data)
    assert rem is not None and not rem["within_noise"]
    assert rem["z_expected"] == pytest.approx(1.5)
    assert "about 1.5 when the model is right" in rem["explanation"]


def averaged_frf(rng, G: np.ndarray, n_avg: int, *, rel: float = 0.02) -> FrfData:
    """G_var estimated from ``n_avg`` averages: the true variance times chi2(d) / d, d = 2
    (n_avg - 1), so |dG|^2 / G_var ~ F(2, d), not Exp(1)."""
    var = (rel * np.abs(G)) ** 2 + 1e-30
    noise = np.sqrt(var / 2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    d = 2 * (n_avg - 1)
    return FrfData(freq=FREQ, G=G + noise, G_var=var * rng.chisquare(d, G.shape) / d)


@pytest.mark.parametrize("n_avg", [4, 11, 30])
def test_variance_dof_reads_the_averages_from_the_scatter_of_G_var(rng, n_avg):
    from workbench.validate.compare import variance_dof

    G = lti.frf(modal_model([MODE_A, MODE_B], 3, 2), FREQ)
    d = variance_dof(averaged_frf(rng, G, n_avg).G_var)
    assert d == pytest.approx(2 * (n_avg - 1), rel=0.15)
    # an exact variance is smooth from line to line, however steep (the resonances)
    assert variance_dof((0.02 * np.abs(G)) ** 2) is None


def test_right_model_with_G_var_from_few_averages_shows_no_band(rng):
    # the F(2, 10) tail: against the Exp(1) threshold a right model showed a band in 11 of
    # 40 draws; 12 draws all clean would then happen by chance 2 % of the time
    true = modal_model([MODE_A, MODE_B], 3, 2)
    G = lti.frf(true, FREQ)
    runs = [compare(true, averaged_frf(rng, G, 6)) for _ in range(12)]
    assert [len(r.failing_bands) for r in runs] == [0] * 12  # 11 of 40 drew a band before
    assert runs[0].z_expected == pytest.approx(10 / 8, rel=0.1)  # F(2, 10): mean 10 / 8
    assert "F(2, " in runs[0].criterion
    # the heavier tail does not hide a missing mode
    res = compare(modal_model([MODE_A], 3, 2), averaged_frf(rng, G, 6))
    assert any(b.f_lo_hz <= 420.0 <= b.f_hi_hz for b in res.failing_bands)


def test_cli_compare_states_z_for_a_right_model_under_G_var_from_averages(tmp_path, rng, capsys):
    true = modal_model([MODE_A, MODE_B], 3, 2)
    save_measurement(tmp_path / "data.npz", averaged_frf(rng, lti.frf(true, FREQ), 6))
    save_model(tmp_path / "model.npz", true)
    argv = ["compare", "--model", str(tmp_path / "model.npz"), "--data", str(tmp_path / "data.npz")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    # F(2, 10): mean 1.25, as the criterion line says, not "about 1"
    assert "(about 1.2" in out and "F(2, " in out
    assert "failing bands: none, the model is within noise" in out
