"""scenarios/studies/beam_inferential_youla.toml through the CLI: issue 10's numbers.

The Youla band design (held on a simulated 0.1 % FRF of the measured loop) against the
conventional pid-notch loops, both on the updated FE model, judged again here on the
TRUE beam's measured loops through ``workbench.testing`` (independent of the stage's
own evaluation): stable, |S_ii| <= 2 (6 dB); and from the stage's figures the z error
at the first flexible mode >= 10 dB below pid-notch's with the broadband z rms no more
than 1 dB worse (issue 10 asks for the rms to be reported; the design bounds it at
pid-notch's on the model, the true beam's z differs from the model's by ~1 %). On the
prior FE model the measured loop refuses the design (why updating matters).

Slow (about 10 minutes: the Youla design solves ~10 cone programs).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import run_scenario

SCENARIO = (
    Path(__file__).resolve().parents[1] / "scenarios" / "studies" / "beam_inferential_youla.toml"
)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return run_scenario(tmp_path_factory, SCENARIO, "beam_inferential_youla")


@pytest.mark.parametrize("design", ["pid-notch", "youla-band"])
def test_updated_designs_meet_the_bound_on_the_true_beam(run, beam_measured_truth, design):
    from workbench.testing import assert_margins, assert_stable

    out, res = run
    assert res["designs"][f"{design}/updated"]["status"] == "designed"
    path = out / f"controller_{design}_updated.npz"
    m = res["loop_delay_samples"]
    assert_stable(beam_measured_truth, path, loop_delay_samples=m)
    assert_margins(beam_measured_truth, path, s_peak_max=res["ms_max"], loop_delay_samples=m)


def test_youla_band_meets_the_target_at_the_unmeasured_point(run):
    _, res = run
    c = res["comparison"]["updated"]["youla-band"]
    assert c["z_mode1_reduction_db"] >= 10.0
    assert c["dz_band_peak_reduction_db"] >= 10.0
    assert c["z_rms_reduction_db"] > -1.0
    assert c["s_peak_within_bound"]


def test_prior_model_is_refused_by_the_measured_loop(run):
    _, res = run
    r = res["designs"]["youla-band/prior"]
    assert r["status"] == "refused", r.get("analysis", {}).get("stable")
