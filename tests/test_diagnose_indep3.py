"""diagnose on the third independent generator (tests/indepgen3.py), CI subset.

The generator's plants are not the project's (a two-mass drive with a flexible
shaft, a planar 3-DOF stage with 4 actuators and 3-4 sensors, a free-free
aluminium beam) and its code shares nothing with the diagnosis engine. The
CI subset: a few quick FRF cases (spec 1b with G_var); the assertion is on
the effect named by the top finding, and on the error after the findings
against the noise floor of the case (the spec error of the TRUE system on its
own noisy measurement), within 2x as the task asks. The whole table is
benchmarks/bench_diagnose_indep3.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_diagnose_indep3 import score, to_measurement  # noqa: E402
from indepgen3 import make_case  # noqa: E402

from workbench.diagnosis import diagnose  # noqa: E402


def _time_case(seed: int, plant: str, effect: str):
    """The held-out time record of ``seed``, ``plant`` and ``effect`` (as the benchmark
    draws it with ``--kinds time``)."""
    from indepgen3 import make_suite

    ((plant, effect, kind, rng),) = make_suite(
        seed, kinds=("time",), plants=(plant,), effects=(effect,)
    )
    return make_case(effect, plant, kind, rng)


#: (plant, effect): quick FRF cases, one per plant and a clean one
CI_CASES = [
    ("shaft", "time_delay"),
    ("planar", "missing_mode"),
    ("beam", "actuator_dynamics"),
    ("planar", "none"),
]


@pytest.mark.parametrize(("plant", "effect"), CI_CASES, ids=[f"{p}-{e}" for p, e in CI_CASES])
def test_frf_case_names_the_effect(plant, effect):
    case = make_case(effect, plant, "frf", np.random.default_rng([313, len(plant), len(effect)]))
    res = diagnose(case.nominal, to_measurement(case))
    row = score(case, res)
    assert row["top"] == effect, row
    assert row["param_ok"], row
    assert row["ratio"] <= 2.0, row


def test_a_candidate_that_raises_the_error_does_not_hold_back_the_coupled_suspension():
    """Held-out seed 22, a beam FRF on springs without dampers (17.6 and 31.4 Hz) that
    stiffen its first bending mode 59.5 -> 68.6 Hz. An actuator lag came first by the lines'
    weighted cost while it raised the error (0.24 -> 1.03); the rigid suspension (0.088),
    not the best, was not refined with its coupling, and a modal mismatch stood in beside it
    at 17.5x the floor. Its coupling reaches the floor."""
    from indepgen3 import make_suite

    ((plant, effect, kind, rng),) = make_suite(
        22, kinds=("frf",), plants=("beam",), effects=("suspension_stiffness",), n_frf=1
    )
    case = make_case(effect, plant, kind, rng)
    row = score(case, diagnose(case.nominal, to_measurement(case)))
    assert row["findings"] == ["suspension_stiffness"] and row["param_ok"], row
    assert row["ratio"] <= 1.05, row


def test_generator_answer_is_consistent():
    """The case's own oracle: the true system's FRF error on its data is the noise floor."""
    case = make_case("time_delay", "planar", "frf", np.random.default_rng(5))
    G_true = case.truth.frf(case.data["freq"])
    G = case.data["G"]
    err = np.mean(np.linalg.norm(G - G_true, axis=(1, 2)) / np.linalg.norm(G, axis=(1, 2)))
    assert err == pytest.approx(case.answer["noise_floor_error"], rel=1e-12)
    # and the effect is visible: the nominal misses it by >= 4x the floor (the generator's rule)
    assert case.answer["visibility"] >= 4.0


def test_residual_compliance_split_with_a_mode_that_rings_in_the_record():
    """Truncated modes at 5975 and 9497 Hz sampled at 7900 Hz: the second rings at
    9497 - 7900 = 1597 Hz (damping 0.02 x 9497 / 1597 = 0.119), so a missing mode named
    there is that mode, and the residual compliance is scored against the first's static
    part alone; a mode elsewhere leaves the whole matrix to the residual compliance."""
    from bench_diagnose_indep3 import param_error

    R1, R2 = np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[-4.0, 1.0], [2.0, -3.0]])
    modes = [
        {"freq_hz": 5975.0, "damping": 0.02, "matrix": R1.tolist()},
        {"freq_hz": 9497.0, "damping": 0.02, "matrix": R2.tolist()},
    ]
    truth = {"matrix": (R1 + R2).tolist(), "modes": modes}
    found = {"matrix": R1.tolist()}
    # same decay rate and damped frequency less fs: the same sampled poles
    sigma, f_d = 0.02 * 9497.0, 9497.0 * np.sqrt(1 - 0.02**2) - 7900.0
    ringing = {"freq_hz": np.hypot(f_d, sigma), "damping": sigma / np.hypot(f_d, sigma)}
    assert param_error("residual_compliance", truth, found, [ringing], 7900.0) == pytest.approx(0)
    elsewhere = {"freq_hz": 1500.0, "damping": 0.119}
    whole = np.linalg.norm(R2) / np.linalg.norm(R1 + R2)
    got = param_error("residual_compliance", truth, found, [elsewhere], 7900.0)
    assert got == pytest.approx(whole)
    # an FRF shows no aliases: the same mode is named only at its own frequency
    assert param_error("missing_mode", truth, ringing, fs=None) > 0.5
    assert param_error("missing_mode", truth, ringing, fs=7900.0) < 1e-12


def test_record_without_periods_stops_where_the_residual_is_white(monkeypatch):
    """A record without periods has no noise floor of its own: once the findings leave a
    white residual, no further round is searched (its joint refits were most of the time,
    for nothing), and the finding is the generator's effect at the noise floor."""
    # the module (the package's name ``diagnose`` is the function)
    diagnose_module = sys.modules["workbench.diagnosis.diagnose"]

    calls = []
    joint = diagnose_module.fit_joint
    monkeypatch.setattr(
        diagnose_module, "fit_joint", lambda *a, **k: calls.append(1) or joint(*a, **k)
    )
    case = _time_case(0, "shaft", "time_delay")
    assert not case.answer["periodic"]
    res = diagnose(case.nominal, to_measurement(case))
    row = score(case, res)
    assert row["top"] == "time_delay" and row["param_ok"] and row["ratio"] <= 1.05, row
    assert len(res.findings) == 1 and not calls


@pytest.mark.slow
def test_compliance_whose_image_reaches_past_nyquist_stays_a_compliance():
    """Held-out seed 1, planar record at 5400 Hz without periods, modes at 8133 and
    10 256 Hz left out: the residual compliance's image at 2667 Hz (zeta 0.06) reaches past
    Nyquist, so it is no resonance the band shows; it was swapped for a missing mode that
    went to 2706 Hz, above Nyquist. The compliance stays, its matrix in tolerance."""
    case = _time_case(1, "planar", "residual_compliance")
    res = diagnose(case.nominal, to_measurement(case))
    row = score(case, res)
    assert row["top"] == "residual_compliance" and row["param_ok"], row
    assert row["ratio"] <= 1.2, row


@pytest.mark.slow
def test_a_pair_that_explains_less_than_the_best_single_effect_is_not_taken():
    """Held-out seed 7, beam record in motion with periods, a suspension (15.8 / 24.8 Hz):
    the coupled suspension alone reaches 1.01x the floor, yet compare finds it above the
    noise, and the rerun's pair (suspension and crosstalk, better on the lines' cost, 1.14x on
    the record) had replaced it, with a zero delay and a null mismatch after it at 1.13x. A
    pair whose error is not below the best single effect's is not taken: one finding."""
    case = _time_case(7, "beam", "suspension_stiffness")
    res = diagnose(case.nominal, to_measurement(case))
    row = score(case, res)
    assert row["findings"] == ["suspension_stiffness"] and row["param_ok"], row
    assert row["ratio"] <= 1.05, row


@pytest.mark.slow
@pytest.mark.parametrize("plant", ["planar", "beam"])
def test_truncated_modes_on_a_sampled_record_are_one_residual_compliance(plant):
    """Held-out seed 10, records at 7600 Hz. Planar: modes at 10 068 and 18 492 Hz left
    out; the compliance's static part, a feedthrough D u[k], answered a sample early, and a
    "time delay" of 1.5e-10 s (its std 3.2e-10) moved it by one sample (matrix 56 % off).
    Beam: eight modes from 7507 Hz up, the lowest folded to 93 Hz (damping 0.40 there,
    0.005 at its image), named a missing mode beside the compliance (matrix 72 % off).
    Now no delay, and the folded mode's static part is the compliance's."""
    row = _compliance_record(10, plant)
    assert "time_delay" not in row["findings"], row


@pytest.mark.slow
@pytest.mark.parametrize("seed", [4, 9])
def test_a_beams_truncated_modes_add_up_to_its_compliance(seed):
    """Held-out seeds 4 and 9, periodic beam records at 6400 and 4800 Hz, six modes left out
    from 1.2x Nyquist up, most of them folded into or near the band. Seed 9: the third
    image lowered the error only 0.86x near the floor (F 11.8 -> 7.1) and the search
    stopped at 1.6x it, the matrix 55 % off. Seed 4: a mode above the band named by its
    static part kept the value of the round that found it (45 % off)."""
    _compliance_record(seed, "beam")


@pytest.mark.slow
def test_a_compliance_on_a_record_without_periods_is_found_near_the_floor():
    """Held-out seed 9, a planar record without periods, its modes above
    Nyquist left out: the compliance lowered the error only 0.87x (7.97e-6 -> 6.92e-6), no
    large finding by the error, and the diagnosis was 'none' at 1.16x the floor. Over the
    noise read from the residuals' spectra it removes the misfit (F 1.32 -> 0.99)."""
    row = _compliance_record(9, "planar")
    assert row["findings"] == ["residual_compliance"], row


@pytest.mark.slow
def test_a_compliance_on_low_passed_noise_is_not_a_mode_above_the_excitation():
    """Held-out seed 20, a shaft record without periods at 6900 Hz, noise low-passed at
    2606 Hz, modes at 8090 and 10 396 Hz left out. The band read from the record's
    unwindowed spectrum ran to Nyquist (the step between its ends leaks a floor over the
    threshold), so a mode fitted at 3331 Hz, damping 0.0006, where the input is 60 dB down,
    was "in the band" and named a missing mode, the compliance dropped. Windowed, the band
    ends at 3267 Hz and that mode is the compliance's static part."""
    _compliance_record(20, "shaft")


def _compliance_record(seed: int, plant: str) -> dict:
    """The held-out residual compliance time record of ``seed`` and ``plant``, diagnosed and
    scored: the compliance on top, its matrix in tolerance, within 1.3x the floor."""
    case = _time_case(seed, plant, "residual_compliance")
    row = score(case, diagnose(case.nominal, to_measurement(case)))
    assert row["top"] == "residual_compliance" and row["param_ok"], row
    assert row["ratio"] <= 1.3, row
    return row


def _fits_recorded(monkeypatch, results: list | None = None) -> list:
    """The names of the structures diagnose fits, recorded as it runs (``results``: their
    FitResults too)."""
    diagnose_module = sys.modules["workbench.diagnosis.diagnose"]
    fitted = []
    fit = diagnose_module.fit

    def recorded(s, *a, **k):
        fitted.append(type(s).__name__)
        out = fit(s, *a, **k)
        if results is not None:
            results.append(out)
        return out

    monkeypatch.setattr(diagnose_module, "fit", recorded)
    return fitted


def test_a_suspension_at_the_floor_is_not_refined_with_its_coupling(monkeypatch):
    """A planar stage on springs, a periodic record from rest: the rigid suspension,
    refitted on the record, is at the floor the periods give, so its coupling to the
    flexible modes (37 parameters by differences, most of the diagnosis's time) is not
    fitted; the finding is the generator's suspension at the noise floor all the same."""
    fitted = _fits_recorded(monkeypatch)
    case = _time_case(9, "planar", "suspension_stiffness")
    assert case.answer["periodic"] and case.answer["at_rest"]
    res = diagnose(case.nominal, to_measurement(case))
    row = score(case, res)
    assert row["top"] == "suspension_stiffness" and row["param_ok"], row
    assert row["ratio"] <= 1.05, row
    assert "RigidSuspension" in fitted and "CoupledSuspension" not in fitted


def test_sensor_lags_on_a_single_input_plant_are_one_lag_on_the_response():
    """Held-out seed 12, the shaft (one motor torque, two angles) time record: both sensors
    lagged, at 2191.2 and 2185.4 Hz (drawn apart, 0.26 % apart). With one input, a lag on it
    is the same factor on the response as one lag on both outputs (l G = G l, a scalar); the
    one-cutoff lag reached 1.00003x the floor, the two sensor lags 0.99999x with one more
    parameter. The finding says it is that scalar factor (``common``), and is scored against
    every true cutoff."""
    case = _time_case(12, "shaft", "sensor_dynamics")
    res = diagnose(case.nominal, to_measurement(case))
    row = score(case, res)
    assert row["top"] in ("actuator_dynamics", "sensor_dynamics"), row
    if row["top"] == "actuator_dynamics":
        assert res.top.parameters["common"] is True
        assert "inputs and outputs alike" in res.top.explanation
    assert row["right"] and row["param_ok"], row
    assert row["ratio"] <= 1.05, row


@pytest.mark.slow
def test_lags_beyond_the_screen_are_not_fitted_where_the_best_leaves_white_noise(monkeypatch):
    """Held-out seed 14, a beam record without periods, in motion, output crosstalk: the
    crosstalk fitted among the screen's best few leaves a white residual, so the per-channel
    lags the screen ranked below them are not fitted (5.8 of the diagnosis's 17 s); the
    finding is the crosstalk at the floor all the same."""
    fitted = _fits_recorded(monkeypatch)
    case = _time_case(14, "beam", "crosstalk")
    assert not case.answer["periodic"]
    row = score(case, diagnose(case.nominal, to_measurement(case)))
    assert row["findings"] == ["crosstalk"] and row["ratio"] <= 1.05, row
    assert "ActuatorDynamics" not in fitted and "SensorDynamics" not in fitted


@pytest.mark.slow
def test_searches_stalled_far_above_a_fit_at_the_noise_are_given_up(monkeypatch):
    """Held-out seed 16, a planar record without periods, in motion, input crosstalk: the
    crosstalk, first by the screen, is fitted to a white residual in a few evaluations; the
    suspensions after it crept down at more than 1000x its cost (9 and 6 s of a 29 s
    diagnosis). They are given up at their best point, and the finding is the same."""
    results: list = []
    _fits_recorded(monkeypatch, results)
    case = _time_case(16, "planar", "crosstalk")
    assert not case.answer["periodic"]
    row = score(case, diagnose(case.nominal, to_measurement(case)))
    assert row["findings"] == ["crosstalk"] and row["ratio"] <= 1.05, row
    crosstalk = min((r for r in results if r.effect == "crosstalk"), key=lambda r: r.cost)
    given_up = [r for r in results if r.abandoned]
    assert {type(r.structure).__name__ for r in given_up} >= {"SuspensionModes"}
    assert all(r.cost > 100 * crosstalk.cost for r in given_up)


def test_a_model_that_leaves_a_white_residual_on_a_record_without_periods_is_not_searched(
    monkeypatch,
):
    """Held-out seed 16, a planar record without periods, in motion, nothing missing: the
    model as given leaves a white residual, the rounds' own stop on such a record, so the
    search stops before its first round (every structure screened and the best few fitted
    took 5.9 s) and says why."""
    fitted = _fits_recorded(monkeypatch)
    case = _time_case(16, "planar", "none")
    assert not case.answer["periodic"]
    res = diagnose(case.nominal, to_measurement(case))
    assert [f.effect for f in res.findings] == ["none"] and not fitted
    assert "white residual" in res.findings[0].explanation
    assert "no effect was fitted" in res.findings[0].explanation
