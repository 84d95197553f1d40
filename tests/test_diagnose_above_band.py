"""A mode fitted above the excited band: a missing mode when the record resolves its
resonance, residual compliance when it shows only a static term."""

from __future__ import annotations

import control
import numpy as np
import scipy.signal
from scipy.linalg import block_diag

from workbench.diagnosis import diagnose
from workbench.diagnosis.problem import _time_band
from workbench.io.formats import TimeData
from workbench.sim import simulate_zoh

FS = 2048.0


def modal_ss(modes) -> control.StateSpace:
    """Modes (f Hz, z, c (2,), b (2,)), each c b^T / (s^2 + 2 z w s + w^2)."""
    A, B, C = [], [], []
    for f, z, c, b in modes:
        w = 2 * np.pi * f
        A.append(np.array([[0.0, 1.0], [-(w**2), -2 * z * w]]))
        B.append(np.vstack([np.zeros(2), b]))
        C.append(np.column_stack([c, np.zeros(2)]))
    return control.ss(block_diag(*A), np.vstack(B), np.hstack(C), np.zeros((2, 2)))


def test_a_mode_ringing_above_the_band_of_a_record_from_rest_stays_a_mode():
    # the input has no power above 600 Hz; the 780 Hz mode is excited by the start of the
    # record and rings in it: its frequency and damping are determined, a mode (it was named
    # residual compliance, which drops both)
    rng = np.random.default_rng(3)
    sprung = (20.0, 0.05, [1.0, 1.0], [0.5, 0.5])  # a body on soft springs
    low = (140.0, 0.01, [1.0, -0.5], [0.8, 0.6])
    high = (780.0, 0.009, [0.7, 0.9], [-0.9, 0.6])
    truth, nominal = modal_ss([sprung, low, high]), modal_ss([sprung, low])
    n = 8192  # random noise with no power above 600 Hz (nor below 5 Hz), no period
    f = np.fft.rfftfreq(n, 1 / FS)
    U = rng.standard_normal((f.size, 2)) + 1j * rng.standard_normal((f.size, 2))
    U[(f < 5.0) | (f > 600.0)] = 0.0
    u = np.fft.irfft(U, n, axis=0)
    u /= np.std(u, axis=0)
    y = simulate_zoh(truth, u, FS)
    y += 2e-4 * np.std(y, axis=0) * rng.standard_normal(y.shape)
    data = TimeData(fs=FS, u=u, y=y, input_names=("F1", "F2"), output_names=("x1", "x2"))
    res = diagnose(nominal, data)
    assert res.top.effect == "missing_mode", [f.effect for f in res.findings]
    assert abs(res.top.parameters["freq_hz"] / 780.0 - 1) < 1e-3
    assert abs(res.top.parameters["damping"] / 0.009 - 1) < 0.1
    assert "above the excited band" in res.top.explanation


def test_the_band_of_low_passed_noise_ends_where_the_filter_does_not_at_nyquist():
    # 4th-order Butterworth (bilinear) noise without periods: its power is 1e-6 of the peak
    # where tan(pi f / fs) = 10^0.75 tan(pi fc / fs). The unwindowed periodogram leaked a
    # floor from the step between the record's ends (~1 / sin^2(pi f / fs)) over that
    # threshold up to Nyquist
    fs, fc, n = 6900.0, 2600.0, 16384
    b, a = scipy.signal.butter(4, fc / (fs / 2))
    r = scipy.signal.lfilter(b, a, np.random.default_rng(5).standard_normal((n, 2)), axis=0)
    data = TimeData(
        fs=fs, u=r, y=r, r=r, loop="closed", input_names=("F1", "F2"), output_names=("x1", "x2")
    )
    lo, hi = _time_band(data)
    edge = fs / np.pi * np.arctan(10**0.75 * np.tan(np.pi * fc / fs))  # 3290 Hz
    assert lo == fs / n
    assert 0.95 * edge < hi < 1.02 * edge < 0.5 * fs, (hi, edge)
