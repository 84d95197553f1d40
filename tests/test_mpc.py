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
    # scipy's solver: SLICOT's sb02od (python-control's default when slycot is installed)
    # gives up on weights this far apart (Q 1e8 against R 1e-4), it does not balance
    K, _, _ = control.dlqr(A, B, Q, R, method="scipy")
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


# ------------------------------------------------------------------ MPC as a Controller
FS = 5000.0
M_KG, F_FLEX_HZ, Z_FLEX = 2.0, 300.0, 0.01  # a mass and one flexible mode (as test_cli_design)


def _mass_flex():
    from workbench.core.model import LTIModel

    w = 2 * np.pi * F_FLEX_HZ
    g = control.tf([1.0], [M_KG, 0, 0]) + control.tf([1.0], [1, 2 * Z_FLEX * w, w * w])
    return LTIModel.from_statespace(control.ss(g), input_names=("F",), output_names=("x",))


# rigid-body position weight (modal coordinates) and input weight giving a ~50 Hz loop
# (the LQR of m x'' = u: closed-loop frequency (q / (r m^2))^(1/4) ~ 2 pi 50 for q/r ~ 4e10)
WEIGHTS = dict(rigid_position=4e10, integral=1e14)


def _designs(**limits):
    from controllers import modal_sf
    from controllers.mpc import design_mpc

    K_mpc = design_mpc(
        _mass_flex(), FS, loop_delay_samples=1, horizon=25, weights=WEIGHTS, sensor=1e-8,
        **limits,
    )  # fmt: skip
    dm = K_mpc.dm
    K = modal_sf.lqr_gain(dm, modal_sf.modal_weights(dm, **WEIGHTS))
    L = modal_sf.kalman_gain(dm, sensor=1e-8)
    return K_mpc, modal_sf.observer_controller(dm, K, L)


def test_mpc_controller_unconstrained_equals_lqr_observer_controller():
    from controllers.protocol import Controller
    from workbench.sim import closed_loop

    K_mpc, K_lin = _designs()
    assert isinstance(K_mpc, Controller) and not K_mpc.linear
    N = 400
    r = np.zeros((N, 1))
    r[20:] = 1e-4  # a 0.1 mm step of the reference
    u1, y1 = closed_loop(_mass_flex(), K_mpc, r=r, delay_samples=1)
    u2, y2 = closed_loop(_mass_flex(), K_lin, r=r, delay_samples=1, method="step")
    assert np.max(np.abs(y2[-50:] - 1e-4)) < 1e-6  # the reference design itself settles
    np.testing.assert_allclose(u1, u2, rtol=0, atol=1e-7 * np.max(np.abs(u2)))
    np.testing.assert_allclose(y1, y2, rtol=0, atol=1e-7 * 1e-4)
    t = K_mpc.solve_times()
    assert t["n"] == N and t["failures"] == 0 and 0 < t["mean_s"] <= t["max_s"]


def test_mpc_controller_force_limit_holds_in_closed_loop():
    from workbench.sim import closed_loop

    _, K_lin = _designs()
    N = 1500
    r = np.zeros((N, 1))
    r[20:] = 1e-4
    u_free, _ = closed_loop(_mass_flex(), K_lin, r=r, delay_samples=1, method="step")
    u_lim = 0.3 * np.max(np.abs(u_free))  # the unconstrained move needs more than this
    K_mpc, _ = _designs(u_min=-u_lim, u_max=u_lim)
    u, y = closed_loop(_mass_flex(), K_mpc, r=r, delay_samples=1)
    assert np.max(np.abs(u)) <= u_lim * (1 + 1e-9)
    assert np.max(np.abs(u)) >= u_lim * (1 - 1e-6)  # the limit is active
    assert abs(y[-1, 0] - 1e-4) < 1e-7  # and the loop still reaches the reference
    assert K_mpc.solve_times()["failures"] == 0


def test_mpc_controller_refuses_statespace_and_bad_input():
    K_mpc, _ = _designs()
    with pytest.raises(InputError, match="nonlinear"):
        K_mpc.statespace()
    with pytest.raises(InputError, match="e: expected shape"):
        K_mpc.step(K_mpc.init(), np.zeros(2))
