"""Time records that do not start at rest (workbench.diagnosis.problem.TimeProblem).

Oracle: the record is cut from a longer ZOH simulation (scipy.signal.dlsim of the
exactly sampled state space, started at rest), so its first sample is mid-motion;
the true model compared from its estimated start must then show only the noise,
while from rest it drifts (a rigid body with an unknown initial velocity).
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.signal

from workbench.diagnosis.diagnose import base_model
from workbench.diagnosis.problem import TimeProblem, moving_start
from workbench.io.formats import TimeData

FS = 1000.0


def plant():
    """2 x 2: a rigid body (2 kg) and a 60 Hz / 2 % mode, continuous state space."""
    w, z = 2 * np.pi * 60.0, 0.02
    A = np.zeros((4, 4))
    A[0, 1] = 1.0
    A[2, 3] = 1.0
    A[3, 2], A[3, 3] = -(w**2), -2 * z * w
    B = np.array([[0, 0], [0.5, 0.5], [0, 0], [1.0, -1.0]])
    C = np.array([[1.0, 0, 0.3, 0], [1.0, 0, -0.2, 0]])
    return control.ss(A, B, C, np.zeros((2, 2)))


def record(n_skip: int, n: int = 4000, noise: float = 0.01, seed: int = 0, delay: int = 0):
    rng = np.random.default_rng(seed)
    sys = plant()
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((sys.A, sys.B, sys.C, sys.D), 1 / FS)
    u = rng.standard_normal((n_skip + n, 2))
    # a rigid body needs a loop to stay bounded: a 5 Hz PD on its position and velocity,
    # the same force on both inputs (the mode, driven by F1 - F2, is left to ring)
    x = np.zeros(4)
    y = np.zeros((n_skip + n, 2))
    kp, kd = (2 * np.pi * 5.0) ** 2, 2 * 0.7 * 2 * np.pi * 5.0
    for k in range(n_skip + n):
        y[k] = Cd @ x
        u[k] -= kp * x[0] + kd * x[1]
        x = Ad @ x + Bd @ u[k - delay] * (k >= delay)  # the plant sees u ``delay`` samples late
    y = y[n_skip:]
    y = y + noise * np.std(y, axis=0) * rng.standard_normal(y.shape)
    return TimeData(FS, u[n_skip:], y, input_names=("F1", "F2"), output_names=("y1", "y2")), sys


def test_a_record_cut_mid_motion_is_recognized_and_one_at_rest_is_not():
    moving, _ = record(n_skip=3000)
    rest, _ = record(n_skip=0)
    assert moving_start(moving)
    assert not moving_start(rest)


def test_a_record_cut_as_the_body_passes_near_zero_at_speed_is_recognized():
    """Its first samples are a few % of the rms (under any rms-fraction bound) but many
    noise standard deviations: at rest they would be noise. Cut at sample 2037 of the
    same loop, where both outputs are within 8 % of their rms and moving."""
    data, sys = record(n_skip=2037, noise=0.01)
    rms = np.sqrt(np.mean(data.y**2, axis=0))
    assert np.all(np.abs(data.y[0]) < 0.08 * rms)
    assert moving_start(data)
    base = base_model(sys, data)
    assert TimeProblem(data).error(base) < 0.02  # 1 % noise on each output


def test_the_true_model_from_its_estimated_start_shows_only_the_noise():
    data, sys = record(n_skip=3000, noise=0.01)
    base = base_model(sys, data)
    from_rest = TimeProblem(data, transient=False).error(base)
    estimated = TimeProblem(data).error(base)
    assert estimated < 0.02  # 1 % noise on each output
    assert from_rest > 10 * estimated


def test_at_rest_the_problem_is_unchanged():
    data, sys = record(n_skip=0, noise=0.01)
    base = base_model(sys, data)
    auto = TimeProblem(data)
    assert auto.transient is False
    np.testing.assert_array_equal(
        auto.residual(base), TimeProblem(data, transient=False).residual(base)
    )
    assert auto.error(base) == pytest.approx(0.01, rel=0.3)


def test_augment_finds_a_delay_on_a_record_cut_mid_motion():
    """The true plant lags by 2 samples (2 ms); the model has no delay. From the estimated
    start augment recovers the delay and the error falls to the noise; both errors are
    reported from the estimated start (the note says so)."""
    from workbench.diagnosis.augment import augment

    data, sys = record(n_skip=3000, noise=0.01, delay=2)
    assert moving_start(data)
    out = augment(sys, data, "time_delay")
    assert out.parameters["delay_s"] == pytest.approx(0.002, abs=2e-5)
    assert out.error_after < 0.02 < out.error_before
    assert "does not start at rest" in out.note


def test_orthonormal_columns_span_the_same_space_as_householder_qr():
    from workbench.diagnosis.problem import _orthonormal_columns

    rng = np.random.default_rng(3)
    k = np.arange(8000, dtype=float)
    cols = [np.ones_like(k), k / k[-1]]
    for f, z in [(0.5, 0.05), (40.0, 0.02), (900.0, 0.01)]:
        s, wd = -z * 2 * np.pi * f / 5000, 2 * np.pi * f * np.sqrt(1 - z * z) / 5000
        cols += [np.exp(s * k) * np.cos(wd * k), np.exp(s * k) * np.sin(wd * k)]
    X = rng.standard_normal((k.size, 3))
    for B in (np.column_stack(cols), np.column_stack(cols + [cols[0] + 1e-14 * cols[1]])):
        Q = _orthonormal_columns(B)
        Qr, R = np.linalg.qr(B)
        Qr = Qr[:, np.abs(np.diag(R)) > 1e-10 * np.abs(np.diag(R)).max()]
        assert Q.shape == Qr.shape
        assert np.abs(Q.T @ Q - np.eye(Q.shape[1])).max() < 1e-12
        assert np.abs((X - Q @ (Q.T @ X)) - (X - Qr @ (Qr.T @ X))).max() < 1e-10


def test_a_moved_or_added_mode_extends_the_kept_time_basis():
    """The time record's start basis of a model whose mode moved or was added, extended
    from the kept basis of the other modes (:meth:`TimeProblem._basis_near`), projects as
    the basis of all its free responses by Householder QR does; only the first model's
    and (moved in the same place twice) the other modes' are computed afresh."""
    from dataclasses import replace

    from workbench.modal.model import Mode

    data, sys = record(n_skip=3000)
    problem = TimeProblem(data)
    base = base_model(sys, data)
    extra = Mode("flexible", 31.0, 0.02, np.zeros(2), np.zeros(2))
    base = replace(base, modes=base.modes + (extra,))
    k = len(base.modes) - 1
    fresh = []
    problem._basis_of = lambda key, f=problem._basis_of: fresh.append(key) or f(key)
    models = [base]
    for j in range(1, 4):
        modes = list(base.modes)
        modes[k] = modes[k].moved(31.0 * (1 + 0.03 * j), 0.02)
        models.append(replace(base, modes=tuple(modes)))
    added = Mode("flexible", 55.0, 0.01, np.zeros(2), np.zeros(2))
    models.append(replace(models[-1], modes=models[-1].modes + (added,)))
    t = np.arange(data.y.shape[0], dtype=float)
    X = np.random.default_rng(1).standard_normal((t.size, 3))
    for m in models:
        Q = problem._start_basis(m)
        cols = [np.ones_like(t), t]
        for mode in m.modes:
            if mode.freq_hz > 0:  # the sampled pole's powers, complex
                w, z = mode.omega / FS, mode.damping
                lam = np.exp(complex(-z * w, w * np.sqrt(1 - z * z)))
                cols += [(lam**t).real, (lam**t).imag]
        Qr = np.linalg.qr(np.column_stack(cols))[0]
        assert Q.shape == Qr.shape
        assert np.abs((X - Q @ (Q.T @ X)) - (X - Qr @ (Qr.T @ X))).max() < 1e-10
    assert len(fresh) == 2
    assert fresh[1] == (0, tuple((m.freq_hz, m.damping) for m in base.modes[:k] if m.freq_hz > 0))


def test_free_response_columns_are_the_sampled_poles_powers():
    """TimeProblem._pole_columns (tables of powers multiplied) against exp, cos and sin of
    every sample; a pole gone within a sample has none."""
    data, _ = record(n_skip=3000, n=4001)  # not a multiple of the tables' block
    problem = TimeProblem(data)
    poles = [(31.0, 0.02), (0.3, 0.9), (450.0, 0.001), (1200.0, 0.999)]  # the last: gone
    C = problem._pole_columns(poles)
    k = np.arange(data.y.shape[0], dtype=float)
    ref = []
    for f, z in poles[:3]:
        w = 2 * np.pi * f / FS
        env = np.exp(-z * w * k)
        ref += [env * np.cos(w * np.sqrt(1 - z * z) * k), env * np.sin(w * np.sqrt(1 - z * z) * k)]
    assert C.shape == (k.size, 6)
    assert np.abs(C - np.column_stack(ref)).max() < 1e-12


def test_a_growing_free_response_is_counted_back_from_the_last_sample():
    """A trial point's negative damping: lambda^n overflowed over 16 384 samples (NaN in the
    basis, RuntimeWarnings on the user's terminal); its column is lambda^(n - N + 1), the
    same span, finite, largest at the end."""
    data, _ = record(n_skip=3000, n=16384)
    problem = TimeProblem(data)
    f, z = 40.0, -0.05
    with np.errstate(all="raise"):
        C = problem._pole_columns([(f, z)])
    N = data.y.shape[0]
    w = 2 * np.pi * f / FS
    lam = np.exp(complex(-z * w, w * np.sqrt(1 - z * z)))
    ref = lam ** (np.arange(N) - (N - 1.0))
    assert np.all(np.isfinite(C))
    assert np.abs(C[:, 0] - ref.real).max() < 1e-9
    assert np.abs(C[:, 1] - ref.imag).max() < 1e-9
