"""A mode above Nyquist on a sampled record: found in the band, reported with its image.

Oracle: an independent model built here (a rigid body and one mode, scipy's exact ZOH
discretization and ``dlsim``), the truth adding a mode at 1.5x Nyquist. Sampled, that
mode shows as a resonance at ``fs - f`` with the damping scaled by ``f / (fs - f)``; the
record cannot tell the two apart, so the finding must report both.
"""

from __future__ import annotations

import control
import numpy as np
import scipy.linalg
import scipy.signal

from workbench.diagnosis import diagnose
from workbench.io.formats import TimeData

FS = 2000.0  # Hz
MODEL_MODES = [  # (freq Hz, damping, b (2,), c (2,)): a rigid body and one mode
    (0.0, 0.0, np.array([1.0, 0.5]), np.array([1.0, 0.8])),
    (180.0, 0.02, np.array([0.6, -0.9]), np.array([0.7, -1.0])),
]


def _ss(modes) -> control.StateSpace:
    A, B, C = [], [], []
    for f, z, b, c in modes:
        w = 2 * np.pi * f
        A.append(np.array([[0.0, 1.0], [-w * w, -2 * z * w]]))
        B.append(np.vstack([0 * b, b]))
        C.append(np.column_stack([c, 0 * c]))
    return control.ss(scipy.linalg.block_diag(*A), np.vstack(B), np.hstack(C), np.zeros((2, 2)))


def _case(f_hz: float, z: float, seed: int = 0, n: int = 8192, noise: float = 1e-3):
    """(nominal, TimeData, noise floor error): the truth has one more mode at ``f_hz``."""
    rng = np.random.default_rng(seed)
    extra = (f_hz, z, np.array([2.4, 1.5]), np.array([-1.8, 2.7]))
    truth = _ss(MODEL_MODES + [extra])
    sysd = scipy.signal.cont2discrete((truth.A, truth.B, truth.C, truth.D), 1 / FS, "zoh")
    # high-passed noise: the rigid body's drift does not swamp the record
    hp = scipy.signal.butter(2, 100 / (FS / 2), "high")
    u = scipy.signal.lfilter(*hp, rng.standard_normal((n, 2)), axis=0)
    _, y, _ = scipy.signal.dlsim(sysd[:4] + (1 / FS,), u)
    v = noise * y.std(axis=0) * rng.standard_normal(y.shape)
    floor = float(np.linalg.norm(v) / np.linalg.norm(y + v))
    return _ss(MODEL_MODES), TimeData(fs=FS, u=u, y=y + v), floor


def test_a_mode_above_nyquist_is_reported_with_its_image():
    f_true, z_true = 1.5 * FS / 2, 0.02
    nominal, data, floor = _case(f_true, z_true)
    top = diagnose(nominal, data).findings[0]
    assert top.effect == "missing_mode"
    p = top.parameters
    # in the band: the image of the true mode
    assert abs(p["freq_hz"] / (FS - f_true) - 1) < 0.01, p["freq_hz"]
    assert abs(p["image_freq_hz"] / f_true - 1) < 0.005, p["image_freq_hz"]
    assert abs(p["image_damping"] / z_true - 1) < 0.05, p["image_damping"]
    assert top.error_after < 1.05 * floor and p["image_error_after"] < 1.05 * floor
    assert "above Nyquist" in top.explanation
