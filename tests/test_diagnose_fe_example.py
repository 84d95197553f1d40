"""diagnose on the public FE-updating example: two causes in one modal mismatch (issue 13).

../shared/fe_examples/example_beam_update_frf was made by others' code (a finer mesh,
an exact modal sum): an aluminium beam on two wire flexures whose FE file has Young's
modulus 6 % too high and the flexures' stiffnesses -25 % and +10 %. The modes the file
gives are its own, reduced at the measured channels; the measured FRF is the truth's.
A wrong modulus scales every bending frequency by sqrt(E_true / E_file); the flexures
move the two suspension modes each its own way. The check is against the example's
answer.json, not the diagnosis code.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import SHARED, require_shared

from workbench.diagnosis import diagnose
from workbench.diagnosis.effects import SuspensionSprings, _shared_by_most, suspended_modes
from workbench.diagnosis.modal import decompose
from workbench.diagnosis.problem import FrfProblem
from workbench.fe.model import read_fe
from workbench.fe.reduce import reduce_fe
from workbench.io.formats import load_measurement

EXAMPLE = SHARED / "fe_examples" / "example_beam_update_frf"


@pytest.fixture(scope="module")
def fe_case():
    folder = require_shared(EXAMPLE)
    answer = json.loads((folder / "answer.json").read_text())
    data = load_measurement(folder / "measurement.npz")
    fe = read_fe(folder / "fe_model.npz")
    model = reduce_fe(fe, 12, outputs=data.output_names, inputs=data.input_names)
    return answer, data, diagnose(model.to_lti(), data)


def test_a_wrong_modulus_and_wrong_flexures_are_two_findings(fe_case):
    """Young's modulus: one factor on every bending mode; the flexures: the suspension's
    springs set anew (its modes move and turn), to the noise floor and within compare's."""
    answer, data, result = fe_case
    modulus, flexures = result.findings
    assert (modulus.effect, flexures.effect) == ("modal_mismatch", "suspension_stiffness")
    assert result.error_before > modulus.error_after > flexures.error_after
    assert flexures.error_after < 1.05 * result.noise_floor
    assert result.remaining["within_noise"]
    scale = np.sqrt(
        answer["alpha_true"]["youngs_modulus_pa"] / answer["alpha_nominal"]["youngs_modulus_pa"]
    )
    assert modulus.parameters["pattern"]["freq_scale"] == pytest.approx(scale, rel=2e-4)
    nominal = np.array(answer["nominal_modal_freq_hz"])
    moved = [m["model_freq_hz"] for m in modulus.parameters["modes"]]
    np.testing.assert_allclose(moved, nominal[2:], rtol=1e-6)  # the bending modes, not the two
    assert "every mode's frequency scaled by one factor, 0.9713" in modulus.explanation
    # the suspension modes from the model's to the truth's, damping too
    true_f = np.array(answer["true_modal_freq_hz"][:2])
    true_z = np.array(answer["true_modal_damping"][:2])
    springs = flexures.parameters["modes"]
    np.testing.assert_allclose([m["model_freq_hz"] for m in springs], nominal[:2], rtol=1e-6)
    np.testing.assert_allclose([m["freq_hz"] for m in springs], true_f, rtol=2e-3)
    np.testing.assert_allclose([m["damping"] for m in springs], true_z, rtol=0.1)
    assert "2.526 -> 2.807 Hz" in flexures.explanation


def test_without_the_springs_the_two_causes_are_still_two_findings(fe_case):
    """The mismatch alone (the springs not among the candidates): most modes at one factor,
    the suspension's each on its own, split into two findings from one joint fit."""
    answer, data, _ = fe_case
    folder = require_shared(EXAMPLE)
    model = reduce_fe(
        read_fe(folder / "fe_model.npz"), 12, outputs=data.output_names, inputs=data.input_names
    )
    result = diagnose(model.to_lti(), data, effects=("modal_mismatch",))
    modulus, others = result.findings
    assert modulus.effect == others.effect == "modal_mismatch"
    assert result.error_before > modulus.error_after > others.error_after
    nominal = np.array(answer["nominal_modal_freq_hz"])
    bending = nominal[(nominal > 10.0) & (nominal <= data.freq[-1])]
    np.testing.assert_allclose(modulus.parameters["pattern"]["of_modes_hz"], bending, rtol=1e-6)
    own = [m["model_freq_hz"] for m in others.parameters["modes"]]
    np.testing.assert_allclose(own, nominal[:2], rtol=1e-6)
    assert "move each on its own" in others.explanation
    assert others.model is result.model


def test_a_factor_most_modes_share():
    """Ten ratios at one factor and two apart: the ten; no majority, or every mode: none."""
    ten = 0.9713 * (1 + 1e-4 * np.linspace(-1, 1, 10))
    ratio = np.concatenate([[1.113, 0.994], ten])
    std = np.full(ratio.size, 1e-5)
    got = _shared_by_most(ratio, std)
    assert got["freq_scale"] == pytest.approx(0.9713, rel=1e-4)
    np.testing.assert_array_equal(got["share"], [False, False] + [True] * 10)
    assert _shared_by_most(np.array([1.1, 0.9, 1.0, 1.05]), np.full(4, 1e-5)) == {}
    assert _shared_by_most(ten, std[:10]) == {}  # all share: the full pattern's test
    assert _shared_by_most(np.array([0.97, 0.97, 1.2]), np.full(3, 1e-5)) == {}  # two: too few


def test_the_springs_jacobian_is_the_residuals_derivative():
    """SuspensionSprings' analytic Jacobian (the trust region's) against central differences
    of the model's residual, on the example's model at turned, moved springs."""
    folder = require_shared(EXAMPLE)
    data = load_measurement(folder / "measurement.npz")
    model = reduce_fe(
        read_fe(folder / "fe_model.npz"), 12, outputs=data.output_names, inputs=data.input_names
    )
    base = decompose(model.to_lti())
    problem = FrfProblem(data)
    springs = SuspensionSprings()
    f0 = np.array([base.modes[k].freq_hz for k in suspended_modes(base)])
    theta = np.concatenate([np.log(f0 * [1.1, 0.95]), np.log([0.03, 0.02]), [0.2, -0.4]])
    J = springs.jacobian(theta, problem, base)

    def residual(t):
        return problem.residual(springs.build(t, problem, base).model)

    cols = []
    for i in range(theta.size):
        up, down = theta.copy(), theta.copy()
        up[i] += 1e-6
        down[i] -= 1e-6
        cols.append((residual(up) - residual(down)) / 2e-6)
    J_fd = np.column_stack(cols)
    scale = np.abs(J_fd).max(axis=0)
    assert J.shape == J_fd.shape and np.all(scale > 0)
    np.testing.assert_array_less(np.abs(J - J_fd).max(axis=0), 1e-5 * scale)
