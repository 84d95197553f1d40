import control
import numpy as np
import pytest

from controllers.mpc import LinearMPC
from workbench.core.errors import InputError


def _plant(fs=5000.0):
    """Mass 1 kg + flexible mode 300 Hz (zeta 0.02), force input, discrete ZOH."""
    w = 2 * np.pi * 300
    A = np.array([[0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1], [0, 0, -(w**2), -2 * 0.02 * w]])
    B = np.array([[0], [1.0], [0], [0.5]])
    sys = control.c2d(control.ss(A, B, np.array([[1.0, 0, 1, 0]]), 0), 1 / fs)
    return sys.A, sys.B


def test_unconstrained_equals_lqr():
    A, B = _plant()
    Q, R = np.diag([1e8, 1e2, 1e6, 1.0]), np.array([[1e-4]])
    K, _, _ = control.dlqr(A, B, Q, R)
    mpc = LinearMPC(A, B, Q, R, N=10)
    rng = np.random.default_rng(0)
    for _ in range(5):
        x0 = rng.standard_normal(4) * np.array([1e-3, 1e-2, 1e-5, 1e-3])
        u = mpc.solve(x0)
        np.testing.assert_allclose(u, -K @ x0, rtol=1e-6, atol=1e-9 * np.abs(K @ x0).max())


def test_force_limit_and_window_hold_in_closed_loop():
    A, B = _plant()
    Q, R = np.diag([1e8, 1e2, 1e6, 1.0]), np.array([[1e-4]])
    Cz = np.array([[1.0, 0, 1, 0]])
    umax = 5.0
    mpc = LinearMPC(A, B, Q, R, N=20, u_min=-umax, u_max=umax, Cz=Cz, y_min=-1e-3, y_max=2e-3)
    x = np.array([1e-3, 0, 0, 0])  # 1 mm error from the target: a large step
    us, ys = [], []
    for _ in range(300):
        u = mpc.solve(x)
        us.append(u[0])
        x = A @ x + B @ u
        ys.append((Cz @ x)[0])
    assert np.max(np.abs(us)) <= umax + 1e-9
    assert np.max(np.abs(us)) >= umax - 1e-6  # the limit is actually active
    assert min(ys) >= -1e-3 - 1e-9 and max(ys) <= 2e-3 + 1e-9
    assert abs(ys[-1]) < 1e-4
    assert mpc.report["n"] == 300


def test_bad_input_refused():
    A, B = _plant()
    with pytest.raises(InputError, match="A must be"):
        LinearMPC(A[:3, :3], B, np.eye(4), np.eye(1), N=5)
    with pytest.raises(InputError, match="infeasible force limits"):
        LinearMPC(A, B, np.eye(4), np.eye(1), N=5, u_min=1.0, u_max=-1.0)
    with pytest.raises(InputError, match="x0 must have"):
        LinearMPC(A, B, np.eye(4), np.eye(1), N=5).solve(np.zeros(3))
