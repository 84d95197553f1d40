"""Exact sensitivities of the port-force simulation (workbench._port_kernel, SubstepZoh.simulate).

Oracle: central finite differences of the simulation itself (sens=None), independent of the
forward-sensitivity recursion; the parameters are those fit_port_element fits for friction:
the log levels, log v0 and a port velocity map moved by a gain. The system has sticking
rigid bodies and a lightly damped mode (stiff friction: F_c Mv / v0 > 1 at 4 substeps).
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench import sim
from workbench.core.errors import InputError

#: two free masses (kg) and a 300 Hz mode seen at both ports
MASS = (5.0, 3.0)
FS = 2000.0


def _system():
    w = 2 * np.pi * 300.0
    A = np.zeros((6, 6))
    A[0, 1] = A[2, 3] = A[4, 5] = 1.0
    A[5, 4], A[5, 5] = -w * w, -2 * 0.02 * w
    B = np.zeros((6, 2))
    B[1, 0], B[3, 1] = 1 / MASS[0], 1 / MASS[1]
    B[5] = [0.3, -0.2]
    Cp0 = np.zeros((2, 6))
    Cp0[0, 0] = Cp0[1, 2] = 1.0
    Cpk = np.zeros((2, 6))
    Cpk[:, 4] = [0.3, -0.2]  # the mode's share of the port displacement per unit gain
    return A, B, Cp0, Cpk


def _run(theta, u, n_sub, *, sens=False):
    """Outputs (and dy/dtheta) at theta = (log F_c (2), log v0, log g)."""
    A, B, Cp0, Cpk = _system()
    Fc, v0, g = np.exp(theta[:2]), float(np.exp(theta[2])), float(np.exp(theta[3]))
    Cp = Cp0 + g * Cpk
    law = sim.PortLaw(
        Cv=Cp @ A, Cp=Cp, friction_force=Fc, friction_velocity=v0, cubic_stiffness=0.0
    )
    prop = sim.substep_zoh(A, B, B, 1 / FS, n_sub)
    C = np.vstack([Cp0 + 0.5 * Cpk, Cp0])  # measured: other shapes than the ports'
    D = np.zeros((4, 2))
    if not sens:
        return prop.simulate(law, u, u, C, D)[0]
    ps = sim.PortSensitivity(
        friction_force=np.vstack([np.diag(Fc), np.zeros((2, 2))]),
        log_velocity=np.array([0.0, 0.0, 1.0, 0.0]),
        Cv=np.stack([np.zeros((2, 6))] * 3 + [g * Cpk @ A]),
    )
    return prop.simulate(law, u, u, C, D, sens=ps)


@pytest.mark.parametrize("n_sub", [1, 4])
def test_sensitivities_equal_finite_differences_of_the_simulation(n_sub):
    rng = np.random.default_rng(0)
    u = 2.0 * rng.standard_normal((1500, 2))
    theta = np.log([0.3, 0.2, 1e-4, 0.8])
    y, _, dy = _run(theta, u, n_sub, sens=True)
    np.testing.assert_array_equal(y, _run(theta, u, n_sub))  # the simulation is unchanged
    # the friction sticks part of the time (a stiff law) and slides the rest
    v = np.diff(y[:, 2]) * FS
    assert 0.05 < np.mean(np.abs(v) < 1e-4) < 0.95
    for q in range(theta.size):
        step = 1e-6 * np.eye(theta.size)[q]
        fd = (_run(theta + step, u, n_sub) - _run(theta - step, u, n_sub)) / 2e-6
        scale = np.abs(fd).max()
        assert scale > 0
        np.testing.assert_allclose(dy[:, :, q], fd, rtol=0, atol=1e-5 * scale)


def test_a_cubic_spring_has_no_sensitivities():
    A, B, Cp0, _ = _system()
    law = sim.PortLaw(
        Cv=Cp0 @ A, Cp=Cp0, friction_force=0.1, friction_velocity=1e-4, cubic_stiffness=1e6
    )
    prop = sim.substep_zoh(A, B, B, 1 / FS, 2)
    u = np.ones((10, 2))
    with pytest.raises(InputError, match="cubic"):
        prop.simulate(law, u, u, Cp0, np.zeros((2, 2)), sens=sim.PortSensitivity(np.eye(2)))


def test_square_ports_map_derivative_is_the_change_of_the_port_rows():
    """The stage's non-collocated flexible modes (DOF coordinates): the port rows of
    SquarePorts.system move linearly with each gain, by port_map_derivative per m/N."""
    import plants
    from workbench.diagnosis.nonlinear import square_ports
    from workbench.modal.model import ModalModel

    lin = plants.get_plant("wafer_stage", delay_s=0.0).linear_model()
    family = square_ports(ModalModel.from_statespace(lin))
    assert family is not None and len(family.modes) >= 1
    dCp = family.port_map_derivative()
    g = family.unit * np.linspace(0.3, 2.0, len(family.modes))
    ports = family.port_outputs
    base = family.system(g)
    for k in range(len(family.modes)):
        moved = g.copy()
        moved[k] *= 1.37
        sys_k = family.system(moved)
        np.testing.assert_array_equal(np.asarray(sys_k.A), np.asarray(base.A))
        change = (np.asarray(sys_k.C) - np.asarray(base.C))[ports]
        np.testing.assert_allclose(change, 0.37 * g[k] * dCp[k], atol=1e-9 * np.abs(change).max())


@pytest.mark.parametrize("sliding", [(), (1, 4), (0, 2, 3, 5), tuple(range(6))])
def test_port_solve_equals_the_whole_systems_solution(sliding):
    """The Newton step's and the sensitivities' solve on the ports not sliding (slope s_i = 0
    rows substituted) equals numpy's solve of the whole ``(I + diag(s) Mv) X' = R'``."""
    from workbench._port_kernel import _port_solve

    rng = np.random.default_rng(3)
    n_p, n_rhs = 6, 4
    L = rng.standard_normal((n_p, n_p))
    Mv = L @ L.T * 1e-6  # a driving-point mobility: symmetric, positive definite
    s = 10.0 ** rng.uniform(2, 8, n_p)  # stiff and mild slopes (1/m/s units of F_c / v0)
    s[list(sliding)] = 0.0
    R = rng.standard_normal((n_rhs, n_p))
    ref = np.linalg.solve(np.eye(n_p) + s[:, None] * Mv, R.T).T
    X = R.copy()
    _port_solve(Mv, s, X, np.empty((n_p, n_p)), np.empty((n_rhs, n_p)), np.empty(n_p, np.int64))
    np.testing.assert_allclose(X, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_array_equal(X[:, list(sliding)], R[:, list(sliding)])
