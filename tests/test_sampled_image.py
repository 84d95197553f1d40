"""A mode above Nyquist on a sampled record: found in the band, reported with its image.

Oracle: an independent model built here (a rigid body and one mode, scipy's exact ZOH
discretization and ``dlsim``), the truth adding a mode at 1.5x Nyquist. Sampled, that
mode shows as a resonance at ``fs - f`` with the damping scaled by ``f / (fs - f)``; the
record cannot tell the two apart, so the finding must report both.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
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


def _case(extra, seed: int = 0, n: int = 8192, noise: float = 1e-3, D=None):
    """(nominal, TimeData, noise floor error): the truth has the modes ``extra`` (f Hz, z, b,
    c) added to the model's, and the feedthrough ``D`` (2, 2) where given (``D u[k]``)."""
    rng = np.random.default_rng(seed)
    truth = _ss(MODEL_MODES + list(extra))
    D = truth.D if D is None else D
    sysd = scipy.signal.cont2discrete((truth.A, truth.B, truth.C, D), 1 / FS, "zoh")
    # high-passed noise: the rigid body's drift does not swamp the record
    hp = scipy.signal.butter(2, 100 / (FS / 2), "high")
    u = scipy.signal.lfilter(*hp, rng.standard_normal((n, 2)), axis=0)
    _, y, _ = scipy.signal.dlsim(sysd[:4] + (1 / FS,), u)
    v = noise * y.std(axis=0) * rng.standard_normal(y.shape)
    floor = float(np.linalg.norm(v) / np.linalg.norm(y + v))
    return _ss(MODEL_MODES), TimeData(fs=FS, u=u, y=y + v), floor


def test_a_mode_above_nyquist_is_reported_with_its_image():
    f_true, z_true = 1.5 * FS / 2, 0.02
    nominal, data, floor = _case([(f_true, z_true, np.array([2.4, 1.5]), np.array([-1.8, 2.7]))])
    top = diagnose(nominal, data).findings[0]
    assert top.effect == "missing_mode"
    p = top.parameters
    # in the band: the image of the true mode
    assert abs(p["freq_hz"] / (FS - f_true) - 1) < 0.01, p["freq_hz"]
    assert abs(p["image_freq_hz"] / f_true - 1) < 0.005, p["image_freq_hz"]
    assert abs(p["image_damping"] / z_true - 1) < 0.05, p["image_damping"]
    assert top.error_after < 1.05 * floor and p["image_error_after"] < 1.05 * floor
    assert "above Nyquist" in top.explanation


def _static(modes) -> np.ndarray:
    """Static compliance (2, 2) of flexible modes: sum of c b^T / w^2."""
    return sum(np.outer(c, b) / (2 * np.pi * f) ** 2 for f, _, b, c in modes)


FAR = (7300.0, 0.2, np.array([9.0, -6.0]), np.array([8.0, 5.0]))  # settles within a sample
FOLDED = [  # ring in the band: at 500 Hz damped 0.06, at 600 Hz damped 0.043
    (1500.0, 0.02, np.array([2.4, 1.5]), np.array([-1.8, 2.7])),
    (2600.0, 0.01, np.array([1.0, -2.0]), np.array([1.5, 1.2])),
]


def _one_compliance(extra, floor, result) -> dict:
    """The single residual compliance finding's parameters, checked against the truth."""
    assert [f.effect for f in result.findings] == ["residual_compliance"], result.findings
    rc = result.findings[0]
    M, M_true = np.asarray(rc.parameters["matrix"]), _static(extra)
    assert np.linalg.norm(M - M_true) / np.linalg.norm(M_true) < 0.02, (M, M_true)
    assert rc.error_after < 1.1 * floor
    return rc


def test_a_compliance_sampled_one_sample_late_is_no_time_delay():
    # the far mode's static part answers u[k-1] on the record, a feedthrough D u[k]: a
    # sub-sample "delay" moved D by one sample and was named beside the compliance
    extra = [FAR, FOLDED[0]]
    nominal, data, floor = _case(extra, seed=1)
    result = diagnose(nominal, data)
    rc = _one_compliance(extra, floor, result)
    assert abs(rc.parameters["upper_freq_hz"] / 1500.0 - 1) < 0.01
    assert any(m.effect == "late_compliance" for m in result.model.modes)
    assert result.model.delay_s == 0.0
    assert "one sample late" in rc.explanation


def test_truncated_modes_that_fold_into_the_band_are_one_residual_compliance():
    # the pseudo-mode takes one folded mode; the other is found as a resonance at 500 Hz
    # damped 0.06 (3x the model's mode), whose image at 1500 Hz is damped 0.02: a truncated
    # mode, its static part in the one compliance finding
    extra = [FAR] + FOLDED
    nominal, data, floor = _case(extra, seed=1)
    rc = _one_compliance(extra, floor, diagnose(nominal, data))
    (image,) = rc.parameters["modes_above_nyquist"]
    assert abs(image["band_freq_hz"] / 500.0 - 1) < 0.01
    assert abs(image["freq_hz"] / 1500.0 - 1) < 0.01
    assert "truncated mode above Nyquist" in rc.explanation
    assert f"the error falls to {rc.error_after:.4g}." in rc.explanation


def test_folded_modes_without_a_compliance_stay_missing_modes():
    # nothing shows a compliance: each resonance is reported in the band, with its image
    nominal, data, _ = _case(FOLDED, seed=1)
    found = diagnose(nominal, data).findings
    assert sorted(f.effect for f in found) == ["missing_mode", "missing_mode"]
    images = sorted(f.parameters["image_freq_hz"] for f in found)
    assert np.allclose(images, [1400.0, 1500.0], rtol=0.01), images


def test_a_feedthrough_of_the_sample_itself_stays_a_feedthrough():
    # the record's D u[k] (the simulation convention of a model with D): the compliance
    # is the model's D, not the late mode
    M = np.array([[2e-6, -1e-6], [0.5e-6, 3e-6]])
    nominal, data, floor = _case([], seed=3, D=M)
    result = diagnose(nominal, data)
    (rc,) = result.findings
    assert rc.effect == "residual_compliance" and rc.error_after < 1.05 * floor
    assert np.allclose(rc.parameters["matrix"], M, rtol=0.01, atol=1e-8)
    assert np.allclose(result.model.D, M, rtol=0.01)
    assert not any(m.effect == "late_compliance" for m in result.model.modes)


def test_a_joint_fit_of_added_terms_is_backfitted_before_it_is_compared():
    # the joint fit solves the mode's residue and the compliance's matrices one after the
    # other (the mode first, on what the compliance would explain): 2.6x the floor where
    # solving them together (backfit) reaches it; one added term is left as it is
    from workbench.diagnosis.diagnose import _backfitted, base_model
    from workbench.diagnosis.effects import MissingMode, UpperResidual
    from workbench.diagnosis.fit import fit_joint
    from workbench.diagnosis.problem import make_problem

    nominal, data, floor = _case([FAR] + FOLDED, seed=1)
    base, problem = base_model(nominal, data), make_problem(data)
    starts = [np.log([1400.0, 0.019]), np.log([500.0, 0.06])]
    fits, _ = fit_joint([UpperResidual(late=True), MissingMode()], starts, problem, base)
    assert fits[-1].error > 2 * floor
    done = _backfitted(fits, problem, base)
    assert done[-1].error < 1.1 * floor
    assert done[-1].cost == pytest.approx(problem.cost(done[-1].model))
    assert done[:-1] == fits[:-1]
    one, _ = fit_joint([UpperResidual(late=True)], starts[:1], problem, base)
    assert _backfitted(one, problem, base) is one
