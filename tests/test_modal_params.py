"""The modal model as a parameter vector (workbench.modal.params): pack / unpack.

Oracles: the round trip keeps the response (the modal FRF evaluated term by
term in this file), every entry of theta is the named field of the model, and
the refinement's Jacobian in theta is checked against finite differences of
unpack in tests/test_refine.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench.modal.model import ModalModel, Mode
from workbench.modal.params import pack

FREQ = np.geomspace(0.5, 2000.0, 300)


def modal_frf(modes, D, f):
    """sum_k c_k b_k^T / den_k(s) + D, written out here (independent of ModalModel.frf)."""
    s = 2j * np.pi * f
    G = np.zeros((f.size,) + D.shape, complex) + D
    for kind, fk, zk, b, c in modes:
        w = 2 * np.pi * fk
        den = {"rigid": s**2, "flexible": s**2 + 2 * zk * w * s + w * w, "real": s + zk * w}[kind]
        G += np.outer(c, b)[None] / den[:, None, None]
    return G


def model(rng, n_rigid, n_y=2, n_u=3):
    spec = [("rigid", 0.0, 0.0)] * n_rigid + [("flexible", 150.0, 0.02), ("flexible", 420.0, 0.01)]
    spec += [("real", 60.0, 1.0)]
    modes = [(k, f, z, rng.standard_normal(n_u), rng.standard_normal(n_y)) for k, f, z in spec]
    D = rng.standard_normal((n_y, n_u))
    mm = ModalModel(
        modes=tuple(Mode(k, f, z, b, c) for k, f, z, b, c in modes),
        D=D,
        input_names=tuple(f"F{j}" for j in range(n_u)),
        output_names=tuple(f"x{i}" for i in range(n_y)),
    )
    return mm, modes, D


@pytest.mark.parametrize("n_rigid", [2, 1], ids=["shared-rigid-gain", "rigid-per-mode"])
@pytest.mark.parametrize("feedthrough", [True, False], ids=["D", "no-D"])
def test_pack_unpack_round_trip(n_rigid, feedthrough):
    rng = np.random.default_rng(7)
    mm, modes, D = model(rng, n_rigid)
    lay, theta = pack(mm, feedthrough=feedthrough)
    assert theta.shape == (lay.n_par,) and len(lay.names) == lay.n_par
    n_y, n_u = 2, 3
    # parameter count: rigid P (or c, b per rigid mode), (f, z, c, b) per flexible mode,
    # (p, c, b) per real mode, D
    n_rig = n_y * n_u if n_rigid >= min(n_y, n_u) else n_rigid * (n_y + n_u)
    assert lay.n_par == n_rig + 2 * (2 + n_y + n_u) + (1 + n_y + n_u) + feedthrough * n_y * n_u
    assert lay.kinds[0] == ("rigid_full" if n_rigid == 2 else "rigid")
    # the named entries are the model's fields
    names = list(lay.names)
    assert theta[names.index(f"mode {n_rigid + 1} freq_hz")] == 150.0
    assert theta[names.index(f"mode {n_rigid + 2} damping")] == 0.01
    assert theta[names.index(f"mode {n_rigid + 3} pole")] == pytest.approx(-2 * np.pi * 60.0)
    back = lay.unpack(theta, mm)
    assert back.kinds == mm.kinds and back.input_names == mm.input_names
    G = modal_frf(modes, D, FREQ)
    assert np.max(np.abs(back.frf(FREQ) - G)) < 1e-12 * np.max(np.abs(G))
    # each mode normalized |b| = |c|, its response kept
    for m in back.modes:
        assert np.linalg.norm(m.b) == pytest.approx(np.linalg.norm(m.c), rel=1e-12)
    assert list(lay.mode_order(theta)) == list(range(len(mm.modes)))  # already in order


def test_unpack_orders_modes_and_reports_std_per_mode():
    """A frequency moved past the next mode's: unpack sorts, mode_order says where each went;
    mode_std takes the diagonal of the covariance (Hz for a real pole's rad/s)."""
    rng = np.random.default_rng(8)
    mm, _, _ = model(rng, 1)
    lay, theta = pack(mm)
    i = lay.names.index("mode 2 freq_hz")
    theta = theta.copy()
    theta[i] = 500.0  # mode 2 (150 Hz) now above mode 3 (420 Hz)
    back = lay.unpack(theta, mm)
    assert list(back.freq_hz[1:3]) == [420.0, 500.0]
    assert list(lay.mode_order(theta)) == [0, 2, 1, 3]
    cov = np.diag(np.arange(1.0, lay.n_par + 1) ** 2)
    f_std, z_std = lay.mode_std(cov)
    assert np.isnan(f_std[0]) and np.isnan(z_std[0])
    assert f_std[1] == i + 1 and z_std[1] == i + 2
    p = lay.names.index("mode 4 pole")
    assert f_std[3] == pytest.approx((p + 1) / (2 * np.pi)) and z_std[3] == 0.0
