"""A damping ratio that ends at the search's floor is reported as an upper bound, not a value."""

from __future__ import annotations

from workbench.diagnosis.effects import MIN_DAMPING
from workbench.diagnosis.explain import damping_floor_note


def test_a_mode_at_the_damping_floor_says_what_the_record_resolves():
    note = damping_floor_note({"freq_hz": 0.4127, "damping": MIN_DAMPING}, {"damping": 0.0024})
    assert "floor (1e-06)" in note and "below about 0.0024 (its std)" in note


def test_a_resolved_damping_gets_no_note():
    assert damping_floor_note({"damping": 10 * MIN_DAMPING}, {"damping": 1e-6}) == ""
    assert damping_floor_note({"delay_s": 1e-4}, {"delay_s": 1e-6}) == ""


def test_a_suspension_names_its_modes_at_the_floor():
    params = {
        "damping": 0.05,
        "modes": [
            {"freq_hz": 12.85, "damping": 0.05},
            {"freq_hz": 20.55, "damping": 1.0000000000447917e-06},
        ],
    }
    note = damping_floor_note(params, {"damping": 1e-5})
    assert "20.55 Hz" in note and "12.85" not in note
