"""``workbench run`` ends with a readable summary, not raw JSON lines (issue 13)."""

from __future__ import annotations

from workbench.digest import run_digest as _digest

SUMMARY = {
    "plant": {"name": "wafer_stage", "fs_hz": 5000.0, "n_u": 6, "n_y": 6},
    "compare": {"error": 0.31, "within_noise": False, "failing_bands": 14},
    "diagnose": {
        "error_before": 0.31,
        "findings": [
            {"effect": "time_delay", "parameters": {"delay_s": 0.0002}, "error_after": 0.04},
            {
                "effect": "modal_mismatch",
                "parameters": {
                    "freq_hz": 913.8,
                    "damping": 0.012,
                    "model_freq_hz": 967.0,
                    "modes": [{"freq_hz": 913.8}, {"freq_hz": 1032.0}],
                    "pattern": {"freq_scale": 0.945},
                    "b": [0.1] * 6,
                },
                "error_after": 0.012,
            },
            {
                "effect": "residual_compliance",
                "parameters": {"matrix": [[1e-9] * 6] * 6},
                "error_after": 0.011,
            },
        ],
    },
    "augment": {
        "steps": [{"effect": "time_delay", "error_after": 0.04}],
        "compare_after": {"error": 0.011, "within_noise": True, "failing_bands": 0},
    },
    "design": {
        "minimal": True,
        "designs": {"pid-notch": {"crossover_hz": [191.6, 190.0]}, "hinf": "skipped"},
    },
    "scenario": {"name": "demo", "seed": 7, "stage_seconds": {"compare": 1.0, "diagnose": 2.5}},
    "files": ["a.json"],
}


def test_digest_is_readable_text():
    text = _digest(SUMMARY)
    lines = text.splitlines()
    assert all(len(line) <= 100 for line in lines), text
    assert not any('{"' in line for line in lines)  # no JSON
    assert "compare: error 0.31, 14 failing band(s)" in text
    assert "error before 0.31" in text
    assert "1. time_delay (delay 200 us) -> error after 0.04" in text
    assert "freq_scale 0.945" in text and "2 modes" in text and "b [" not in text
    assert "residual_compliance (matrix (6x6)) -> error after 0.011" in text
    assert "compare after: error 0.011, within noise" in text
    assert "pid-notch crossovers [191.6, 190] Hz" in text
    assert "total 3.5 s" in text


def test_digest_survives_an_unknown_or_changed_section():
    text = _digest({**SUMMARY, "diagnose": {"findings": "changed"}, "new_stage": {"x": 1.5}})
    assert "new_stage: x 1.5" in text
