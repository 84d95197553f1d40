"""The three shared example cases give the right top finding (format and convention check)."""

from __future__ import annotations

import json

import pytest
from conftest import SHARED_EXAMPLES, require_shared

from workbench.diagnosis import diagnose
from workbench.io.formats import load_measurement, load_model

EXAMPLES = SHARED_EXAMPLES
NAMES = ["example_stage_missing_frf", "example_beam_none_frf", "example_stage_delay_time"]


@pytest.mark.parametrize("name", NAMES)
def test_example_top_finding(name):
    folder = require_shared(EXAMPLES / name)
    answer = json.loads((folder / "answer.json").read_text())
    result = diagnose(
        load_model(folder / "nominal_model.npz"), load_measurement(folder / "measurement.npz")
    )
    assert result.error_before == pytest.approx(answer["nominal_error"], abs=1e-6)
    top = result.findings[0]
    truth = answer["effects"][0]
    assert top.effect == truth["effect"]
    assert top.error_after < 2 * answer["noise_floor_error"]
    for key, value in truth["parameters"].items():
        if isinstance(value, float):
            assert top.parameters[key] == pytest.approx(value, rel=0.05)
