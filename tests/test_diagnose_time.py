"""Diagnosis of time records: ZOH simulation from rest driven by the recorded u.

Cases from test_diagnose_gen: the stage in closed loop (PD per axis), the beam
in open loop, periodic multisines, white output noise at 1 % of the output rms.
Tolerances as in test_diagnose_frf.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_diagnose_frf import check_parameters
from test_diagnose_gen import beam, beam_params, stage, stage_params, time_case

from workbench.diagnosis import diagnose
from workbench.io.formats import TimeData

CASES = [
    ("beam", "time_delay"),
    ("stage", "suspension_stiffness"),
    ("stage", "crosstalk"),
    pytest.param("beam", "modal_mismatch", marks=pytest.mark.slow),
    pytest.param("beam", "actuator_dynamics", marks=pytest.mark.slow),
    pytest.param("stage", "sensor_dynamics", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("plant,effect", CASES)
def test_time_single_effect(plant, effect):
    p, params = (stage(), stage_params) if plant == "stage" else (beam(), beam_params)
    truth = params(effect, "clear")
    if effect == "modal_mismatch":
        truth = dict(truth, true_freq_hz=p.modes[truth["index"]][0])
    case = time_case(p, effect, truth, rel=0.01, rng=np.random.default_rng(3))
    assert case.visibility > 1.5
    result = diagnose(case.nominal, case.data)
    top = result.findings[0]
    assert top.effect == effect, [f.effect for f in result.findings]
    check_parameters(effect, top.parameters, truth)
    assert top.error_after < 2 * case.noise_floor


def test_time_none_on_clean_model():
    case = time_case(beam(), "none", {}, rel=0.01, rng=np.random.default_rng(4))
    result = diagnose(case.nominal, case.data)
    assert [f.effect for f in result.findings] == ["none"]


def test_nonlinearity_on_unexcited_lines():
    # a cubic stiffening output distortion: periodic power on the lines the multisine leaves empty
    case = time_case(stage(), "none", {}, rel=0.002, rng=np.random.default_rng(8))
    y = case.data.y
    y_nl = y + 0.3 * y**3 / np.max(np.abs(y), axis=0) ** 2
    data = TimeData(
        fs=case.data.fs,
        u=case.data.u,
        y=y_nl,
        r=case.data.r,
        loop="closed",
        period=case.data.period,
    )
    result = diagnose(case.nominal, data, max_effects=1)
    effects = [f.effect for f in result.findings]
    assert "nonlinearity" in effects
    nl = next(f for f in result.findings if f.effect == "nonlinearity")
    assert 0 < nl.parameters["level"] < 1


def test_none_on_a_record_without_periods_says_whether_the_residual_is_white():
    """Without periods there is no noise floor: "nothing is missing" only where the right
    model's residual is white; coloured (a slow drift of the sensor here) it says so."""
    import scipy.signal

    from workbench.diagnosis.diagnose import _none_finding, base_model
    from workbench.diagnosis.problem import make_problem

    case = time_case(beam(), "none", {}, rel=0.01, rng=np.random.default_rng(4))
    d = case.data
    drift = scipy.signal.lfilter(
        [1.0], [1.0, -0.99], np.random.default_rng(5).standard_normal(d.y.shape), axis=0
    )
    texts = []
    for y in (d.y, d.y + 0.3 * np.std(d.y - np.mean(d.y, 0)) * drift / np.std(drift)):
        data = TimeData(fs=d.fs, u=d.u, y=y, r=d.r, loop=d.loop, period=None)
        problem = make_problem(data)
        model = base_model(case.nominal, data)
        err = problem.error(model)
        texts.append(_none_finding(problem, model, data, err, err, None, []).explanation)
    assert texts[0].endswith("nothing is missing.")
    assert "not white" in texts[1] and "nothing is missing" not in texts[1]


def test_time_delay_of_many_samples_is_found():
    """A delay of 64 samples (12.8 ms at 5 kHz: a network or computation delay) is a delay,
    not an actuator lag plus a shorter delay (the search once stopped at 16 samples)."""
    delay = 64 / 5000.0
    case = time_case(
        beam(), "time_delay", {"delay_s": delay}, rel=0.01, rng=np.random.default_rng(3)
    )
    result = diagnose(case.nominal, case.data)
    top = result.findings[0]
    assert [f.effect for f in result.findings] == ["time_delay"]
    assert abs(top.parameters["delay_s"] - delay) < 0.02 * delay
    assert top.error_after < 1.2 * case.noise_floor


def test_unrepeated_periods_note_on_a_time_varying_record():
    """The note's rule alone: the right model's own record repeats its periods; the same
    record from a plant whose gain drifts by 30 % over it does not."""
    from workbench.diagnosis import detect
    from workbench.diagnosis.diagnose import _unrepeated_periods, base_model
    from workbench.diagnosis.problem import make_problem

    case = time_case(beam(), "none", {}, rel=0.01, rng=np.random.default_rng(4))
    d = case.data
    drift = 1.0 + 0.3 * np.arange(d.n_samples)[:, None] / d.n_samples
    varying = TimeData(fs=d.fs, u=d.u, y=d.y * drift, r=d.r, loop=d.loop, period=d.period)
    for data, expected in ((d, False), (varying, True)):
        problem = make_problem(data)
        y_model = problem.predict(base_model(case.nominal, data))
        spread = detect.noise_floor(data, y_model)
        err = float(np.linalg.norm(data.y - y_model) / np.linalg.norm(data.y))
        assert (_unrepeated_periods(data, y_model, spread, err) is not None) == expected


@pytest.mark.slow
def test_periods_that_do_not_repeat_are_said_so():
    """A periodic record whose periods do not repeat (here a plant whose gain drifts by 30 %
    over the record: time-varying) says so in the notes and in compare's explanation, with
    the spread against its white-noise estimate; the right model on its own record does not."""
    case = time_case(beam(), "none", {}, rel=0.01, rng=np.random.default_rng(4))
    right = diagnose(case.nominal, case.data)
    assert not any("do not repeat" in n for n in right.notes)
    d = case.data
    drift = 1.0 + 0.3 * np.arange(d.n_samples)[:, None] / d.n_samples
    varying = TimeData(fs=d.fs, u=d.u, y=d.y * drift, r=d.r, loop=d.loop, period=d.period)
    res = diagnose(case.nominal, varying)
    note = [n for n in res.notes if "do not repeat" in n]
    assert len(note) == 1, res.notes
    assert "x its estimate as white noise" in note[0]


def test_weak_distortion_is_noted_where_no_element_can_be_fitted():
    """Distortion beyond the noise on the unexcited lines at a share of the output power too
    small for an element (a hardening spring whose linearization a modal mismatch holds) is
    said; strong distortion (fitted as an element) or noise is not."""
    from workbench.diagnosis.detect import NonlinearityEvidence
    from workbench.diagnosis.diagnose import _weak_distortion

    def ev(f_stat, level):
        return NonlinearityEvidence(
            level=level, f_stat=f_stat, n_lines=369, band_hz=(3.0, 611.0), stationarity=1.0
        )

    note = _weak_distortion(ev(7.2, 2.1e-6))
    assert note is not None and "F 7.2" in note and "2.1e-06" in note
    assert _weak_distortion(ev(7.2, 0.01)) is None  # an element's evidence
    assert _weak_distortion(ev(1.1, 2.1e-6)) is None  # noise
    assert _weak_distortion(None) is None


def test_distortion_on_a_record_whose_periods_do_not_repeat_is_a_finding(monkeypatch):
    """Distortion on the unexcited lines is direct evidence, but an element must still
    lower the error to make it a finding; a record whose periods do not repeat is the
    exception (a chaotic Duffing response is followed sample by sample by no simulation,
    the truth's included): the finding then carries the distortion, the linear model's
    error, and the element that was tried with its error."""
    import sys

    from workbench.diagnosis.detect import NonlinearityEvidence
    from workbench.diagnosis.diagnose import base_model
    from workbench.diagnosis.nonlinear import ElementFit, PortNonlinearity

    module = sys.modules["workbench.diagnosis.diagnose"]
    case = time_case(beam(), "none", {}, rel=0.01, rng=np.random.default_rng(4))
    model = base_model(case.nominal, case.data)
    cur_err = 0.3
    tried = ElementFit(
        element="cubic_stiffness",
        ports=(),
        parameters={"cubic_stiffness": [1.0], "mode": 3, "mode_freq_hz": 230.0},
        nonlinearity=PortNonlinearity(friction_force=np.zeros(case.data.n_u)),
        error_before=cur_err,
        error_after=1.05 * cur_err,  # no lower than the linear model
        candidates={"cubic_stiffness": 1.05 * cur_err},
        level=0.01,
    )
    monkeypatch.setattr(module, "_fit_element", lambda *a, **k: (tried, model, None))
    ev = NonlinearityEvidence(
        level=0.04, f_stat=4.8, n_lines=300, band_hz=(3.0, 600.0), stationarity=1.0
    )

    def finding(unrepeated):
        return module._nonlinearity_finding(
            ev, case.data, 0.4, [model], cur_err, direct=True, unrepeated=unrepeated
        )

    found, alt = finding(False)
    assert found is None and alt["effect"] == "nonlinearity"
    found, alt = finding(True)
    assert alt is None and found.effect == "nonlinearity"
    assert found.error_after == cur_err and found.parameters["level"] == ev.level
    assert "do not repeat" in found.explanation and "cubic stiffness" in found.explanation


def test_the_rerun_reuses_the_first_rounds_screens_and_fits(monkeypatch):
    """diagnose's second pass (the rerun on the pairs) starts from the same model on the same
    record: sharing the decomposition, the problem and the first round's screens and fits,
    a pass given what an earlier one computed screens and fits nothing again in its first
    round and ends as that one did."""
    import importlib

    D = importlib.import_module("workbench.diagnosis.diagnose")
    truth = beam_params("time_delay", "clear")
    case = time_case(beam(), "time_delay", truth, rel=0.01, rng=np.random.default_rng(3))
    kw = dict(max_effects=1, n_full_fits=None, effects=None, delay_s=0.0, domain="auto")
    shared: dict = {}
    first = D._diagnose(case.nominal, case.data, shared=shared, **kw)
    calls = []
    for name in ("fit", "screen", "_on_the_record"):
        orig = getattr(D, name)
        monkeypatch.setattr(
            D, name, lambda *a, _o=orig, _n=name, **k: calls.append(_n) or _o(*a, **k)
        )
    again = D._diagnose(case.nominal, case.data, shared=shared, **kw)
    assert calls == []
    assert (
        [f.effect for f in again.findings] == [f.effect for f in first.findings] == ["time_delay"]
    )
    assert again.findings[0].error_after == first.findings[0].error_after
    # without what the first pass kept, the same pass screens and fits afresh
    D._diagnose(case.nominal, case.data, shared={}, **kw)
    assert "fit" in calls and "screen" in calls
