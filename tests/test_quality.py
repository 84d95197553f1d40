"""Data-quality warnings (workbench.signals.quality): each poor-data case warns once,
naming the channel or band; good data gives no warning."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.signal
from conftest import SHARED_EXAMPLES, require_shared

from workbench.cli.main import main
from workbench.core.errors import DataWarning
from workbench.io.formats import FrfData, TimeData, load_measurement, save_measurement
from workbench.signals.quality import check_measurement, runs

EXAMPLES = SHARED_EXAMPLES
FS = 2000.0  # Hz, sampling of the synthetic records (any rate would do)


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def plant_response(u: np.ndarray) -> np.ndarray:
    """A smooth 2-output response: low-pass filtered mixtures of the inputs."""
    b, a = scipy.signal.butter(2, 100.0, fs=FS)
    mix = np.array([[1.0, 0.3, -0.2], [0.1, 0.8, 0.5]])[:, : u.shape[1]]
    return scipy.signal.lfilter(b, a, u @ mix.T, axis=0)


def good_time(rng, n=8192, n_u=3, **kw) -> TimeData:
    u = rng.standard_normal((n, n_u))
    y = plant_response(u) + 1e-3 * rng.standard_normal((n, 2))
    return TimeData(fs=FS, u=u, y=y, **kw)


def multisine(rng, P: int, lines, n_u: int, M: int, *, amp=None, vary=False) -> np.ndarray:
    """(M*P, n_u) periodic multisine on the given DFT lines; random phases per
    input (and per period when ``vary``: a multi-experiment record)."""
    out = np.zeros((M, P, n_u))
    ph = rng.uniform(0, 2 * np.pi, (len(lines), n_u))
    for p in range(M):
        if vary and p:
            ph = rng.uniform(0, 2 * np.pi, (len(lines), n_u))
        X = np.zeros((P // 2 + 1, n_u), complex)
        X[lines] = (1.0 if amp is None else amp[:, None]) * np.exp(1j * ph)
        out[p] = np.fft.irfft(X, n=P, axis=0)
    return out.reshape(M * P, n_u)


def check(data) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        msgs = check_measurement(data, src="test")
    assert [str(w.message) for w in caught if w.category is DataWarning] == msgs
    for m in msgs:
        assert "\n" not in m
    return msgs


def test_good_time_data_has_no_warning(rng):
    assert check(good_time(rng)) == []


def test_good_periodic_closed_loop_has_no_warning(rng):
    P, M = 1024, 4
    r = multisine(rng, P, np.arange(1, 300), 2, M)
    u = r + 0.1 * rng.standard_normal(r.shape)
    y = plant_response(u)
    assert check(TimeData(fs=FS, u=u, y=y, r=r, loop="closed", period=P)) == []


def test_constant_input(rng):
    d = good_time(rng)
    u = d.u.copy()
    u[:, 1] = 2.5
    msgs = check(TimeData(fs=FS, u=u, y=d.y))
    assert len(msgs) == 1
    assert "input 'u1' (channel 1) is constant" in msgs[0]


def test_identical_inputs(rng):
    d = good_time(rng)
    u = d.u.copy()
    u[:, 2] = u[:, 0]
    (msg,) = check(TimeData(fs=FS, u=u, y=d.y))
    assert "'u0' and 'u2'" in msg and "proportional" in msg


def test_linearly_dependent_inputs(rng):
    d = good_time(rng)
    u = d.u.copy()
    u[:, 2] = u[:, 0] - 2 * u[:, 1]
    (msg,) = check(TimeData(fs=FS, u=u, y=d.y))
    assert "rank 2 of 3" in msg and "linearly dependent" in msg
    assert "'u0', 'u1', 'u2'" in msg


def test_multi_experiment_rank_deficient_per_line(rng):
    """r2 = (r0 delayed by 3 samples) + r1: independent over time, yet at every
    line R2 = exp(-j w 3/fs) R0 + R1, so the 3 inputs span only 2 directions."""
    P, M = 512, 4
    lines = np.arange(1, 100)
    r = multisine(rng, P, lines, 3, M, vary=True)
    blocks = r.reshape(M, P, 3)
    blocks[:, :, 2] = np.roll(blocks[:, :, 0], 3, axis=1) + blocks[:, :, 1]
    r = blocks.reshape(M * P, 3)
    y = plant_response(r)
    msgs = check(TimeData(fs=FS, u=r, y=y, r=r, loop="open", period=P))
    assert len(msgs) == 1
    assert "per-line excitation matrix" in msgs[0] and "rank 2 < 3" in msgs[0]
    assert f"{lines[0] * FS / P:g}-{lines[-1] * FS / P:g} Hz" in msgs[0]


def test_multi_experiment_full_rank_is_fine(rng):
    P, M = 512, 4
    r = multisine(rng, P, np.arange(1, 100), 3, M, vary=True)
    assert check(TimeData(fs=FS, u=r, y=plant_response(r), r=r, period=P)) == []


def test_closed_loop_without_r(rng):
    d = good_time(rng)
    (msg,) = check(TimeData(fs=FS, u=d.u, y=d.y, loop="closed"))
    assert "closed-loop data without the reference 'r'" in msg


def test_clipped_sensor(rng):
    d = good_time(rng)
    y = d.y.copy()
    top = 0.6 * y[:, 1].max()
    y[:, 1] = np.minimum(y[:, 1], top)
    (msg,) = check(TimeData(fs=FS, u=d.u, y=y))
    assert "sensor 'y1' (channel 1) looks clipped" in msg and "its max" in msg


def test_quantized_sensor_is_not_clipped(rng):
    """A coarse encoder repeats every value; only an excess at the extremes is clipping."""
    d = good_time(rng)
    y = np.round(d.y / 0.02) * 0.02
    assert check(TimeData(fs=FS, u=d.u, y=y)) == []


def test_periodic_gap_in_excited_lines(rng):
    P, M = 1024, 2
    lines = np.r_[1:80, 120:300]
    r = multisine(rng, P, lines, 2, M)
    (msg,) = check(TimeData(fs=FS, u=r, y=plant_response(r), r=r, period=P))
    f = FS / P
    assert f"no lines between {79 * f:g}-{120 * f:g} Hz" in msg


def test_periodic_weak_lines(rng):
    P, M = 1024, 2
    lines = np.arange(1, 300)
    amp = np.ones(lines.size)
    amp[(lines >= 150) & (lines < 160)] = 1e-3  # 60 dB down, < the 20 dB criterion
    r = multisine(rng, P, lines, 2, M, amp=amp)
    (msg,) = check(TimeData(fs=FS, u=r, y=plant_response(r), r=r, period=P))
    f = FS / P
    assert "10 lines more than 20 dB below" in msg and f"{150 * f:g}-{159 * f:g} Hz" in msg


def test_random_excitation_notch(rng):
    """Band-stop filtered noise (200-260 Hz) as input: a gap in the excited band."""
    n = 32768
    sos = scipy.signal.butter(8, [200.0, 260.0], btype="bandstop", fs=FS, output="sos")
    u = scipy.signal.sosfiltfilt(sos, rng.standard_normal((n, 2)), axis=0)
    (msg,) = check(TimeData(fs=FS, u=u, y=plant_response(u)))
    assert "gap in the excited band" in msg
    lo, hi = (float(x) for x in msg.split(" at ")[-1].split(" Hz")[0].split("-"))
    assert 195 < lo < 230 < hi < 265


def frf_data(rng, freq, *, snr=1e4) -> FrfData:
    w = 2 * np.pi * freq
    G = np.stack(
        [
            [1 / (-(w**2) + 2j * 0.05 * 300 * w + 300**2), 0.5 / (1j * w + 50.0)],
            [0.2 / (1j * w + 80.0), 1 / (-(w**2) + 2j * 0.03 * 900 * w + 900**2)],
        ]
    ).transpose(2, 0, 1)
    G_var = np.abs(G) ** 2 / snr
    return FrfData(freq=freq, G=G, G_var=G_var)


def test_good_frf_has_no_warning(rng):
    assert check(frf_data(rng, np.arange(1.0, 500.0))) == []
    assert check(frf_data(rng, np.logspace(0, 3, 400))) == []  # log grid: no false gap


def test_frf_noise_above_response(rng):
    d = frf_data(rng, np.arange(1.0, 500.0))
    G_var = d.G_var.copy()
    band = (d.freq >= 200) & (d.freq <= 230)
    G_var[band, 1, 0] = 4 * np.abs(d.G[band, 1, 0]) ** 2
    (msg,) = check(FrfData(freq=d.freq, G=d.G, G_var=G_var))
    assert "noise variance exceeds |G|^2" in msg
    assert "'y1'/'u0' (1,0)" in msg and "200-230 Hz" in msg


def test_frf_gap_in_lines(rng):
    freq = np.r_[np.arange(1.0, 100.0), np.arange(200.0, 300.0)]
    (msg,) = check(frf_data(rng, freq))
    assert "no lines between 99-200 Hz" in msg


def test_runs_merges_small_gaps():
    mask = np.array([0, 1, 1, 0, 1, 0, 0, 0, 1], bool)
    assert runs(mask) == [(1, 3), (4, 5), (8, 9)]
    assert runs(mask, gap=1) == [(1, 5), (8, 9)]
    assert runs(mask, gap=3) == [(1, 9)]


def test_shared_examples_warnings_are_justified():
    """The time example is clean; the FRF examples have elements below the noise
    (small cross-couplings of the stage, antiresonances of the beam): one line each."""
    require_shared()
    for case, n_expected in [
        ("example_stage_delay_time", 0),
        ("example_stage_missing_frf", 1),
        ("example_beam_none_frf", 1),
    ]:
        msgs = check(load_measurement(EXAMPLES / case / "measurement.npz"))
        assert len(msgs) == n_expected, msgs
        assert all("noise variance exceeds |G|^2" in m for m in msgs)


def test_info_prints_warning_and_exits_zero(tmp_path, rng, capsys):
    d = good_time(rng)
    u = d.u.copy()
    u[:, 0] = 0.0
    p = tmp_path / "const.npz"
    save_measurement(p, TimeData(fs=FS, u=u, y=d.y))
    assert main(["info", str(p)]) == 0
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: ")
    assert "input 'u0' (channel 0) is constant" in lines[0]
    assert "quality: 1 warning(s)" in captured.out
    assert main(["info", "--json", str(p)]) == 0
    import json

    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "time" and info["n_u"] == 3 and len(info["warnings"]) == 1


def test_data_reading_commands_warn_on_poor_data(capsys):
    """compare warns like info, one line, exit 0 (the stage FRF has noise-dominated lines)."""
    require_shared()
    from workbench.cli.main import main

    folder = EXAMPLES / "example_stage_missing_frf"
    argv = ["compare", "--model", str(folder / "nominal_model.npz")]
    assert main(argv + ["--data", str(folder / "measurement.npz")]) == 0
    warnings_ = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("warning:")]
    assert len(warnings_) == 1 and "noise variance exceeds |G|^2" in warnings_[0]
