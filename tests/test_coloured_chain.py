"""When diagnose reruns its search with pairs on a record without periods.

Such a record gives compare no noise reference, so the rerun's usual trigger (compare
says the greedy result is above the noise) never fires. There, two or more linear
findings that leave a residual that is not white (Ljung-Box) call for the pairs: the
greedy search split a pair. The cases are built from a mass-spring-damper's exact ZOH
response, the residual's colour set by what is added to the record.
"""

from __future__ import annotations

import sys

import control
import numpy as np

from workbench.diagnosis import Finding
from workbench.diagnosis.modal import decompose
from workbench.io.formats import TimeData
from workbench.sim import simulate_zoh

FS = 1000.0
N = 8192

#: 1 kg on 4e4 N/m (31.8 Hz), 2 % damping
MODEL = control.ss([[0.0, 1.0], [-4e4, -2 * 0.02 * 200.0]], [[0.0], [1.0]], [[1.0, 0.0]], 0.0)
#: a 150 Hz resonance the model lacks: its response is coloured
EXTRA = control.ss(
    [[0.0, 1.0], [-((2 * np.pi * 150) ** 2), -2 * 0.01 * 2 * np.pi * 150]],
    [[0.0], [1.0]],
    [[1.0, 0.0]],
    0.0,
)


def _coloured_chain():
    return sys.modules["workbench.diagnosis.diagnose"]._coloured_chain


def _record(extra: float, period=None) -> TimeData:
    rng = np.random.default_rng(7)
    u = rng.standard_normal((N, 1))
    y = simulate_zoh(MODEL, u, FS)
    y = y + extra * simulate_zoh(EXTRA, u, FS) + 1e-7 * rng.standard_normal(y.shape)
    return TimeData(fs=FS, u=u, y=y, period=period)


def _findings(n: int, effect: str = "missing_mode") -> list[Finding]:
    model = decompose(MODEL)
    return [
        Finding(effect, (0,), (0,), (1.0, 400.0), {}, {}, 1.0, "", model=model) for _ in range(n)
    ]


class _Result:
    def __init__(self, findings):
        self.findings = findings


def test_two_findings_that_leave_a_coloured_residual_call_for_the_pairs():
    assert _coloured_chain()(_Result(_findings(2)), _record(extra=1.0))


def test_a_white_residual_does_not():
    assert not _coloured_chain()(_Result(_findings(2)), _record(extra=0.0))


def test_one_finding_a_periodic_record_or_an_element_does_not():
    data = _record(extra=1.0)
    assert not _coloured_chain()(_Result(_findings(1)), data)
    assert not _coloured_chain()(_Result(_findings(2)), _record(extra=1.0, period=1024))
    chain = _findings(1) + _findings(1, effect="nonlinearity")
    assert not _coloured_chain()(_Result(chain), data)
