"""compare on a periodic record: the whole record against the noise floor its periods give.

The failing bands test the steady state's excited lines, the first period dropped. A misfit
between the lines or in the transient does not show there; the whole record's error over
the periods' noise floor does (``whole_record_ratio``, about 1 for a right model), and a
note says so where the bands pass.
"""

from __future__ import annotations

import numpy as np
import scipy.signal
from test_crosstalk_stack import PERIOD, _multisine
from test_sampled_image import FS, MODEL_MODES, _ss

from workbench.cli.commands.compare import format_text
from workbench.io.formats import TimeData
from workbench.validate.compare import WHOLE_RECORD_RATIO, compare

NOISE = 1e-3  # of each output's rms


def _record(ring: float, seed: int = 3):
    """A right model's record (scipy's ZOH, 6 periods from rest, sparse multisine) and, with
    ``ring`` > 0, a 640 Hz ring of ``ring`` x the noise on every output that has died out
    within the first period (a record cut while a mode the model lacks still rang)."""
    rng = np.random.default_rng(seed)
    u = _multisine(rng, np.arange(3, 450, 6), 6)
    sys = _ss(MODEL_MODES)
    sysd = scipy.signal.cont2discrete((sys.A, sys.B, sys.C, sys.D), 1 / FS, "zoh")
    _, y, _ = scipy.signal.dlsim(sysd[:4] + (1 / FS,), u)
    sd = NOISE * y.std(axis=0)
    t = np.arange(y.shape[0]) / FS
    w, z = 2 * np.pi * 640.0, 0.01  # settles within 0.1 s, a fifth of the first period
    y = y + ring * sd * np.exp(-z * w * t)[:, None] * np.sin(w * t)[:, None]
    y = y + sd * rng.standard_normal(y.shape)
    return sys, TimeData(fs=FS, u=u, y=y, period=PERIOD)


def test_a_right_model_is_at_the_whole_records_floor():
    model, data = _record(ring=0.0)
    res = compare(model, data)
    assert res.within_noise
    # the floor from the periods' spread is the noise's own error within a few %
    assert 0.97 <= res.whole_record_ratio <= 1.03
    assert not any("which the bands do not test" in n for n in res.notes)
    out = res.as_dict()
    assert out["error_noise_floor"] == res.error_noise_floor
    assert out["whole_record_ratio"] == res.whole_record_ratio


def test_a_transient_the_bands_do_not_test_is_named_with_its_ratio():
    model, data = _record(ring=40.0)
    res = compare(model, data)
    assert res.within_noise  # the steady state's lines: the ring has died out
    assert res.whole_record_ratio > WHOLE_RECORD_RATIO
    assert any("which the bands do not test" in n for n in res.notes)
    assert f"whole record: {res.whole_record_ratio:.4g}x the noise floor" in format_text(
        res, "m", "d"
    )


def test_a_record_without_periods_has_no_whole_record_floor():
    model, data = _record(ring=0.0)
    res = compare(model, TimeData(fs=data.fs, u=data.u, y=data.y))
    assert res.error_noise_floor is None and res.whole_record_ratio is None
    assert "whole record" not in format_text(res, "m", "d")
