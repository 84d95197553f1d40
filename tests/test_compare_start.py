"""compare on time records: from rest and from the estimated initial state (issue 13).

The oracle: the TRUE linear model of the simulated wafer stage (plants/,
``linear_model()`` with its delay) on its own closed-loop record. Cut so that
it starts mid-motion, the simulation from rest drifts (rigid-body modes: the
unknown initial position and velocity grow as a + b t), yet the model is right:
with the initial state estimated by least squares the error must fall to the
error of the same model on the record that does start at rest (the noise), and
no band may fail.
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench.cli.main import main
from workbench.core.model import LTIModel
from workbench.io.formats import TimeData, load_measurement, save_measurement
from workbench.validate.compare import compare

PERIOD = 2000  # samples: the simulate command's default multisine period


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    from plants import get_plant

    d = tmp_path_factory.mktemp("stage")
    assert main(["simulate", "wafer_stage", "--out", str(d / "rec.npz"), "--seed", "3"]) == 0
    plant = get_plant("wafer_stage")
    true = LTIModel.from_statespace(plant.linear_model(), delay_s=plant.delay_s)
    true.write(d / "true.npz")
    data = load_measurement(d / "rec.npz")
    assert data.loop == "closed" and data.r is not None and data.period == PERIOD
    k = PERIOD + 777  # mid-motion: not at rest, not at a period boundary
    n = 3 * PERIOD
    cut = TimeData(
        fs=data.fs,
        u=data.u[k : k + n],
        y=data.y[k : k + n],
        r=data.r[k : k + n],
        loop="closed",
        period=PERIOD,
        input_names=data.input_names,
        output_names=data.output_names,
    )
    save_measurement(d / "cut.npz", cut)
    return d, true, data, cut


def test_true_model_mid_motion_record_has_no_failing_band(stage):
    _, true, data, cut = stage
    at_rest = compare(true, data)
    res = compare(true, cut)
    # the from-rest simulation drifts: the spec measure is far above the noise ...
    assert res.error > 100 * at_rest.error
    # ... the estimated start is at the noise level of the record that starts at rest
    assert res.error_estimated_start < 1.5 * at_rest.error
    assert res.time.residual_from == "estimated start"
    assert res.failing_bands == ()
    # z ~ F(2, 2(M-1)) with M = 2 kept periods of 3 (the first dropped): mean 2 for a
    # right model; the from-rest drift gave z ~ 1e8
    assert res.z_mean < 4.0


def test_wrong_model_still_fails_with_estimated_start(stage):
    """The estimated start removes a transient, not a model error: a 20 % gain error fails."""
    _, true, _, cut = stage
    wrong = true.replace(B=1.2 * np.asarray(true.B))
    res = compare(wrong, cut)
    assert res.failing_bands
    assert res.error_estimated_start > 0.1


def test_cli_says_which_error_is_which(stage, capsys):
    d, *_ = stage
    rc = main(
        [
            "compare",
            "--model",
            str(d / "true.npz"),
            "--data",
            str(d / "cut.npz"),
            "--json",
            str(d / "c.json"),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0
    assert "error (spec measure):" in out and "(simulation from rest)" in out
    assert "error with estimated start:" in out and "(initial state by least squares)" in out
    assert "failing bands: none" in out
    import json

    js = json.loads((d / "c.json").read_text())
    assert js["error_from_rest"] == js["error"]
    assert js["error_estimated_start"] < js["error_from_rest"]
    assert js["residual_from"] == "estimated start"


def test_the_estimated_start_minimizes_the_error_it_reports():
    """compare's start is the least squares of the relative error it reports (all outputs
    unweighted): checked against numpy's lstsq on the free responses, on two outputs 1000x
    apart in scale whose model is wrong (a residual that weighting per output would tilt)."""
    import control

    from workbench.core.lti import relative_error_time

    rng = np.random.default_rng(5)
    A = np.array([[0.95, 0.2, 0.0], [-0.2, 0.95, 0.0], [0.0, 0.0, 0.7]])
    B = np.array([[1.0], [0.0], [0.5]])
    C = np.array([[1.0, 0.0, 1.0], [0.0, 1e-3, 2e-3]])
    true = control.ss(A, B, C, np.zeros((2, 1)), 1.0)
    wrong = control.ss(A, 0.8 * B, C, np.zeros((2, 1)), 1.0)  # a gain error
    u = rng.standard_normal((400, 1))
    x0 = np.array([3.0, -2.0, 1.0])
    t = np.arange(400.0)
    y = control.forced_response(true, T=t, U=u.T, X0=x0).outputs.T
    data = TimeData(fs=1.0, u=u, y=y + 1e-3 * np.abs(y).mean(0) * rng.standard_normal(y.shape))
    res = compare(wrong, data)
    y_rest = control.forced_response(wrong, T=t, U=u.T).outputs.T
    O = np.stack([C @ np.linalg.matrix_power(A, k) for k in range(400)])  # (N, 2, 3)
    x_ls = np.linalg.lstsq(O.reshape(-1, 3), (data.y - y_rest).ravel(), rcond=None)[0]
    best = relative_error_time(data.y, y_rest + O @ x_ls)
    assert res.error_estimated_start == pytest.approx(best, rel=1e-9)


def test_a_finding_on_a_record_in_motion_is_kept_at_compares_error(stage):
    """The stage's delay left out of its true model: on the record cut mid-motion the
    diagnosis keeps the delay as its finding, its errors those compare reports from the
    estimated start (the model as given, then with the delay), down to the true model's."""
    from workbench.diagnosis import diagnose

    _, true, _, cut = stage
    nominal = true.replace(delay_s=0.0)
    result = diagnose(nominal, cut)
    (delay,) = result.findings
    assert delay.effect == "time_delay"
    assert delay.parameters["delay_s"] == pytest.approx(true.delay_s, rel=0.01)
    assert result.error_before == pytest.approx(
        compare(nominal, cut).error_estimated_start, rel=1e-9
    )
    after = compare(delay.model.to_lti(), cut)
    assert delay.error_after == pytest.approx(after.error_estimated_start, rel=1e-6)
    assert delay.error_after < 1.05 * compare(true, cut).error_estimated_start
    assert after.failing_bands == ()
    assert any("as compare computes it" in n for n in result.notes)
