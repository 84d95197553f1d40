"""Coulomb friction on the wafer stage, in a closed-loop time record (issue 13, item 4).

The stage's model is square (DOF coordinates): its outputs are the ports' motion for the
six rigid modes, but its two flexible modes (914, 1032 Hz) are seen by the sensors with
other shapes than the actuators drive (c_k != b_k). Taking the outputs as the ports put a
non-collocated path in the friction's port velocity, and the diagnosis named saturation
(clear) or friction on the wrong ports (subtle), ~250x the floor. The diagnosis now fits
one port gain |b_k|^2 per non-collocated mode with the levels and v0
(workbench.diagnosis.nonlinear.SquarePorts).

Oracle: tests/casegen.py's truth (0.2 N clear, 0.05 N subtle at every DOF, v0 = 1e-6 m/s,
integrated by casegen's own scheme); its noise_floor is the record against that noise-free
truth. The true gains |b_k|^2 are the plant's flexible mode shapes at the actuators.
Measured (session 25, helper 22): 1.009x the floor (clear, seed 7), levels within 0.05 %.
"""

from __future__ import annotations

import numpy as np
import pytest

import casegen
from workbench.diagnosis import diagnose

#: casegen.make_case's stage friction, N, per size
STAGE_FRICTION_N = {"clear": 0.2, "subtle": 0.05}


def _true_gains() -> np.ndarray:
    """|b_k|^2 of the stage's flexible modes (m/N), the port residue the fit should find."""
    import plants

    truth = plants.get_plant("wafer_stage", delay_s=0.0)
    b = truth.chain.modes.b[6:]  # the six rigid modes first
    return np.einsum("ki,ki->k", b, b)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [7, 8])
@pytest.mark.parametrize("size", ["clear", "subtle"])
def test_stage_friction_is_named_with_its_element_levels_and_gains(size, seed):
    case = casegen.make_case("wafer_stage", "time", (("nonlinearity", size),), seed=seed)
    result = diagnose(case.model, case.data)
    effects = [f.effect for f in result.findings]
    assert effects and effects[0] == "nonlinearity", effects
    f = result.findings[0]
    p = f.parameters
    assert p["element"] == "coulomb_friction", p.get("element_errors")
    assert p["ports"] == [0, 1, 2, 3, 4, 5], p["ports"]
    force = np.asarray(p["friction_force"])
    truth = STAGE_FRICTION_N[size]
    assert np.all(np.abs(force - truth) <= 0.1 * truth), (force, truth)
    # the floor is the record against its noise-free truth, friction included
    assert f.error_after <= 2.0 * case.noise_floor, (f.error_after, case.noise_floor)
    # one gain per flexible mode, near |b_k|^2 (they set how the sticking ports hold them)
    gains = np.asarray(p["port_gains"])
    np.testing.assert_allclose(gains, _true_gains(), rtol=0.25)
    assert len(p["port_gain_freq_hz"]) == gains.size
