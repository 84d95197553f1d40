"""Diagnose on independent-style cases (tests/indepgen.py: randomized plants, not plants/).

CI subset: one clear FRF case per effect on a random stage and beam, clean
('none') cases, and closed-loop stage time records (delay, friction). The
acceptance figures of the task: >= 90 % right top finding, the key parameter
within its tolerance (delay 10 %, frequencies 1 %, cutoffs 20 %, suspension
frequency 10 %, damping 30 %), error_after <= 2x the noise floor, 'none' on
clean data, the same answer for a model in any state coordinates. Bigger runs
are marked slow; the whole benchmark is benchmarks/bench_diagnose_indep.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

import control
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_diagnose_indep import TOL, accepted_effects, param_error  # noqa: E402
from indepgen import make_case  # noqa: E402

from workbench.diagnosis import LINEAR_EFFECTS, diagnose  # noqa: E402

FRF_STAGE = list(LINEAR_EFFECTS)
FRF_BEAM = ["time_delay", "missing_mode", "modal_mismatch", "sensor_dynamics"]
#: the CI subset (every effect once over the two plants; the rest in the slow test)
CI_STAGE = [
    "time_delay",
    "modal_mismatch",
    "actuator_dynamics",
    "suspension_stiffness",
    "crosstalk",
]
CI_BEAM = ["missing_mode", "residual_compliance", "sensor_dynamics"]
CI_STAGE_LAST = ["residual_compliance"]
#: damping tolerance of the task (relative)
DAMPING_TOL = 0.30


def _check(case, res):
    """(right top finding, parameter within tolerance, error_after / floor)."""
    top = res.findings[0]
    ok = top.effect in accepted_effects(case)
    truth = case.answer["effects"][0]
    perr = param_error(top.effect, truth["parameters"], top.parameters) if ok else None
    p_ok = perr is None or perr <= TOL[top.effect][1]
    if ok and "damping" in truth["parameters"] and "damping" in top.parameters:
        z_t, z_f = truth["parameters"]["damping"], top.parameters["damping"]
        p_ok = p_ok and abs(z_f / z_t - 1) <= DAMPING_TOL
    return ok, p_ok, top.error_after / case.answer["noise_floor_error"]


def _run(cases):
    out = []
    for case in cases:
        res = diagnose(case.nominal, case.data)
        out.append((case, res, *_check(case, res)))
    return out


def _assert_suite(results):
    n = len(results)
    right = [r for r in results if r[2]]
    lines = [
        f"{c.answer['plant']} {c.answer['data_kind']} {c.answer['effects'][0]['effect']} -> "
        f"{[f.effect for f in res.findings]} param_ok={p} after/floor={q:.2f}"
        for c, res, _, p, q in results
    ]
    msg = "\n".join(lines)
    assert n > 0 and right, "empty suite or nothing right: the checks below would pass vacuously"
    assert len(right) >= 0.9 * n, msg
    assert all(p for *_, p, _ in right), msg
    assert all(q <= 2.0 for *_, q in right), msg


def test_frf_stage_and_beam_clear():
    rng = np.random.default_rng(2024)
    cases = []
    # the stage's residual compliance last (added after the others: their draws stay)
    for plant, effects in (("stage", CI_STAGE), ("beam", CI_BEAM), ("stage", CI_STAGE_LAST)):
        for e in effects:
            try:
                cases.append(make_case(rng, plant=plant, kind="frf", effects=(e,), size="clear"))
            except RuntimeError:
                # not visible in this draw (the beam's residual compliance is at most its whole
                # static part, often within the noise); the draw consumed its random numbers
                # all the same, so the other cases are those of every earlier run
                continue
    assert len(cases) >= len(CI_STAGE) + len(CI_BEAM) + len(CI_STAGE_LAST) - 1
    _assert_suite(_run(cases))


@pytest.mark.parametrize("plant", ["stage", "beam"])
def test_none_on_clean_frf(plant):
    rng = np.random.default_rng(7)
    for _ in range(2):
        case = make_case(rng, plant=plant, kind="frf", effects=("none",))
        res = diagnose(case.nominal, case.data)
        assert [f.effect for f in res.findings] == ["none"]


def test_time_closed_loop_stage():
    # example-like closed-loop records: one-sample delay, Coulomb friction, nothing missing
    rng = np.random.default_rng(11)
    cases = [
        make_case(rng, plant="stage", kind="time", effects=(e,), size="clear")
        for e in ("none", "time_delay", "nonlinearity")
    ]
    results = _run(cases)
    assert [r[0].answer["effects"][0]["effect"] for r in results] == [
        r[1].findings[0].effect for r in results
    ]
    assert results[1][3]  # delay within 10 %


def test_model_in_other_coordinates_same_answer():
    # a random similarity transform of the nominal model must not change the diagnosis
    rng = np.random.default_rng(5)
    case = make_case(rng, plant="stage", kind="frf", effects=("missing_mode",))
    A, B, C, D = (
        np.asarray(M) for M in (case.nominal.A, case.nominal.B, case.nominal.C, case.nominal.D)
    )
    T = rng.standard_normal(A.shape) + 3 * np.eye(A.shape[0])
    Ti = np.linalg.inv(T)
    other = control.ss(Ti @ A @ T, Ti @ B, C @ T, D)
    r1 = diagnose(case.nominal, case.data).findings[0]
    r2 = diagnose(other, case.data).findings[0]
    assert r1.effect == r2.effect == "missing_mode"
    assert r2.parameters["freq_hz"] == pytest.approx(r1.parameters["freq_hz"], rel=1e-3)


@pytest.mark.slow
@pytest.mark.parametrize("size", ["clear", "subtle"])
@pytest.mark.parametrize("kind", ["frf", "time"])
@pytest.mark.parametrize("plant", ["stage", "beam"])
def test_all_effects(plant, kind, size):
    rng = np.random.default_rng(99)
    effects = FRF_STAGE if plant == "stage" else FRF_BEAM
    cases = []
    for e in effects:
        try:
            cases.append(make_case(rng, plant=plant, kind=kind, effects=(e,), size=size))
        except RuntimeError:  # not visible in this kind of data
            continue
    _assert_suite(_run(cases))


#: indepgen draws that failed (``bench_diagnose_indep.py --kinds time``, seed 0 with ``--plants
#: beam,stage --effects nonlinearity,suspension_stiffness,modal_mismatch``, seed 3 with
#: ``--plants stage,beam`` or ``beam``): the generator's PCG64 state before each case (state, inc,
#: has_uint32, uinteger), and the case's noise floor as drawn (a check that the state still
#: draws the same case). Before the fixes: a 10 % saturation of every input of a closed-loop
#: stage 287x the floor (the peak scan left an input unclipped), a slight one 9.6x, a mode
#: 0.06 % off (0.07 of its damping) named residual_compliance (the mismatch grid missed the
#: model frequency's neighbourhood), a light beam mode at 35.1 Hz between the excited lines
#: named residual_compliance (only the best candidate was refitted on the record), and (seed 3,
#: ``--plants beam``) a subtle crosstalk that only the from-rest response shows, 'none' at
#: 3.1x (the lines found nothing significant); and (seed 2, ``--kinds time``) a beam mode the
#: record hardly excites, whose model frequency the generator's strength search drove to -0.63x
#: the truth (an unstable nominal, named nonlinearity at 4e5x: the shift is bounded now,
#: indepgen.MAX_MISMATCH)
def _rng_at(state: int, inc: int, has_uint32: int, uinteger: int) -> np.random.Generator:
    """A generator at a recorded PCG64 state (a benchmark draw replayed)."""
    rng = np.random.default_rng()
    rng.bit_generator.state = {
        "bit_generator": "PCG64",
        "state": {"state": state, "inc": inc},
        "has_uint32": has_uint32,
        "uinteger": uinteger,
    }
    return rng


_INC0 = 87136372517582989555478159403783844777
_INC2 = 121863417007658695389390353187995180015
_INC3 = 222003063171874261427395693950637096479
_INC4 = 278272906083703887290699702293328866393
_DRAWS = {
    "stage_saturation_clear": (
        ("stage", "nonlinearity", "clear"),
        (79475984959111552478935125087140603718, _INC0, 0, 1445700676),
        0.007576444372338694,
    ),
    "stage_saturation_subtle": (
        ("stage", "nonlinearity", "subtle"),
        (335982534123803190894290274866614975802, _INC0, 0, 905512937),
        0.005117820922024464,
    ),
    # seed 18 (all effects): 7-11 % of each input's samples clipped; the least squares left
    # the sixth input's level 34 % high (five right to 1e-8), 88x the floor
    # seed 20 (all effects): a delay of one sample on a closed-loop record; the steady-state
    # lines fitted it 1.2 % long (1.15x the floor from rest), a pseudo-mode made up the rest
    # and was named a missing mode at its in-band image. On the sample: 1.00x, alone
    "stage_delay_one_sample_seed20": (
        ("stage", "time_delay", "clear"),
        (
            113704304020805440299607410238882379420,
            72763549156770659863042999813056722643,
            0,
            1651719361,
        ),
        0.0054898427391412265,
    ),
    "stage_saturation_clear_seed18": (
        ("stage", "nonlinearity", "clear"),
        (
            156962351294242105678069076607269416544,
            61103650459218955061752147258824541677,
            0,
            969592835,
        ),
        0.00804764647277866,
    ),
    "stage_mismatch_subtle": (
        ("stage", "modal_mismatch", "subtle"),
        (243245390598432021733244484719927236253, _INC0, 1, 3978911211),
        0.004389852599766486,
    ),
    "beam_missing_mode_subtle": (
        ("beam", "missing_mode", "subtle"),
        (38458068960779428944377209385997458804, _INC3, 1, 1676346504),
        0.0024055842202669125,
    ),
    "beam_crosstalk_subtle": (
        ("beam", "crosstalk", "subtle"),
        (169919823325736736945992507613172357112, _INC3, 1, 2436292870),
        0.01826696798681725,
    ),
    "beam_mismatch_clear_bounded": (
        ("beam", "modal_mismatch", "clear"),
        (256822951687814569811498793452118232642, _INC2, 1, 1097172331),
        0.018814222098612506,
    ),
    # seed 37 (all effects): ten periods, each input clipped at its two largest peaks (20
    # samples); the saturation screen's peak sweep took 12 samples, found nothing, and the
    # record was named 'none' at 3.35x the floor. The sweep takes 12 peaks a period now
    "beam_saturation_subtle_seed37": (
        ("beam", "nonlinearity", "subtle"),
        (
            307762612849641932549417860504706859497,
            70782546554204343252291554031180047225,
            0,
            319296586,
        ),
        0.006880733832622751,
    ),
    # seed 43 (all effects): the 644 Hz mode (damping 0.0068) 0.013 % low, z0 / 52. Every
    # point of the mismatch's grid (the nearest z0 / 16 away) cost more than the model as
    # given; it was not fitted, and a compliance of 110 parameters was named at the floor.
    # The screen takes the Gauss-Newton point from the model as given now
    "stage_mismatch_subtle_seed43": (
        ("stage", "modal_mismatch", "subtle"),
        (
            115392506637240115575690892544942740413,
            25065611243303971628957076795638243391,
            1,
            4096056368,
        ),
        0.002692342129221648,
    ),
    # seed 45 (all effects): a mode at 621 Hz on six inputs that share every line of one
    # period, named a residual compliance whose pseudo-mode at 5620.6 Hz (fs 5 kHz) is its
    # image: the mode tried at the image walked off on the lines, which do not determine its
    # residue (666 Hz, damping 7e-6, 13x the chain's error). On the record it holds
    "stage_missing_mode_clear_seed45": (
        ("stage", "missing_mode", "clear"),
        (
            105583715702046436556521143192596245486,
            122620962813697476525009183845032774019,
            0,
            3979278145,
        ),
        0.00665872554654081,
    ),
    # seed 45 (all effects): a closed-loop record whose lines start at 30 Hz, a suspension at
    # 0.73 Hz (3.4x the floor as given) that only the loop's start shows: the periods'
    # residual was at the noise (F 1.23), the search stopped before its first round and
    # friction on the rigid bodies was named at 2.02x. A from-rest error beyond twice the
    # periods' spread now searches the first round on the record
    "stage_suspension_subtle_below_the_lines_seed45": (
        ("stage", "suspension_stiffness", "subtle"),
        (
            315948991987838906184452518341970974023,
            122620962813697476525009183845032774019,
            1,
            883960621,
        ),
        0.00618161748282291,
    ),
}


@pytest.mark.parametrize("name", list(_DRAWS))
def test_time_draws_reach_the_floor(name):
    (plant, effect, size), (state, inc, has_uint32, uinteger), floor = _DRAWS[name]
    rng = _rng_at(state, inc, has_uint32, uinteger)
    case = make_case(rng, plant=plant, kind="time", effects=(effect,), size=size, case_id=name)
    assert case.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    res = diagnose(case.nominal, case.data)
    ok, p_ok, _ = _check(case, res)
    assert ok and p_ok, [f.effect for f in res.findings]
    ratio = res.findings[-1].error_after / floor
    assert ratio <= 1.1, ratio


def test_suspension_modes_below_the_lines_are_chosen_on_the_record():
    """indepgen seed 36 (all kinds and effects), beam time record, two suspension modes at
    3.0 and 4.2 Hz below the lowest excited line (4.9 Hz), subtle: the lines' BIC put the
    rigid suspension first (4.2x the floor on the record), the two modes refitted on the
    record reached 1.00x; the search went on to 2.8x and the whole record's rerun found
    them. The record's choice is now taken in the first round, on the lines' search."""
    rng = _rng_at(
        74933155055580736301079842886134969674,
        296356834324821931568104106068914913287,
        0,
        1339613882,
    )
    case = make_case(
        rng,
        plant="beam",
        kind="time",
        effects=("suspension_stiffness",),
        size="subtle",
        case_id="seed36",
    )
    floor = case.answer["noise_floor_error"]
    assert floor == pytest.approx(0.010141686885893814, rel=1e-9)
    res = diagnose(case.nominal, case.data)
    ok, p_ok, _ = _check(case, res)
    assert ok and p_ok and len(res.findings) == 1, [f.effect for f in res.findings]
    assert len(res.findings[0].parameters["modes"]) == 2
    assert res.findings[0].error_after / floor <= 1.1
    assert not any("fitted on the whole record" in note for note in res.notes), res.notes


def test_frf_without_variance_skips_the_coupling_where_the_suspension_leaves_noise(
    monkeypatch,
):
    """indepgen seed 31 (all kinds and effects), beam FRF without G_var, two suspension
    modes, clear: the suspension alone leaves at most a few per cent of the residual's power
    beyond noise from line to line, so its coupling to the flexible modes (38 parameters on
    1707 lines, most of the diagnosis's 25 s) is not fitted. The same finding at the floor."""
    import workbench.diagnosis.diagnose  # noqa: F401  (the module, not the function)

    module = sys.modules["workbench.diagnosis.diagnose"]
    fitted = []
    real_fit = module.fit

    def spy(structure, *args, **kwargs):
        fitted.append(type(structure).__name__)
        return real_fit(structure, *args, **kwargs)

    monkeypatch.setattr(module, "fit", spy)
    rng = _rng_at(
        253832813492436439799295846748053817347,
        107090353359002252723118071224206516545,
        1,
        466372295,
    )
    case = make_case(
        rng,
        plant="beam",
        kind="frf",
        effects=("suspension_stiffness",),
        size="clear",
        case_id="seed31",
    )
    assert case.data.G_var is None
    floor = case.answer["noise_floor_error"]
    res = diagnose(case.nominal, case.data)
    ok, p_ok, _ = _check(case, res)
    assert ok and p_ok and len(res.findings) == 1, [f.effect for f in res.findings]
    assert res.findings[0].error_after / floor <= 1.1
    assert "SuspensionModes" in fitted and "CoupledSuspension" not in fitted, fitted


#: indepgen stage records with hard Coulomb friction on the six rigid bodies (the generator's
#: friction acts on every body: all six ports carry it), each a generator at its draw, the size
#: and the noise floor as drawn:
#:
#: - seed 2 with ``--kinds time --plants stage``, subtle (visibility 7.9): the regression of the
#:   levels put two rotations' below zero (one at each high-pass corner) and the level fit kept
#:   a dropped port at none, so friction could not reach the floor and a cubic spring at the
#:   ports was named at 3.02x;
#: - seed 8 with ``--kinds time --effects nonlinearity``, the first case, clear (a closed loop;
#:   the linear model drifts to 1400x the output): the port-by-port start searched a rotation's
#:   level (regressed at 2.5x its truth) over 4x either way by a bounded 1-D search, which
#:   ended in a local minimum at 3.9x: the fit 29.7x the floor, then the ports' elements fitted
#:   for 300 s. The start takes the best of a grid first;
#: - seed 18 with ``--kinds time --plants stage,beam --effects nonlinearity``, subtle (a closed
#:   loop, visibility 9.3): the first-order signature of the bodies' friction removed 0.5 % of
#:   the residual power, the screen left it unfitted and the record was named 'none' at 9.3x
#:   the floor. A from-rest error above DRIFT_RATIO times the periods' floor fits it anyway
_STAGE_FRICTION_DRAWS = {
    "seed2_subtle": (
        lambda: _rng_at(206115282099456626102579666522903090780, _INC2, 1, 936373982),
        "subtle",
        0.008297236237371155,
    ),
    "seed8_clear": (lambda: np.random.default_rng(8), "clear", 0.010258870240599554),
    "seed18_subtle": (
        lambda: _rng_at(
            108267915832496814817408123126564502311,
            61103650459218955061752147258824541677,
            0,
            73146211,
        ),
        "subtle",
        0.009278843593196166,
    ),
    # seed 8 with ``--kinds time --plants stage --effects nonlinearity``: stiction taken for a
    # 0.85 Hz suspension (and a lag), 1.13x the floor, too close to it for the drift test:
    # the element was not tried
    "seed8_subtle": (
        lambda: _rng_at(
            183687288714136826205431183240859473628,
            60804517828637344299932890193562703917,
            0,
            3092812071,
        ),
        "subtle",
        0.011429681505164583,
    ),
    # the tilts' levels regressed 10x and 53x high; a port-by-port scan of a few per cent
    # around them ended where the bodies stick (94.7x the floor): only within a few per cent
    # of its truth is a level's error below that plateau (coulomb_port_profile)
    "seed24_clear": (
        lambda: _rng_at(
            262333686136293729942856292746383790185,
            14503878986101793044376121114264460843,
            0,
            1844832017,
        ),
        "clear",
        0.005258288297741881,
    ),
}


@pytest.mark.parametrize("name", list(_STAGE_FRICTION_DRAWS))
def test_stage_friction_on_every_rigid_body(name):
    rng, size, floor = _STAGE_FRICTION_DRAWS[name]
    case = make_case(rng(), plant="stage", kind="time", effects=("nonlinearity",), size=size)
    assert case.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    assert case.answer["effects"][0]["parameters"]["type"] == "friction"
    res = diagnose(case.nominal, case.data)
    f = res.findings[0]
    assert f.effect == "nonlinearity", [g.effect for g in res.findings]
    assert f.parameters["element"] == "coulomb_friction", f.parameters.get("element_errors")
    assert f.parameters["on"] == "rigid_modes"
    assert f.parameters["ports"] == [0, 1, 2, 3, 4, 5]
    assert f.error_after <= 1.1 * floor, f.error_after / floor


#: indepgen beam records with a cubic spring on a mode's coordinate (a modal Duffing: the
#: generator's spring on its first flexible mode of 30 Hz or more) that were named
#: modal_mismatch: the generator's PCG64 state before each case as in _DRAWS (seed 0 with
#: ``--kinds time``; seed 3 with ``--kinds time --plants stage,beam`` or ``--plants beam``),
#: the noise floor as drawn, and the error_after / floor before the modal element. The clear
#: ones' mismatch moved the mode out of the band at the floor (1.02x, 1.04x), the subtle ones'
#: left 2.12x and 1.52x. Seed 27 (all kinds and effects) subtle: a modal mismatch and a
#: missing mode beside it at 1.045x the floor, compare still failing 52-58 Hz at median z 42
_CUBIC_DRAWS = {
    "seed0_clear": (
        "clear",
        (198016630887804653132021786451797361185, _INC0, 1, 3330165333),
        0.003209593411771767,
    ),
    "seed3_clear": (
        "clear",
        (183023478725615755394323060943650550798, _INC3, 0, 1878131897),
        0.0021173152160271886,
    ),
    "seed3_subtle": (
        "subtle",
        (93189367815660307166475400493161203351, _INC3, 0, 3264794382),
        0.003098384028552803,
    ),
    "seed3_beam_subtle": (
        "subtle",
        (233754765070044772301018878115510247967, _INC3, 1, 2832159642),
        0.0028079984638176166,
    ),
    "seed27_subtle": (
        "subtle",
        (
            304789375582742068766926541799743563711,
            218250142745413522186470865394637724367,
            0,
            3785310157,
        ),
        0.005312133459629766,
    ),
}


@pytest.mark.parametrize("name", list(_CUBIC_DRAWS))
def test_beam_modal_duffing_draws_are_named(name):
    size, (state, inc, has_uint32, uinteger), floor = _CUBIC_DRAWS[name]
    rng = _rng_at(state, inc, has_uint32, uinteger)
    case = make_case(
        rng, plant="beam", kind="time", effects=("nonlinearity",), size=size, case_id=name
    )
    assert case.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    truth = case.answer["effects"][0]["parameters"]
    assert truth["type"] == "cubic"
    res = diagnose(case.nominal, case.data)
    top = res.findings[0]
    assert top.effect == "nonlinearity", [f.effect for f in res.findings]
    # the element on the mode's coordinate, the level it adds as the generator measured it
    assert top.parameters["element"] == "cubic_stiffness" and "mode" in top.parameters
    assert top.parameters["cubic_stiffness"][0] > 0
    assert top.parameters["level"] == pytest.approx(truth["level"], rel=0.1)
    assert res.findings[-1].error_after / floor <= 1.1
    if size == "clear":
        # the mismatch that moved the mode out of the band reached the floor too: listed
        # beside the spring, which says the record cannot choose
        (alt,) = [a for a in res.alternatives if "ambiguous" in a]
        assert alt["effect"] == "modal_mismatch" and alt["error_after"] / floor <= 1.1
        assert "cannot choose" in top.explanation


@pytest.mark.slow
def test_frf_pair_the_greedy_search_passes_over():
    # seed 4 --kinds frf --pairs, beam: a one-sample delay and a missing mode at 28.36 Hz.
    # Alone each leaves 37x / 204x the floor on the spec error; on the noise-weighted cost a
    # sensor lag at 0.2-2 Hz is best (146x) and the greedy search ended at 104x the floor
    # with sensor_dynamics, a mode at 726 Hz and the delay. The pair fitted jointly: 1.00x
    rng = _rng_at(190094049456367401899040280867471653645, _INC4, 0, 1364922832)
    case = make_case(
        rng, plant="beam", kind="frf", effects=("time_delay", "missing_mode"), size="clear"
    )
    floor = case.answer["noise_floor_error"]
    assert floor == pytest.approx(0.005817640499972754, rel=1e-9)
    truth = {e["effect"]: e["parameters"] for e in case.answer["effects"]}
    res = diagnose(case.nominal, case.data)
    got = {f.effect: f.parameters for f in res.findings}
    assert set(got) == {"time_delay", "missing_mode"}, [f.effect for f in res.findings]
    assert got["time_delay"]["delay_s"] == pytest.approx(truth["time_delay"]["delay_s"], rel=0.02)
    assert got["missing_mode"]["freq_hz"] == pytest.approx(
        truth["missing_mode"]["freq_hz"], rel=0.001
    )
    assert res.findings[-1].error_after <= 1.1 * floor
    assert res.remaining["within_noise"]


@pytest.mark.slow
def test_frf_pairs_are_tried_first_where_bic_and_error_disagree_on_the_first_step(monkeypatch):
    # seed 11 --kinds frf --effects suspension_stiffness --pairs, stage: a 50 us delay and a
    # missing mode at 870.9 Hz. Alone residual compliance is best by BIC (error 0.406), the
    # delay by error (0.371); the best leaves less than half the nominal's 0.86, so the
    # first round's pairs were not tried, and the greedy search built on the compliance
    # (sensor lag, mode, ...: 59 s) before the rerun found the pair. Ambiguous first step:
    # the pairs in the first round, the greedy search ends there
    import sys

    module = sys.modules["workbench.diagnosis.diagnose"]
    rng = _rng_at(135720341417103680717211620133174845114, 7937318808080196428804369945471644491,
                  0, 1052670933)  # fmt: skip
    case = make_case(
        rng, plant="stage", kind="frf", effects=("time_delay", "missing_mode"), size="clear"
    )
    floor = case.answer["noise_floor_error"]
    assert floor == pytest.approx(0.015374833972864379, rel=1e-9)
    passes = []
    original = module._diagnose
    monkeypatch.setattr(
        module, "_diagnose", lambda *a, **k: passes.append(k.get("pair_first")) or original(*a, **k)
    )
    truth = {e["effect"]: e["parameters"] for e in case.answer["effects"]}
    res = diagnose(case.nominal, case.data)
    assert [f.effect for f in res.findings] == ["time_delay", "missing_mode"]
    assert passes == [None]  # no rerun (pair_first=True): the first pass took the pair
    assert res.findings[0].parameters["delay_s"] == pytest.approx(
        truth["time_delay"]["delay_s"], rel=0.01
    )
    assert res.findings[1].parameters["freq_hz"] == pytest.approx(
        truth["missing_mode"]["freq_hz"], rel=1e-4
    )
    assert res.findings[-1].error_after <= 1.1 * floor


@pytest.mark.slow
def test_frf_pair_with_crosstalk_on_the_outputs():
    # seed 4 --kinds frf --pairs, stage: a 0.1 ms input delay and crosstalk on the outputs.
    # Alone, crosstalk on the inputs explains more than on the outputs; paired with the delay
    # only the outputs' reaches the floor (an input delay commutes with crosstalk on the
    # inputs). With one crosstalk per effect the first round's pairs (the rerun's; the
    # greedy search finds the delay, then the crosstalk) missed it and took the delay with a
    # residual compliance
    from workbench.diagnosis.diagnose import _diagnose

    rng = _rng_at(149869713043763407963025794549016310842, _INC4, 0, 2030649798)
    case = make_case(
        rng, plant="stage", kind="frf", effects=("crosstalk", "time_delay"), size="clear"
    )
    floor = case.answer["noise_floor_error"]
    assert floor == pytest.approx(0.006227429914765446, rel=1e-9)
    res = diagnose(case.nominal, case.data)
    got = {f.effect: f.parameters for f in res.findings}
    assert set(got) == {"time_delay", "crosstalk"}, [f.effect for f in res.findings]
    assert got["crosstalk"]["side"] == "outputs"
    assert got["time_delay"]["delay_s"] == pytest.approx(1e-4, rel=0.01)
    assert res.findings[-1].error_after <= 1.1 * floor
    kw = dict(max_effects=3, n_full_fits=None, effects=None, delay_s=0.0, domain="auto")
    paired = _diagnose(case.nominal, case.data, pair_first=True, **kw)
    assert any("time_delay and crosstalk fitted jointly" in note for note in paired.notes)
    assert paired.findings[-1].error_after <= 1.1 * floor


#: two-effect time records (``--kinds time --effects none --pairs``, seeds 4 and 5) that the
#: greedy search got wrong: a spurious mode kept beside the mismatch that explains it
#: (pruned), a missing mode found as its image above Nyquist (a residual compliance), a
#: pair whose members alone explain little (the pair rerun), a weak mode beside a delay
#: (compare's verdict on a periodic record)
_PAIR_TIME_DRAWS = {
    "seed4_stage_mismatch_delay": (
        ("stage", ("modal_mismatch", "time_delay")),
        (54722828464776923628636583529860452628, _INC4, 0, 2134741627),
        0.006954565686687103,
    ),
    "seed4_stage_lag_mode": (
        ("stage", ("actuator_dynamics", "missing_mode")),
        (289960697197256411750006281121038519585, _INC4, 0, 3881547073),
        0.004285586077943014,
    ),
    "seed4_beam_lag_mode": (
        ("beam", ("actuator_dynamics", "missing_mode")),
        (321603457612810179831644845206655104691, _INC4, 1, 1546161100),
        0.0022855056027922325,
    ),
    # drawn with --kinds frf,time: an input crosstalk's drift hides the delay's gain on the
    # record (the delay alone no large finding; a nonlinearity was named at 13.4x)
    "seed4_beam_crosstalk_delay": (
        ("beam", ("crosstalk", "time_delay")),
        (250188237734444393105731800067311870807, _INC4, 1, 1147119766),
        0.0020147322551703436,
    ),
    # drawn with --kinds frf,time --effects none --pairs, seed 11: neither member lowers the
    # error alone (the delay 0.132, the crosstalk 0.391, from 0.128), the pair reaches the
    # floor; it was rejected as a chain whose first step raises the error, 'none' at 10.9x
    "seed11_beam_crosstalk_delay": (
        ("beam", ("crosstalk", "time_delay")),
        (
            96835284730910944882184548286817629941,
            7937318808080196428804369945471644491,
            0,
            3524341431,
        ),
        0.01179138780980537,
    ),
    "seed5_beam_delay_mode": (
        ("beam", ("time_delay", "missing_mode")),
        (
            315135455965829215547644252531803017520,
            233193750087604940414945475171846202189,
            0,
            598616228,
        ),
        0.004012661399832468,
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(_PAIR_TIME_DRAWS))
def test_time_pairs_name_both_effects(name):
    (plant, effects), (state, inc, has_uint32, uinteger), floor = _PAIR_TIME_DRAWS[name]
    rng = _rng_at(state, inc, has_uint32, uinteger)
    case = make_case(rng, plant=plant, kind="time", effects=effects, size="clear")
    assert case.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    res = diagnose(case.nominal, case.data)
    got = {f.effect: f for f in res.findings}
    assert set(got) == set(effects), [f.effect for f in res.findings]
    for e in case.answer["effects"]:
        perr = param_error(e["effect"], e["parameters"], got[e["effect"]].parameters)
        assert perr is None or perr <= TOL[e["effect"]][1], (e["effect"], perr)
    assert res.findings[-1].error_after <= 1.1 * floor


_INC1 = 194290289479364712180083596243593368443
#: indepgen seed 1 ``--kinds time --effects nonlinearity --nonperiodic``: records without
#: periods, where only the residual's colour says the linear search stopped above the noise
#: (stage: 'none' at 4.23x the floor; beam: two missing modes at 1.34x)
_NONPERIODIC_DRAWS = {
    "stage_subtle_friction": (
        "stage",
        (263799596099406378933971500594887409256, _INC1, 0, 267789403),
        0.0030084064333515408,
        "coulomb_friction",
    ),
    "beam_subtle_saturation": (
        "beam",
        (96408444668004718395943044380298202474, _INC1, 0, 1061767445),
        0.008629984135195492,
        "saturation",
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(_NONPERIODIC_DRAWS))
def test_nonperiodic_records_name_the_element(name):
    plant, state, floor, element = _NONPERIODIC_DRAWS[name]
    rng = _rng_at(*state)
    case = make_case(
        rng, plant=plant, kind="time", effects=("nonlinearity",), size="subtle", periodic=False
    )
    assert case.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    res = diagnose(case.nominal, case.data)
    top = res.findings[0]
    assert top.effect == "nonlinearity", [f.effect for f in res.findings]
    assert top.parameters["element"] == element, top.parameters.get("element")
    assert res.findings[-1].error_after <= 1.1 * floor


def test_rigid_friction_leaving_a_white_residual_ends_the_element_search_without_periods(
    monkeypatch,
):
    # indepgen seed 12 with ``--kinds time --plants stage --nonperiodic``, nonlinearity clear: a
    # closed-loop stage record without periods, Coulomb friction on its rigid bodies. The
    # rigid-body friction (fitted first, event-exact) reaches the floor and leaves a white
    # residual; without periods there was no floor to stop at, and the ports' friction and
    # spring were fitted after it (43 of 49 s CPU, to lose). Now the search ends there
    state = 103971923849790510402643582501511165789
    rng = _rng_at(state, 141594020766391051164819261345714058667, 1, 271412755)
    case = make_case(
        rng, plant="stage", kind="time", effects=("nonlinearity",), size="clear", periodic=False
    )
    floor = case.answer["noise_floor_error"]
    assert floor == pytest.approx(0.002476432239679487, rel=1e-9)
    assert case.data.period is None and case.data.loop == "closed"
    import workbench.diagnosis.nonlinear as nonlinear

    fitted = []  # the hypotheses the element fits ran on (the ports', the rigid bodies')
    fit = nonlinear.fit_port_element

    def recorded(sys, *args, **kwargs):
        fitted.append(type(sys).__name__)
        return fit(sys, *args, **kwargs)

    monkeypatch.setattr(nonlinear, "fit_port_element", recorded)
    res = diagnose(case.nominal, case.data)
    (top,) = res.findings
    p = top.parameters
    assert top.effect == "nonlinearity" and p["element"] == "coulomb_friction"
    assert p["on"] == "rigid_modes" and top.error_after <= 1.01 * floor
    assert set(fitted) == {"RigidPorts"}, fitted  # the ports' elements were not fitted
    assert "without periods" in top.explanation and "0 times" not in top.explanation


@pytest.mark.slow
def test_compliance_pseudo_mode_folded_from_twice_the_sampling_rate_is_the_missing_mode():
    # indepgen seed 4 with ``--kinds time --plants stage --pairs --nonperiodic``: an actuator
    # lag (4737 Hz on every input) and a missing mode at 2043 Hz, zeta 0.026, sampled at
    # 8 kHz. The search took a residual compliance whose pseudo-mode sits at 18 043 Hz, zeta
    # 0.003: 2 fs + 2043 Hz at the same decay rate, the same sampled poles, and the floor
    # either way. The swap to the resonance in the band looked only between fs/2 and fs
    rng = _rng_at(69028543481618933853410952156791356580, _INC4, 0, 2327426023)
    case = make_case(
        rng,
        plant="stage",
        kind="time",
        effects=("actuator_dynamics", "missing_mode"),
        size="clear",
        periodic=False,
    )
    floor = case.answer["noise_floor_error"]
    assert floor == pytest.approx(0.014054964085561306, rel=1e-9)
    res = diagnose(case.nominal, case.data)
    effects = {f.effect for f in res.findings}
    assert "missing_mode" in effects and "residual_compliance" not in effects, effects
    mode = next(f for f in res.findings if f.effect == "missing_mode").parameters
    assert mode["freq_hz"] == pytest.approx(2043.33, rel=1e-3)
    assert mode["damping"] == pytest.approx(0.02634, rel=0.02)
    assert res.findings[-1].error_after <= 1.05 * floor


def test_a_chain_of_findings_falls_or_holds_only_between_findings():
    """_falls: each finding lowers the error; the second of a pair fitted as one step may
    repeat the first's error exactly, no other finding, and never the model's own."""
    from workbench.diagnosis.diagnose import _falls

    assert _falls([0.3, 0.2, 0.1])
    assert _falls([0.128, 0.0119, 0.0119], {1})  # a pair as one step
    assert not _falls([0.128, 0.0119, 0.0119])  # else a second finding that changes nothing
    assert not _falls([0.128, 0.128, 0.01], {1})  # a first finding that changes nothing
    assert not _falls([0.128, 0.132, 0.0119])  # a first finding that raises the error
    assert not _falls([0.3, 0.1, 0.2])


#: bench_diagnose_indep.py --pairs --effects none: the order its cases are drawn in
BENCH_PAIRS = [
    ("time_delay", "missing_mode"),
    ("modal_mismatch", "time_delay"),
    ("actuator_dynamics", "missing_mode"),
    ("crosstalk", "time_delay"),
    ("crosstalk", "missing_mode"),
]


def _bench_pair_case(seed: int, plant: str, kind: str, effects: tuple[str, ...]):
    """The case ``bench_diagnose_indep.py --seed SEED --effects none --pairs`` draws for
    ``plant``, ``kind`` and the pair ``effects`` (its cases drawn in order from one rng)."""
    rng = np.random.default_rng(seed)
    for p in ("stage", "beam"):
        for k in ("frf", "time"):
            for effs in [("none",)] + BENCH_PAIRS:
                case = make_case(rng, plant=p, kind=k, effects=effs, size="clear", case_id="x")
                if (p, k, effs) == (plant, kind, effects):
                    return case
    raise ValueError(f"no such case: {plant} {kind} {effects}")


def test_a_delay_beside_a_mode_whose_image_a_compliance_takes_ends_at_the_floor():
    # seed 9's stage record (5 kHz): a mode at 391 Hz and a 0.2 ms delay. A search took a
    # compliance whose pseudo-mode (5391 Hz) is the mode's image, then the delay, and the
    # mode named in the compliance's place raised the error alone (0.751 -> 0.767): the
    # compliance stayed the top finding. The two effects, at the floor
    case = _bench_pair_case(9, "stage", "time", ("time_delay", "missing_mode"))
    res = diagnose(case.nominal, case.data)
    assert sorted(f.effect for f in res.findings) == ["missing_mode", "time_delay"], res.findings
    truth = {e["effect"]: e["parameters"] for e in case.answer["effects"]}
    mode = next(f for f in res.findings if f.effect == "missing_mode").parameters
    assert abs(mode["freq_hz"] / truth["missing_mode"]["freq_hz"] - 1) < 1e-3
    assert abs(mode["damping"] / truth["missing_mode"]["damping"] - 1) < 0.05
    delay = next(f for f in res.findings if f.effect == "time_delay").parameters
    assert abs(delay["delay_s"] / truth["time_delay"]["delay_s"] - 1) < 0.01
    assert res.findings[-1].error_after < 1.05 * case.answer["noise_floor_error"]


def test_a_resolved_pseudo_mode_above_the_band_is_the_missing_mode():
    # a delay and a mode at 1785 Hz, above the excited band and below Nyquist (5 kHz): the
    # search took a residual compliance whose pseudo-mode was that mode (1784.9 Hz, zeta
    # 0.0167 for 0.0164), resolved by the record; named as the mode, as a missing mode
    # fitted there is
    case = make_case(
        np.random.default_rng(15),
        plant="stage",
        kind="time",
        effects=("time_delay", "missing_mode"),
        case_id="x",
    )
    truth = {e["effect"]: e["parameters"] for e in case.answer["effects"]}
    assert truth["missing_mode"]["freq_hz"] == pytest.approx(1785.120406469898, rel=1e-9)
    floor = case.answer["noise_floor_error"]
    res = diagnose(case.nominal, case.data)
    got = {f.effect: f for f in res.findings}
    assert set(got) == {"time_delay", "missing_mode"}, [f.effect for f in res.findings]
    for effect, params in truth.items():
        perr = param_error(effect, params, got[effect].parameters)
        assert perr is None or perr <= TOL[effect][1], (effect, perr)
    mode = got["missing_mode"].parameters
    assert abs(mode["freq_hz"] - truth["missing_mode"]["freq_hz"]) < 1.0
    assert "above the excited band" in got["missing_mode"].explanation
    assert abs(mode["damping"] / truth["missing_mode"]["damping"] - 1) < 0.05
    assert res.findings[-1].error_after <= 1.1 * floor


#: indepgen beam records whose cubic spring drives the response into motion that does not
#: repeat (seeds 7 and 5 of ``bench_diagnose_indep.py --kinds time --effects nonlinearity``,
#: clear). The generator's PCG64 state before each case, its noise floor and the spring's level
#: as drawn, and the evidence the finding rests on. Before, a linear finding was named: a modal
#: mismatch 34 -> 88 Hz, damping 0.11, that lowered the error from 11.3 to 10.5x the floor
#: (seed 7); 61 -> 69.7 Hz and two missing modes at 7.9x (seed 5).
#: - seed 7: the periods' spread 11x its estimate as white noise, the unexcited lines carrying
#:   nothing periodic (F 0.82): the spread is the evidence (``periods_repeat`` false). The
#:   generator's own record does not converge in its substeps (it moves by 10.5x its noise at
#:   every doubling up to 512: ``reproducible`` false), no model follows it to the floor;
#: - seed 5: its record converged (256 substeps; at the generator's former 8 it was 6.6x its
#:   noise off): the spread 6.5x the white estimate, and periodic power on the unexcited lines
#:   (F 4.4): distortion is the evidence, the explanation says the periods do not repeat
_UNREPEATED_DRAWS = {
    "seed7_clear": (
        (78160016201581203427584606035063847414, 261136684632268670825940853076396136793, 0),
        3786980749,
        0.010344675067403967,
        0.014198245956878236,
        "spread",
    ),
    "seed5_clear": (
        (267610781656190528298011472229736068247, 233193750087604940414945475171846202189, 0),
        3374538477,
        0.0023786439614620625,
        0.0023636054584132266,
        "distortion",
    ),
}


@pytest.mark.parametrize(
    "name",
    [
        "seed7_clear",
        pytest.param("seed5_clear", marks=pytest.mark.slow),  # 60 s
    ],
)
def test_a_beam_response_that_does_not_repeat_is_a_nonlinearity(name):
    (state, inc, has_uint32), uinteger, floor, level, evidence = _UNREPEATED_DRAWS[name]
    rng = _rng_at(state, inc, has_uint32, uinteger)
    case = make_case(rng, plant="beam", kind="time", effects=("nonlinearity",), size="clear")
    assert case.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    truth = case.answer["effects"][0]["parameters"]
    assert truth["type"] == "cubic" and truth["level"] == pytest.approx(level, rel=1e-9)
    assert truth["reproducible"] is (evidence == "distortion")
    res = diagnose(case.nominal, case.data)
    top = res.findings[0]
    assert top.effect == "nonlinearity", [f.effect for f in res.findings]
    if evidence == "spread":
        assert top.parameters["periods_repeat"] is False
    else:
        assert top.parameters["f_stat"] > 4.0 and "periods_repeat" not in top.parameters
    # said to the user: in the finding, or (seed 5 since the model's own suspension is a
    # candidate, SuspensionSprings: the search then names the cubic spring itself, level
    # 0.0025 for the drawn 0.0024, where it had named 0.00024 beside three linear findings,
    # its linearization) in the notes the CLI prints
    told = [top.explanation, *res.notes]
    assert any("periods do not repeat" in t for t in told), told
    # what does not repeat is a part of what the spring adds (the generator's level, the
    # spring's whole share of the output power): 0.94 of it on seed 7, 0.1 on seed 5
    assert 0.05 * level < top.parameters["level"] <= 1.2 * level


def _one_finding(draw: tuple, floor: float, **case):
    """(case, its one finding): the indepgen case at a recorded PCG64 ``draw`` (state, inc,
    has_uint32, uinteger; ``case`` make_case's keywords), checked to be the one drawn by
    its noise floor, diagnosed."""
    c = make_case(_rng_at(*draw), **case)
    assert c.answer["noise_floor_error"] == pytest.approx(floor, rel=1e-9)
    (top,) = diagnose(c.nominal, c.data).findings
    return c, top


def test_a_linear_record_whose_transient_rings_through_every_period_is_searched():
    # indepgen seed 6 with ``--effects suspension_stiffness,crosstalk,none``, beam, time,
    # crosstalk clear: an open-loop periodic record from rest, input crosstalk 0.12. The
    # suspension's transient rings through all five periods (their spread 5.6x its white
    # estimate), so the period-synchronous misfit came out below PERIODIC_F against that
    # spread, the search stopped before its first round, and the record was named a
    # nonlinearity at 10.2x the floor. The spread is no noise reference there: searched, the
    # crosstalk fits to the floor.
    draw = (
        253861021359029665752462506301666546232,
        48033170148846378449264849981880743275,
        1,
        3605136091,
    )
    floor = 0.008848906140376015
    case, top = _one_finding(
        draw, floor, plant="beam", kind="time", effects=("crosstalk",), size="clear"
    )
    assert case.data.period and case.data.loop == "open"
    assert top.effect == "crosstalk" and top.parameters["side"] == "inputs"
    assert top.error_after <= 1.05 * floor


def test_a_suspension_far_below_the_lowest_excited_line_is_found_not_a_spring():
    # indepgen seed 14 (all effects), stage, time, suspension subtle: a closed-loop record
    # whose multisine starts at 40 Hz, the stage suspended at 1.22 Hz (damping 0.077). The
    # suspension's grid started at a tenth of the band (4 Hz), where every point cost more
    # than no suspension: the structure was not among the five fitted, and a cubic spring
    # at two ports was named at 2.6x the floor (85 s). Screened down to a hundredth of the
    # band, it is fitted, to the floor.
    draw = (
        142769400245411378071398269362186294033,
        210602798688404222029095236965608334861,
        0,
        399614559,
    )
    floor = 0.0030012367065901644
    case, top = _one_finding(
        draw, floor, plant="stage", kind="time", effects=("suspension_stiffness",), size="subtle"
    )
    assert case.data.loop == "closed" and case.data.period
    truth = case.answer["effects"][0]["parameters"]
    assert top.effect == "suspension_stiffness"
    assert top.parameters["freq_hz"] == pytest.approx(truth["freq_hz"], rel=0.01)
    assert top.error_after <= 1.02 * floor


def test_a_mode_below_the_lowest_excited_line_is_found_on_the_record():
    # indepgen seed 15 (all effects), beam, time, missing mode subtle: an open-loop record
    # from rest, its multisine from 28.7 Hz, the nominal without a mode at 22.7 Hz (damping
    # 0.0053). The missing mode's grid started at the band's lowest line, and a compliance
    # whose pseudo-mode above Nyquist (4118 Hz at fs 4096) imitated the mode was named at
    # 1.64x the floor. Screened below the band too, within its bounds: the mode itself.
    draw = (
        236111878897160235865746703450165751019,
        168635386100685449938534718985723470245,
        1,
        1480309174,
    )
    floor = 0.004948606009313975
    case, top = _one_finding(
        draw, floor, plant="beam", kind="time", effects=("missing_mode",), size="subtle"
    )
    truth = case.answer["effects"][0]["parameters"]
    assert top.effect == "missing_mode"
    assert top.parameters["freq_hz"] == pytest.approx(truth["freq_hz"], rel=1e-3)
    assert top.parameters["damping"] == pytest.approx(truth["damping"], rel=0.1)
    assert top.error_after <= 1.02 * floor


def test_a_hardening_mode_near_its_jumps_is_fitted_to_the_floor():
    # indepgen seed 17 (all effects), beam, time, nonlinearity clear: a cubic spring on the
    # first flexible mode (47.9 Hz), 30 % of its stiffness at the rms motion. The error is
    # rough in the level at a fraction of a per cent (the mode near its jumps): scanned from
    # a unit guessed off the linear model's motion, with a bounded search 0.5 % wide, the
    # spring was left at 6.3x the floor. Regressed on the mode's coordinate as the record
    # shows it and refined on a grid of 0.25 %: the level the generator measured, 1.00x.
    draw = (
        86874961184101985556823856436085018088,
        78856291631749604729656725519709880197,
        1,
        3061134910,
    )
    floor = 0.0036759727006682756
    case, top = _one_finding(
        draw, floor, plant="beam", kind="time", effects=("nonlinearity",), size="clear"
    )
    truth = case.answer["effects"][0]["parameters"]
    assert truth["type"] == "cubic" and truth["reproducible"]
    assert top.effect == "nonlinearity" and top.parameters["element"] == "cubic_stiffness"
    assert top.parameters["level"] == pytest.approx(truth["level"], rel=0.02)
    assert top.error_after / floor <= 1.1


def test_a_common_lag_far_above_nyquist_is_a_lag_not_a_delay():
    # indepgen seed 27 (all effects), stage, FRF, actuator lag subtle: one cutoff on all six
    # inputs, 208 kHz on a 5 kHz grid (83x the band's top). A delay of 0.77 us, the per-input
    # lags and the per-output lags all reach the floor within 0.02 % of one another; the
    # per-channel lags fit best (a log-likelihood 17 above the delay's) but with 5 more
    # parameters, and BIC named the delay. The one-cutoff lag has the delay's one parameter:
    # the likelihood decides, and the explanation says how close the delay comes
    draw = (
        151075291297394272997708195736272854871,
        218250142745413522186470865394637724367,
        0,
        3924236871,
    )
    floor = 0.002039811575461325
    case, top = _one_finding(
        draw, floor, plant="stage", kind="frf", effects=("actuator_dynamics",), size="subtle"
    )
    truth = case.answer["effects"][0]["parameters"]["cutoff_hz"]
    assert len(set(truth)) == 1
    assert top.effect == "actuator_dynamics"
    cut = top.parameters["cutoff_hz"]
    assert len(set(cut)) == 1 and cut[0] == pytest.approx(truth[0], rel=0.05)
    assert top.parameters["common"] is True
    assert top.error_after / floor <= 1.01
    assert "time_delay fits nearly as closely" in top.explanation
    assert "one lag on every input is the same factor on the response" in top.explanation


def test_a_suspension_below_the_band_that_the_record_resolves_is_the_number():
    # indepgen seed 27 (all effects), beam, time, suspension clear: springs at 1.1227 and
    # 4.599 Hz, the band from 12 Hz. Both fitted to the floor, the lower to 5e-6 of itself
    # by the record's transient, yet reported "not resolved" (below a tenth of the band's
    # lowest line) and the number was 4.6 Hz, 310 % off
    draw = (
        70173315857184512288361299126444991311,
        218250142745413522186470865394637724367,
        0,
        3593373653,
    )
    floor = 0.007155974374453383
    case, top = _one_finding(
        draw, floor, plant="beam", kind="time", effects=("suspension_stiffness",), size="clear"
    )
    truth = case.answer["effects"][0]["parameters"]
    assert top.effect == "suspension_stiffness"
    assert top.parameters["freq_hz"] == pytest.approx(truth["freq_hz"], rel=0.01)
    assert all(m.get("resolved", True) for m in top.parameters["modes"])
    assert top.error_after / floor <= 1.01


def test_output_lags_far_above_nyquist_are_fitted_beside_the_input_lags():
    # indepgen seed 23 (all effects), stage, closed-loop time record, sensor lag subtle:
    # every output lagged at 41-67 kHz, 8-13x Nyquist. The screen kept the input lags among
    # its five best and not the output lags: named actuator_dynamics at 1.013x the floor, the
    # output lags never fitted. Fitted beside them they reach the floor at their cutoffs
    draw = (
        107272756986874671427419851019304027705,
        18438579778062455872196599375400725907,
        1,
        226327536,
    )
    floor = 0.0027069529595340172
    case, top = _one_finding(
        draw, floor, plant="stage", kind="time", effects=("sensor_dynamics",), size="subtle"
    )
    truth = case.answer["effects"][0]["parameters"]["cutoff_hz"]
    assert top.effect == "sensor_dynamics"
    np.testing.assert_allclose(top.parameters["cutoff_hz"], truth, rtol=0.05)
    assert top.error_after / floor <= 1.01


def test_lags_on_some_inputs_near_the_band_top_are_fitted_whatever_the_screen():
    # indepgen seed 31 (all effects), stage, closed-loop time record, actuator lag subtle:
    # inputs 0, 4 and 5 lagged at 2.2-2.8 kHz. The screen kept no lag among its five best,
    # and a missing mode beside the model's own 1383 Hz mode and a compliance were named at
    # the floor, 12 parameters. The lags, fitted, reach it with three
    draw = (
        330453924657359937959430860810404309609,
        107090353359002252723118071224206516545,
        1,
        1753633131,
    )
    floor = 0.019103783107235702
    case, top = _one_finding(
        draw, floor, plant="stage", kind="time", effects=("actuator_dynamics",), size="subtle"
    )
    truth = case.answer["effects"][0]["parameters"]["cutoff_hz"]
    assert top.effect == "actuator_dynamics"
    got = top.parameters["cutoff_hz"]
    assert [c is None for c in got] == [c is None for c in truth]
    np.testing.assert_allclose(
        [c for c in got if c is not None], [c for c in truth if c is not None], rtol=0.05
    )
    assert top.error_after / floor <= 1.01


def test_two_truncated_modes_near_the_band_top_are_one_compliance_at_the_floor():
    # indepgen seed 38 (all effects), stage, FRF, residual compliance clear: modes at 4944
    # and 6446 Hz (1.24x and 1.61x the 4 kHz grid's top), each on its own channels. One
    # pseudo-mode (at 4622 Hz) left 2.87x the noise floor and compare failing above 1.2 kHz
    # on 36 channels; the two-pole upper residual, refined from it, reaches the floor with
    # its poles at the truncated modes
    draw = (
        333094746469029822103299559446938807603,
        83116957542241617309460614540412402693,
        1,
        2499597333,
    )
    floor = 0.004039046598932557
    case, top = _one_finding(
        draw, floor, plant="stage", kind="frf", effects=("residual_compliance",), size="clear"
    )
    truth = case.answer["effects"][0]["parameters"]
    assert top.effect == "residual_compliance"
    assert top.error_after / floor <= 1.05
    found = sorted(top.parameters["upper_freq_hz"])
    assert found == pytest.approx(sorted(m["freq_hz"] for m in truth["modes"]), rel=0.01)
    R, Rt = np.asarray(top.parameters["matrix"]), np.asarray(truth["matrix"])
    assert np.linalg.norm(R - Rt) <= 0.3 * np.linalg.norm(Rt)
