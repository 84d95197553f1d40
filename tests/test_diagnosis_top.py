"""``Diagnosis.top``: the first finding, or an 'unexplained' stand-in when there is none."""

from __future__ import annotations

from workbench.diagnosis.diagnose import Diagnosis, Finding


def _finding(effect: str, err: float) -> Finding:
    return Finding(effect, (0,), (0,), (1.0, 10.0), {}, {}, err, "why")


def test_top_is_the_first_finding():
    d = Diagnosis(error_before=0.5, findings=(_finding("time_delay", 0.1), _finding("none", 0.1)))
    assert d.top is d.findings[0]


def test_no_finding_gives_an_unexplained_stand_in_at_the_error_before():
    remaining = {"within_noise": False, "explanation": "compare still fails in 3 band(s)"}
    d = Diagnosis(error_before=0.5, findings=(), remaining=remaining)
    assert d.top.effect == "unexplained"
    assert d.top.error_after == 0.5
    assert d.top.explanation == remaining["explanation"]
    assert d.findings == ()  # the stand-in is not a finding
