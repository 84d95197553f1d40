"""Coulomb friction at the beam's voice coils, in an open-loop time record (issue 13, item 4).

The beam is 3 inputs x 5 outputs: no output measures the port of every input, so a
port element can only be placed with the mode shapes that sensor s1, collocated with
coil F1, fixes at every coil (the extended modal model, methods.md section 4). The
friction damps the suspension modes the coils move, which a linear search takes for a
modal mismatch (their damping up from 0.02 to 0.07 at 3.2 Hz on the clear case): the
friction element on the model as given must win over that, with its level. A linear
beam record must raise no nonlinearity finding.

Oracle: tests/casegen.py builds the true plant with the friction of its make_case
(2e-3 x level N at every coil, v0 = 1e-5 m/s; level 0.2 clear, 0.05 subtle); the
tolerance on the level is the issue's 20 % (as tests/test_nonlinear.py).
"""

from __future__ import annotations

import numpy as np
import pytest

import casegen
from workbench.diagnosis import diagnose

#: casegen.make_case's beam friction, N, per size
BEAM_FRICTION_N = {"clear": 2e-3 * 0.2, "subtle": 2e-3 * 0.05}
#: the issue's tolerance on the friction level
FRICTION_TOL = 0.2


def _true_noise_floor(case) -> float:
    """Error of the noise-free true plant (friction included) against the record."""
    import plants
    from workbench.core.lti import relative_error_time

    truth = plants.get_plant(
        "beam", delay_s=0.0, friction_force=BEAM_FRICTION_N[case.size], friction_velocity=1e-5
    )
    return relative_error_time(case.data.y, truth.simulate_noise_free(case.data.u))


def _converged_truth_error(case) -> float:
    """Error of the true plant simulated converged (64 substeps, beyond its automatic 35)
    against the record: the best a simulation model of the continuous plant can reach, the
    record's noise (casegen integrates its friction with its own converged scheme; before,
    its 8 explicit substeps left the record 3-4x its noise from the converged response)."""
    import plants
    from workbench.core.lti import relative_error_time

    truth = plants.get_plant(
        "beam",
        delay_s=0.0,
        friction_force=BEAM_FRICTION_N[case.size],
        friction_velocity=1e-5,
        substeps=64,
    )
    return relative_error_time(case.data.y, truth.simulate_noise_free(case.data.u))


def _check_friction_finding(case, result, *, floor_factor=None):
    effects = [f.effect for f in result.findings]
    assert effects and effects[0] == "nonlinearity", effects
    f = result.findings[0]
    p = f.parameters
    assert p["element"] == "coulomb_friction", p.get("element_errors")
    assert p["ports"] == [0, 1, 2], p["ports"]  # friction at every coil
    assert p["collocated"] == [0, 0]  # s1 at F1
    force = np.asarray(p["friction_force"])
    truth = BEAM_FRICTION_N[case.size]
    assert np.all(np.abs(force - truth) <= FRICTION_TOL * truth), (force, truth)
    # casegen's criterion (its floor is the true *linear* model's error: the friction's share)
    assert f.error_after <= 2.0 * case.noise_floor
    # the nonlinear simulation model explains the record: > 99 % of the misfit of the
    # model as given, and the linear model it replaced is not kept beside it
    assert f.error_after < 0.01 * result.error_before, (f.error_after, result.error_before)
    if floor_factor is not None:
        floor = _true_noise_floor(case)
        assert f.error_after <= floor_factor * floor, (f.error_after, floor)


def test_clear_friction_on_the_beam_is_named_with_its_element_and_level():
    # seed 2: before the fix, modal_mismatch (suspension mode damping 0.02 -> 0.057, error
    # 0.048) and no nonlinearity (~20 s)
    case = casegen.make_case("beam", "time", (("nonlinearity", "clear"),), seed=2)
    result = diagnose(case.model, case.data)
    _check_friction_finding(case, result)


def test_clean_beam_record_raises_no_nonlinearity():
    case = casegen.make_case("beam", "time", (("none", "-"),), seed=2)
    result = diagnose(case.model, case.data)
    assert [f.effect for f in result.findings] == ["none"]


def test_element_does_not_replace_a_true_modal_mismatch():
    """The element test the search runs on accepting a modal mismatch, on a linear record.

    The true linear model (a flexible mode 3 % off) stands for the search's modal
    mismatch: the friction element on the model as given must not explain the record
    better (the full diagnosis of this record is in the slow study below).
    """
    import plants
    from workbench.core.blas import limited_blas
    from workbench.diagnosis.detect import NonlinearityEvidence
    from workbench.diagnosis.diagnose import _nonlinearity_finding, base_model
    from workbench.diagnosis.modal import decompose
    from workbench.diagnosis.problem import make_problem

    case = casegen.make_case("beam", "time", (("modal_mismatch", "clear"),), seed=2)
    truth = plants.get_plant("beam", delay_s=0.0, **casegen.BEAM_EFFECTS["modal_mismatch"]["clear"])
    base = base_model(case.model, case.data)
    found = decompose(truth.linear_model())
    problem = make_problem(case.data)
    err = problem.error(found)
    ev = NonlinearityEvidence(level=err**2, f_stat=0.0, n_lines=0, band_hz=problem.band_hz)
    with limited_blas(1):  # as diagnose runs it: small matrices, BLAS threads only cost
        finding, alt = _nonlinearity_finding(
            ev, case.data, problem.error(base), [found, base], err, direct=False
        )
    assert finding is None, finding.parameters
    # an element was fitted (on ports located by a collocated pair, or a spring on a mode's
    # coordinate) and did not lower the error of the linear finding by the factor a finding
    # must; the ports' elements may be left unfitted, their first-order signature not
    # lowering the error enough to be worth the fit (diagnose's screen)
    p = alt["parameters"]
    assert any(k in p for k in ("collocated", "mode", "screened")), p
    assert alt["error_after"] >= 0.85 * err


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("size", ["clear", "subtle"])
def test_beam_friction_study(size, seed):
    case = casegen.make_case("beam", "time", (("nonlinearity", size),), seed=seed)
    result = diagnose(case.model, case.data)
    # at the record's noise floor: casegen's record is converged and the element's v0 is
    # fitted with its levels (its estimate, 1e-3 of the rms port velocity, 3.4x too small
    # here, left 1.35-1.94x the floor on the clear cases; before the converged truth, the
    # record's own scheme left 3.0-4.2x)
    _check_friction_finding(case, result, floor_factor=1.25)
    # as close to the record as the true plant simulated converged (the levels and v0 are
    # fitted, so it may come below)
    assert result.findings[0].error_after <= 1.25 * _converged_truth_error(case)


#: every linear beam time case of the suite
LINEAR_BEAM_TIME = [
    (effect, size)
    for effect, sizes in casegen.BEAM_EFFECTS.items()
    for size in sizes
    if ("beam", effect) not in casegen.TIME_INVISIBLE
]


@pytest.mark.slow
@pytest.mark.parametrize(
    "effect,size", LINEAR_BEAM_TIME, ids=["_".join(c) for c in LINEAR_BEAM_TIME]
)
def test_linear_beam_time_records_raise_no_nonlinearity(effect, size):
    case = casegen.make_case("beam", "time", ((effect, size),), seed=1)
    result = diagnose(case.model, case.data)
    named = [f.effect for f in result.findings]
    assert "nonlinearity" not in named, named
