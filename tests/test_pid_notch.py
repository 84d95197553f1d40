"""controllers.pid_notch: the automatic baseline tuner, checked by independent loop computations."""

from __future__ import annotations

import warnings

import control
import numpy as np
import pytest
import scipy.signal

from controllers import Controller, tune_pid
from controllers.pid_notch import detect_modes, tune_pid_notch
from workbench.core.errors import InputError
from workbench.core.lti import frf
from workbench.io.formats import FrfData
from workbench.loop import analyze_loop

FS = 5000.0
MASS = 10.0
F_MODE = 600.0


def _plant():
    """Rigid mass and one lightly damped in-phase flexible mode at 600 Hz (m/N)."""
    wm = 2 * np.pi * F_MODE
    return control.ss(
        control.tf([1.0], [MASS, 0, 0]) + control.tf([0.3 / MASS], [1, 2 * 0.005 * wm, wm**2])
    )


def _dense_s_and_poles(P, K, delay: int):
    """|S|inf on a dense grid and the closed-loop pole radius, by python-control alone."""
    Pd = control.c2d(P, 1 / FS, "zoh")
    z = control.ss(control.tf([1], [1] + [0] * delay, 1 / FS))
    L = Pd * z * K.statespace()
    cl = control.feedback(control.ss([], [], [], [[1.0]], 1 / FS), L)
    w = np.linspace(1e-2, np.pi * FS * 0.9999, 100001)
    s_inf = float(np.max(np.abs(cl.frequency_response(w).complex.ravel())))
    return s_inf, float(np.max(np.abs(control.feedback(L, 1).poles())))


@pytest.fixture(scope="module")
def tuned():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tune_pid_notch(_plant(), FS, loop_delay_samples=1)


def test_tuner_meets_bound_and_beats_hand_design(tuned):
    K, rep = tuned
    assert isinstance(K, Controller) and K.n_u == 1 and K.n_y == 1
    s_inf, radius = _dense_s_and_poles(_plant(), K, 1)
    assert s_inf <= 2.0 * 1.01
    assert radius < 1
    # the design sits on the bound (the search pushed fc up to it)
    assert s_inf >= 2.0 * 0.97
    # a fixed hand-tuned design: lead 4, low-pass 8 fc, notch at the mode, fc = 60 Hz
    hand = tune_pid(
        MASS, crossover_hz=60.0, fs=FS, lead_ratio=4.0, lowpass_ratio=8.0,
        notch_hz=np.array([F_MODE]), delay_samples=0,
    )  # fmt: skip
    s_hand, r_hand = _dense_s_and_poles(_plant(), hand, 1)
    assert s_hand <= 2.0 and r_hand < 1  # a fair comparison: the hand design is admissible
    fc_hand = analyze_loop(_plant(), hand, loop_delay_samples=1).loops[0].crossover_hz
    assert rep.crossover_hz[0] > 1.2 * fc_hand
    # the report's crossover is the loop's
    assert rep.analysis.loops[0].crossover_hz == pytest.approx(rep.crossover_hz[0], rel=0.01)
    assert rep.notch_hz[0] and abs(rep.notch_hz[0][0] / F_MODE - 1) < 0.01


def test_notch_matters_on_this_plant(tuned):
    _K, rep = tuned
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _K0, rep0 = tune_pid_notch(_plant(), FS, loop_delay_samples=1, notch_hz=[()])
    assert rep0.notch_hz == ((),)
    assert rep.crossover_hz[0] > 1.2 * rep0.crossover_hz[0]


def test_frf_data_gives_same_crossover(tuned):
    _K, rep = tuned
    f = np.linspace(0.5, FS / 2 * 0.999, 6000)
    data = FrfData(freq=f, G=frf(_plant(), f))
    Kf, repf = tune_pid_notch(data, FS, loop_delay_samples=1)
    assert repf.crossover_hz[0] == pytest.approx(rep.crossover_hz[0], rel=0.02)
    assert repf.analysis.source == "frf" and repf.analysis.stable
    s_inf, radius = _dense_s_and_poles(_plant(), Kf, 1)
    assert s_inf <= 2.0 * 1.03 and radius < 1


def test_controller_matrices_are_the_tustin_design(tuned):
    K, _rep = tuned
    ch = K.channels[0]
    num, den = ch.transfer_function(fs=FS)  # pre-warped continuous design
    numd, dend = scipy.signal.bilinear(num, den, fs=FS)
    f = np.logspace(0, np.log10(2400), 300)
    _w, h = scipy.signal.freqz(numd, dend, worN=f, fs=FS)
    got = frf(K.statespace(), f)[:, 0, 0]
    assert np.max(np.abs(got / h - 1)) < 1e-6
    # step() is the state space
    rng = np.random.default_rng(0)
    e = rng.standard_normal(200)
    st, u = K.init(), []
    for ek in e:
        uk, st = K.step(st, np.array([ek]))
        u.append(uk[0])
    ref = control.forced_response(K.statespace(), U=e).outputs
    assert np.max(np.abs(np.array(u) - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_detect_modes():
    f = np.logspace(0, np.log10(2400), 3000)
    assert detect_modes(f, frf(_plant(), f)[:, 0, 0]) == pytest.approx((F_MODE,), rel=0.01)
    assert detect_modes(f, 1 / (MASS * (2j * np.pi * f) ** 2)) == ()


def test_infeasible_bound_and_non_square():
    with pytest.raises(InputError, match="meets"):
        tune_pid_notch(_plant(), FS, ms_max=1.05, loop_delay_samples=1)
    P2 = control.ss(np.zeros((2, 2)) + np.eye(2, k=1), [[0, 0], [1, 1]], [[1, 0]], [[0, 0]])
    with pytest.raises(InputError, match="square"):
        tune_pid_notch(P2, FS)


def _coupled_plant():
    """Two DOFs of MASS kg sharing one 900 Hz mode (b = [1, 0.7] sqrt(0.03)): a coupled 2x2."""
    wm, z = 2 * np.pi * 900.0, 0.01
    b = np.array([1.0, 0.7]) * np.sqrt(0.3 / MASS)
    A = np.zeros((6, 6))
    A[0:2, 2:4] = np.eye(2)
    A[4, 5], A[5, 4], A[5, 5] = 1.0, -(wm**2), -2 * z * wm
    B = np.zeros((6, 2))
    B[2:4] = np.eye(2) / MASS
    B[5] = b
    C = np.zeros((2, 6))
    C[:, 0:2] = np.eye(2)
    C[:, 4] = b
    return control.ss(A, B, C, np.zeros((2, 2)))


def _mimo_sii_peaks(P, K, delay: int):
    """max_w |S_ii| with every loop closed, and the pole radius, by python-control alone."""
    Pd = control.c2d(P, 1 / FS, "zoh")
    z = control.ss(control.tf([1], [1] + [0] * delay, 1 / FS))
    L = Pd * control.append(z, z) * K.statespace()
    S = control.feedback(control.ss([], [], [], np.eye(2), 1 / FS), L)
    w = np.linspace(1e-2, np.pi * FS * 0.9999, 20001)
    resp = S.frequency_response(w).complex  # (2, 2, n_w)
    peaks = [float(np.max(np.abs(resp[i, i]))) for i in range(2)]
    return peaks, float(np.max(np.abs(control.feedback(L, np.eye(2)).poles())))


def test_mimo_pass_keeps_loop_at_a_time_sensitivity():
    P = _coupled_plant()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        K0, _r0 = tune_pid_notch(P, FS, loop_delay_samples=1, notch_hz=[(), ()], mimo_iterations=0)
        K, rep = tune_pid_notch(P, FS, loop_delay_samples=1, notch_hz=[(), ()])
    peaks0, _ = _mimo_sii_peaks(P, K0, 1)
    peaks, radius = _mimo_sii_peaks(P, K, 1)
    assert max(peaks0) > 2.5  # the diagonal-only design breaks the bound through the coupling
    assert max(peaks) <= 2.0 * 1.01 and radius < 1
    assert [lp.s_peak for lp in rep.analysis.loops] == pytest.approx(peaks, rel=0.01)
