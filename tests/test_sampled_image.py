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


def _case(extra, seed: int = 0, n: int = 8192, noise: float = 1e-3, D=None, T_out=None):
    """(nominal, TimeData, noise floor error): the truth has the modes ``extra`` (f Hz, z, b,
    c) added to the model's, the feedthrough ``D`` (2, 2) where given (``D u[k]``), and its
    outputs mixed by ``T_out`` (2, 2) where given (crosstalk)."""
    rng = np.random.default_rng(seed)
    truth = _ss(MODEL_MODES + list(extra))
    D = truth.D if D is None else D
    sysd = scipy.signal.cont2discrete((truth.A, truth.B, truth.C, D), 1 / FS, "zoh")
    # high-passed noise: the rigid body's drift does not swamp the record
    hp = scipy.signal.butter(2, 100 / (FS / 2), "high")
    u = scipy.signal.lfilter(*hp, rng.standard_normal((n, 2)), axis=0)
    _, y, _ = scipy.signal.dlsim(sysd[:4] + (1 / FS,), u)
    if T_out is not None:
        y = y @ T_out.T
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


IN_BAND = (250.0, 0.01, np.array([2.4, 1.4]), np.array([1.8, -2.2]))  # a mode the model lacks


@pytest.mark.parametrize("folded", [1, 2])
def test_a_missing_mode_beside_a_compliance_is_not_a_pseudo_mode_above_nyquist(folded):
    # the compliance's pseudo-mode took the resonance at 250 Hz as its image (1750 Hz,
    # damped 0.0014) and the error stayed at 2.7x the floor; with two folded modes the
    # mode named in its place left the far mode out (2.2x): the resonance is named in the
    # band, the compliance added on top holds the far mode and the folded ones
    extra = [FAR] + FOLDED[:folded] + [IN_BAND]
    nominal, data, floor = _case(extra, seed=2)
    result = diagnose(nominal, data)
    effects = [f.effect for f in result.findings]
    assert effects == ["missing_mode", "residual_compliance"], effects
    mm, rc = result.findings
    assert abs(mm.parameters["freq_hz"] / IN_BAND[0] - 1) < 0.002
    assert abs(mm.parameters["damping"] / IN_BAND[1] - 1) < 0.05
    M, M_true = np.asarray(rc.parameters["matrix"]), _static(extra[:-1])
    assert np.linalg.norm(M - M_true) / np.linalg.norm(M_true) < 0.05, (M, M_true)
    assert len(rc.parameters["modes_above_nyquist"]) == folded
    assert rc.error_after < 1.1 * floor < mm.error_after < result.error_before
    assert any("a compliance of its own is added" in n for n in result.notes)


def test_folded_modes_move_next_to_the_compliance_with_the_errors_of_the_new_order():
    # the search's order: compliance, a missing mode, then a folded mode; the folded mode
    # is moved up, each finding's error re-read from the final model without the modes
    # found after it (a stand-in problem: the error counts the modes still missing)
    from dataclasses import replace

    from workbench.diagnosis.diagnose import Finding, _folded_first
    from workbench.modal.model import ModalModel, Mode

    def mode(f):
        return Mode("flexible", f, 0.01, np.ones(2), np.ones(2), effect="missing_mode")

    kept, folded = mode(350.0), mode(500.0)
    model = ModalModel(modes=(kept, folded), D=np.zeros((2, 2)))

    class Problem:
        def error(self, m):  # 4 with neither mode, 2 with the folded one alone
            return 1.0 + _lacks(m, kept) * 1.0 + _lacks(m, folded) * 2.0

    def finding(effect, f, before, after):
        return Finding(
            effect=effect,
            inputs=(0, 1),
            outputs=(0, 1),
            band_hz=(1.0, 600.0),
            parameters={"freq_hz": f} if f else {"matrix": [[0.0, 0.0], [0.0, 0.0]]},
            parameters_std={},
            error_after=after,
            explanation=f"a reason; the error falls from {before:.4g} to {after:.4g}.",
        )

    found = [
        finding("residual_compliance", None, 5.0, 4.0),
        finding("missing_mode", 350.0, 4.0, 2.0),
        finding("missing_mode", 500.0, 2.0, 1.0),
    ]

    def _lacks(m, x) -> bool:
        return all(y is not x for y in m.modes)

    out, flags = _folded_first(found, [False, False, True], model, Problem())
    assert [f.parameters.get("freq_hz") for f in out] == [None, 500.0, 350.0]
    assert flags == [False, True, False]
    assert [f.error_after for f in out] == [4.0, 2.0, 1.0]
    assert "the error falls from 4 to 2." in out[1].explanation
    assert "the error falls from 2 to 1." in out[2].explanation
    assert len(out[1].model.modes) == 1 and out[1].model.modes[0] is folded

    # where the new order's errors do not fall (the folded mode alone explains nothing),
    # the findings stay as they are
    class Flat(Problem):
        def error(self, m):
            return 1.0 + _lacks(m, kept) * 2.0

    assert _folded_first(found, [False, False, True], model, Flat()) == (
        found,
        [False, False, True],
    )
    # only missing modes after the compliance are moved
    other = [found[0], replace(found[1], effect="time_delay"), found[2]]
    assert _folded_first(other, [False, False, True], model, Problem())[0] is other


def test_a_mode_above_the_band_named_by_its_static_part_reads_it_from_the_final_model():
    # the finding is made when the mode is found; later rounds refit it (backfit, polish):
    # its static part N0 / w^2 is read back from the model the diagnosis ends with
    from workbench.diagnosis.diagnose import Finding, _refresh_added
    from workbench.modal.model import ModalModel, Mode

    b, c = np.array([2.0, -1.0]), np.array([0.5, 3.0])
    moved = Mode("flexible", 1416.8, 0.036, b, c, effect="missing_mode")
    model = ModalModel(modes=(moved,), D=np.zeros((2, 2)))
    stale = Finding(
        effect="residual_compliance",
        inputs=(0, 1),
        outputs=(0, 1),
        band_hz=(1.0, 1090.0),
        parameters={"matrix": [[1.0, 0.0], [0.0, 1.0]], "freq_hz_fitted": 1388.5},
        parameters_std={},
        error_after=1.0,
        explanation="",
    )
    (fresh,) = _refresh_added([stale], model, ModalModel(modes=(), D=np.zeros((2, 2))))
    w = 2 * np.pi * 1416.8
    assert np.allclose(fresh.parameters["matrix"], np.outer(c, b) / w**2, rtol=1e-12)
    assert fresh.parameters["freq_hz_fitted"] == 1416.8
    assert fresh.parameters["damping_fitted"] == 0.036


def test_a_missing_mode_on_an_end_of_its_frequency_range_is_no_candidate():
    # the fit went as far as it was let: the data do not place that resonance
    from types import SimpleNamespace

    from workbench.diagnosis.diagnose import _on_frequency_bound
    from workbench.diagnosis.effects import MissingMode, UpperResidual

    problem = SimpleNamespace(band_hz=(10.0, 1000.0))
    lo, hi = MissingMode().bounds(problem, None)

    def fitted(structure, log_f):
        return SimpleNamespace(structure=structure, theta=np.array([log_f, np.log(0.5)]))

    assert _on_frequency_bound(fitted(MissingMode(), hi[0]), problem, None)
    # a lightly damped one there lies above the band: its static part, a compliance
    light = SimpleNamespace(structure=MissingMode(), theta=np.array([hi[0], np.log(0.05)]))
    assert not _on_frequency_bound(light, problem, None)
    assert _on_frequency_bound(fitted(MissingMode(), lo[0] + 1e-6), problem, None)
    assert not _on_frequency_bound(fitted(MissingMode(), np.log(900.0)), problem, None)
    assert not _on_frequency_bound(fitted(UpperResidual(), hi[0]), problem, None)


#: a mode at 2 fs + 300 Hz: it rings at 300 Hz damped 0.43 (0.22 as the search fits it),
#: and its image at fs - f is damped 0.044, more than 2x the model's mode (0.02)
TWICE_FOLDED = (2 * FS + 300.0, 0.03, np.array([1.0, -2.0]), np.array([1.5, 1.2]))


def test_a_mode_folded_from_beyond_the_sampling_frequency_is_the_compliances_too():
    # the pseudo-mode takes the 1500 Hz mode; the resonance near 300 Hz has no structural
    # image at fs - f, one at fs + f: its static part belongs in the compliance (2.3 % off
    # without it, beside a missing mode), the image's damping the resonance's decay rate
    # (fitted, the image took 0.042 to tie the resonance's error)
    extra = [FAR, FOLDED[0], TWICE_FOLDED]
    nominal, data, floor = _case(extra, seed=1)
    rc = _one_compliance(extra, floor, diagnose(nominal, data))
    (image,) = rc.parameters["modes_above_nyquist"]
    assert image["freq_hz"] > FS  # not at fs - f
    assert abs(image["freq_hz"] - round(image["freq_hz"] / FS) * FS) == pytest.approx(
        image["band_freq_hz"], rel=0.01
    )
    assert image["damping"] <= 2 * MODEL_MODES[1][1]
    assert image["damping"] == pytest.approx(
        image["band_damping"] * image["band_freq_hz"] / image["freq_hz"]
    )


def _base(*dampings):
    from types import SimpleNamespace

    return SimpleNamespace(
        modes=[
            SimpleNamespace(kind="flexible", freq_hz=100.0 * (k + 1), damping=z)
            for k, z in enumerate(dampings)
        ]
    )


def test_the_image_taken_is_the_lowest_that_a_structural_mode_would_be():
    from types import SimpleNamespace

    from workbench.diagnosis.diagnose import _image

    fs, reach = 7700.0, 38_500.0
    # an indep3 planar record: a resonance at 1293.4 Hz damped 0.342, the model's modes
    # damped up to 0.0233: fs -+ f are damped 0.069 and 0.049, 2 fs - f 0.031
    far = SimpleNamespace(freq_hz=1293.4, damping=0.342)
    fold, side, f_img, z_img = _image(far, fs, reach, _base(0.0074, 0.0233))
    assert (fold, side) == (2, -1)
    assert f_img == pytest.approx(2 * fs - 1293.4)
    assert z_img == pytest.approx(0.342 * 1293.4 / f_img)
    # structural at fs - f already: that one, as before
    light = SimpleNamespace(freq_hz=1293.4, damping=0.05)
    assert _image(light, fs, reach, _base(0.0233))[:2] == (1, -1)
    # none within reach: fs - f, for the image test to refuse
    assert _image(far, fs, 10_000.0, _base(0.0233))[:3] == (1, -1, fs - 1293.4)


def test_an_aliased_modes_frequency_stays_in_its_half_of_the_fs_interval():
    from types import SimpleNamespace

    from workbench.diagnosis.effects import AliasedMode

    problem = SimpleNamespace(data=SimpleNamespace(fs=FS))
    for fold, side, (lo, hi) in [(1, -1, (0.5, 1.0)), (1, 1, (1.0, 1.5)), (3, -1, (2.5, 3.0))]:
        bounds = AliasedMode(fold=fold, side=side).bounds(problem, None)
        assert np.exp([bounds[0][0], bounds[1][0]]) == pytest.approx([lo * FS, hi * FS])
