"""The noise floor a record without periods gives: the low quantile of a residual's spectrum.

Built from a mass-spring-damper's exact ZOH response with white sensor noise of known
level, so the floor ``||v|| / ||y||`` is known exactly; a lightly damped resonance the
"model" lacks is a narrowband misfit, a static gain error on the white input a broadband
one. The rule that uses the floor (a finding is large when it removes COST_RATIO of the
misfit above it) is checked on the same records with predictions given directly.
"""

from __future__ import annotations

import sys
from types import SimpleNamespace

import control
import numpy as np
import pytest

from workbench.diagnosis import detect
from workbench.io.formats import TimeData
from workbench.sim import simulate_zoh

FS = 2000.0
N = 10_000

#: 1 kg on 4e4 N/m (31.8 Hz), 2 % damping: the part of the output the model has right
PLANT = control.ss([[0.0, 1.0], [-4e4, -2 * 0.02 * 200.0]], [[0.0], [1.0]], [[1.0, 0.0]], 0.0)
#: a 300 Hz resonance, damping 0.01: what the model lacks, in a few bins of the spectrum
EXTRA = control.ss(
    [[0.0, 1.0], [-((2 * np.pi * 300) ** 2), -2 * 0.01 * 2 * np.pi * 300]],
    [[0.0], [1.0]],
    [[1.0, 0.0]],
    0.0,
)


def _parts(seed: int = 3):
    """(signal, narrowband misfit, white noise), each (N, 1), the misfit and noise at unit rms."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((N, 1))
    s = simulate_zoh(PLANT, u, FS)
    m = simulate_zoh(EXTRA, u, FS)
    v = rng.standard_normal((N, 1))
    rms = lambda x: np.sqrt(np.mean(x**2))  # noqa: E731
    return u, s, m / rms(m), v


def _data(y) -> TimeData:
    return TimeData(fs=FS, u=np.zeros_like(y), y=y)


@pytest.mark.parametrize("misfit_over_noise", [0.0, 1.0, 3.0])
def test_white_noise_is_read_under_a_narrowband_misfit(misfit_over_noise):
    _, s, m, v = _parts()
    sigma = 1e-3 * np.sqrt(np.mean(s**2))
    y = s + sigma * (v + misfit_over_noise * m)
    floor = np.linalg.norm(sigma * v) / np.linalg.norm(y)
    est = detect.residual_floor(_data(y), y - s)
    # the misfit carries up to 10x the noise's power, in the resonance's few bins
    assert est == pytest.approx(floor, rel=0.05)
    # the residual's own level is the misfit's and the noise's together
    err = np.linalg.norm(y - s) / np.linalg.norm(y)
    assert err == pytest.approx(floor * np.sqrt(1 + misfit_over_noise**2), rel=0.05)


def test_a_broadband_misfit_reads_as_noise():
    # a static gain error on a white input is white itself: the estimate is the noise or more
    u, s, _, v = _parts()
    sigma = 1e-3 * np.sqrt(np.mean(s**2))
    gain = 3 * sigma / np.sqrt(np.mean(u**2))
    y = s + sigma * v + gain * u
    floor = np.linalg.norm(sigma * v) / np.linalg.norm(y)
    assert detect.residual_floor(_data(y), y - s) > 2.5 * floor


def test_too_short_a_record_gives_no_floor():
    y = np.random.default_rng(0).standard_normal((500, 1))
    assert detect.residual_floor(_data(y), y) is None


def _large_above_white():
    return sys.modules["workbench.diagnosis.diagnose"]._large_above_white


class _Predicts:
    """A problem whose models are their own predictions."""

    def predict(self, model):
        return model


def _judged(misfit_over_noise: float, removed: float) -> tuple[bool, float]:
    """(large, error ratio) for a candidate that removes ``removed`` of the misfit's amplitude."""
    _, s, m, v = _parts()
    sigma = 1e-3 * np.sqrt(np.mean(s**2))
    y = s + sigma * (v + misfit_over_noise * m)
    after = s + removed * sigma * misfit_over_noise * m
    err = lambda p: float(np.linalg.norm(y - p) / np.linalg.norm(y))  # noqa: E731
    last = SimpleNamespace(model=after, error=err(after))
    large = _large_above_white()(_data(y), _Predicts(), s, last, err(s))
    return large, err(after) / err(s)


def test_a_finding_that_removes_a_third_of_the_misfit_above_the_noise_is_large():
    # F = 1 + 0.8^2 = 1.64; removing 30 % of the misfit's amplitude leaves 49 % of its power:
    # F - 1 falls to 0.31, below 0.7 x 0.64, while the error falls only to 0.90x (no more
    # than ERROR_RATIO's 15 %: near the floor, the noise holds the error up)
    large, ratio = _judged(0.8, 0.3)
    assert large
    assert ratio > 0.85


def test_a_finding_that_removes_little_of_it_is_not():
    large, _ = _judged(0.8, 0.08)  # 85 % of the misfit's power left
    assert not large


def test_near_the_floor_nothing_is_shared_out():
    # F = 1 + 0.4^2 = 1.16 < PERIODIC_F: even the whole misfit removed is not large
    large, _ = _judged(0.4, 1.0)
    assert not large
