"""Explanations of findings: what the numbers say, in the engineer's terms."""

from __future__ import annotations

from workbench.diagnosis.explain import explain


def _lag_evidence(cutoffs):
    return {
        "parameters": {"cutoff_hz": cutoffs},
        "band_hz": (1.0, 5000.0),
        "inputs": [0, 1, 2],
        "outputs": [0, 1],
        "n_u": 3,
        "n_y": 2,
        "error_before": 4.0e-5,
        "error_after": 3.75e-5,
        "kind": "time",
    }


def test_a_lag_far_above_the_band_is_said_to_be_a_phase_only():
    """Cutoffs of 17 and 57 MHz on a band to 5 kHz (a held-out indep3 beam record): no
    roll-off in the band, a phase of 5000 / 1.7e7 = 2.9e-4 rad at its top; a lag inside the
    band is explained as an actuator's roll-off."""
    fast = explain("actuator_dynamics", _lag_evidence([None, 1.7e7, 5.7e7]))
    assert "no roll-off in the band" in fast and "0.00029 rad" in fast
    slow = explain("actuator_dynamics", _lag_evidence([300.0, 450.0, 600.0]))
    assert "no roll-off" not in slow and "300-600 Hz" in slow
