"""d2c and the modal canonical form: analytic oracles (mass-spring-damper chains)."""

from __future__ import annotations

import json

import control
import numpy as np
import pytest
import scipy.linalg
from conftest import SHARED_EXAMPLES, require_shared

from workbench.cli.main import main
from workbench.core.d2c import d2c
from workbench.core.errors import InputError
from workbench.core.lti import frf
from workbench.io.formats import load_model, save_model
from workbench.modal.model import ModalModel, Mode, plot_mode_superposition, plot_model_bode

EXAMPLE = SHARED_EXAMPLES / "example_stage_delay_time" / "nominal_model.npz"


def chain(n_mass: int, *, grounded: bool, alpha: float = 2e-5, beta: float = 0.5):
    """Mass-spring chain, Rayleigh damping C = alpha K + beta M; forces at both ends, positions.

    Returns the continuous StateSpace (states [q; dq/dt]) and M, K.
    """
    m = np.linspace(1.0, 2.0, n_mass)
    k = np.linspace(4e4, 9e4, n_mass)
    M = np.diag(m)
    K = np.zeros((n_mass, n_mass))
    for i in range(n_mass - 1):  # springs between neighbours
        K[i : i + 2, i : i + 2] += k[i] * np.array([[1, -1], [-1, 1]])
    if grounded:
        K[0, 0] += k[-1]
    Cd = alpha * K + beta * M if grounded else alpha * K  # no damping of the free rigid motion
    Bf = np.zeros((n_mass, 2))
    Bf[0, 0] = 1.0
    Bf[-1, 1] = 1.0
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((n_mass, n_mass)), np.eye(n_mass)], [-Minv @ K, -Minv @ Cd]])
    B = np.vstack([np.zeros((n_mass, 2)), Minv @ Bf])
    C = np.hstack([np.eye(n_mass), np.zeros((n_mass, n_mass))])
    return control.ss(A, B, C, np.zeros((n_mass, 2))), M, K, Cd


def modal_oracle(M, K, Cd):
    """Frequencies (Hz) and damping ratios of the generalized eigenproblem K phi = w^2 M phi."""
    w2, Phi = scipy.linalg.eigh(K, M)
    w2 = np.clip(w2, 0, None)
    d = np.einsum("ik,ij,jk->k", Phi, Cd, Phi)  # modal damping 2 z w (Phi mass-normalized)
    w = np.sqrt(w2)
    with np.errstate(divide="ignore", invalid="ignore"):
        zeta = np.where(w > 0, d / (2 * w), 0.0)
    return w / (2 * np.pi), zeta


# ---------------------------------------------------------------------- d2c
@pytest.mark.parametrize("grounded", [True, False], ids=["grounded", "free (rigid body)"])
def test_d2c_inverts_c2d(grounded):
    sysc, *_ = chain(4, grounded=grounded)
    dt = 2e-4
    back = d2c(control.c2d(sysc, dt, method="zoh"))
    assert back.dt == 0
    for name in "ABCD":
        ref = np.asarray(getattr(sysc, name))
        got = np.asarray(getattr(back, name))
        assert np.allclose(got, ref, rtol=0, atol=1e-9 * max(1.0, np.abs(ref).max())), name


def test_d2c_refuses_poles_at_zero_and_on_the_negative_axis():
    delay = control.ss(np.diag([0.0, 0.5]), [[1.0], [1.0]], [[1.0, 1.0]], [[0.0]], 1e-3)
    with pytest.raises(InputError, match=r"1 pole\(s\) at z = 0 .*input delay"):
        d2c(delay)
    neg = control.ss(np.diag([-0.4, 0.5]), [[1.0], [1.0]], [[1.0, 1.0]], [[0.0]], 1e-3)
    with pytest.raises(InputError, match=r"negative real axis \(-0\.4\)"):
        d2c(neg)
    with pytest.raises(InputError, match="expects a discrete model"):
        d2c(control.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]]))


# -------------------------------------------------------------- modal form
def test_grounded_chain_modes_match_the_generalized_eigenproblem():
    sysc, M, K, Cd = chain(4, grounded=True)
    f_ref, z_ref = modal_oracle(M, K, Cd)
    mm = ModalModel.from_statespace(sysc)
    assert mm.kinds == ("flexible",) * 4
    assert np.allclose(mm.freq_hz, f_ref, rtol=1e-10)
    assert np.allclose(mm.damping, z_ref, rtol=1e-8)
    # a mechanical system is exactly modal: no residual
    assert max(m.residual for m in mm.modes) < 1e-8
    # same input-output behaviour, both forms
    f = np.logspace(0, 3, 200)
    G = frf(sysc, f)
    for form in ("companion", "scaled"):
        Gm = frf(mm.to_statespace(form=form), f)
        assert np.max(np.abs(Gm - G)) < 1e-9 * np.max(np.abs(G))
    # the kept similarity maps the realization's A onto the modal A exactly
    T = mm.transform
    A_modal = np.asarray(mm.to_statespace().A)
    assert np.allclose(
        np.linalg.solve(T, np.asarray(sysc.A) @ T), A_modal, atol=1e-7 * np.abs(A_modal).max()
    )
    # layout: B rows [0; b_k], C columns [c_k, 0]
    ss = mm.to_statespace()
    assert np.all(np.asarray(ss.B)[0::2] == 0) and np.all(np.asarray(ss.C)[:, 1::2] == 0)


def test_free_chain_has_one_rigid_mode_and_the_rest_flexible():
    sysc, M, K, Cd = chain(3, grounded=False)
    f_ref, z_ref = modal_oracle(M, K, Cd)
    mm = ModalModel.from_statespace(sysc)
    assert mm.kinds == ("rigid", "flexible", "flexible")
    assert np.allclose(mm.freq_hz[1:], f_ref[1:], rtol=1e-9)
    assert np.allclose(mm.damping[1:], z_ref[1:], rtol=1e-7)
    f = np.logspace(-1, 3, 200)
    G = frf(sysc, f)
    assert np.max(np.abs(mm.frf(f) - G) / np.abs(G).max()) < 1e-8


def perturbed_rigid_body(rng, n_dof=3, eps=0.3):
    """n_dof double integrators and a flexible mode, as identification returns them.

    The rigid poles are moved to |s| ~ eps rad/s (real pairs, one slightly
    unstable), and the realization is in a random basis.
    """
    b = np.eye(n_dof) * np.array([0.5, 2.0, 1.0])
    A = np.zeros((2 * n_dof + 2, 2 * n_dof + 2))
    B = np.zeros((2 * n_dof + 2, n_dof))
    C = np.zeros((n_dof, 2 * n_dof + 2))
    for k in range(n_dof):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[0, 1], [eps**2 * (1 - 2 * (k == 1)), eps * 0.1]]
        B[2 * k + 1] = b[k]
        C[k, 2 * k] = 1.0
    w = 2 * np.pi * 300.0
    A[-2:, -2:] = [[0, 1], [-(w**2), -2 * 0.02 * w]]
    B[-1] = [1.0, -0.5, 0.2]
    C[:, -2] = [0.3, 0.1, -0.2]
    T = np.eye(A.shape[0]) + 0.2 * rng.standard_normal(A.shape)
    return control.ss(np.linalg.solve(T, A @ T), np.linalg.solve(T, B), C @ T, 0), b


def test_near_rigid_cluster_is_projected_onto_double_integrators_per_dof():
    sysc, b_true = perturbed_rigid_body(np.random.default_rng(0))
    mm = ModalModel.from_statespace(sysc, rigid_threshold_hz=1.0)
    assert mm.kinds == ("rigid",) * 3 + ("flexible",)
    # per DOF: c_k along output k, c_k b_k^T equal to the true 1/s^2 gain of DOF k
    for k, m in enumerate(mm.modes[:3]):
        assert np.count_nonzero(np.abs(m.c) > 1e-12) == 1 and abs(m.c[k]) > 0
        assert np.allclose(np.outer(m.c, m.b), np.outer(np.eye(3)[k], b_true[k]), atol=1e-9)
    assert mm.modes[3].freq_hz == pytest.approx(300.0, rel=1e-9)
    assert mm.modes[3].damping == pytest.approx(0.02, rel=1e-8)
    # the whole cluster lies below 1 Hz and is reported
    assert mm.rigid_poles.size == 6 and np.max(np.abs(mm.rigid_poles)) < 2 * np.pi


def test_real_poles_are_reported_as_such():
    # a flexible mode plus a first-order lag at 50 Hz (an amplifier pole)
    p = -2 * np.pi * 50.0
    w = 2 * np.pi * 200.0
    A = np.array([[0, 1, 0], [-(w**2), -0.1 * w, 0], [0, 0, p]])
    sysc = control.ss(A, [[0.0], [1.0], [3.0]], [[1.0, 0.0, 2.0]], [[0.0]])
    mm = ModalModel.from_statespace(sysc)
    assert mm.kinds == ("flexible", "real")
    assert mm.modes[1].freq_hz == pytest.approx(50.0) and mm.modes[1].damping == 1.0
    assert np.outer(mm.modes[1].c, mm.modes[1].b)[0, 0] == pytest.approx(6.0)
    f = np.logspace(0, 3, 100)
    assert np.max(np.abs(mm.frf(f) - frf(sysc, f))) < 1e-9 * np.max(np.abs(frf(sysc, f)))


def test_discrete_identified_style_model_goes_through_d2c():
    sysc, M, K, Cd = chain(3, grounded=True)
    f_ref, z_ref = modal_oracle(M, K, Cd)
    mm = ModalModel.from_statespace(control.c2d(sysc, 1e-4))
    assert np.allclose(mm.freq_hz, f_ref, rtol=1e-8)
    assert np.allclose(mm.damping, z_ref, rtol=1e-6)


def test_example_nominal_model_layout_is_reproduced():
    require_shared()
    sys = load_model(EXAMPLE)
    mm = ModalModel.from_statespace(sys)
    assert mm.kinds == ("rigid",) * 6 + ("flexible",) * 2
    assert mm.freq_hz[6:] == pytest.approx([913.8, 1032.0], abs=1e-6)
    out = mm.to_statespace(form="scaled")
    # the example's A is exactly the scaled layout; rigid b_k and c_k per DOF as in the file
    assert np.allclose(np.asarray(out.A), np.asarray(sys.A), rtol=1e-10, atol=1e-9)
    assert np.allclose(np.asarray(out.B)[:12], np.asarray(sys.B)[:12], atol=1e-12)
    assert np.allclose(np.asarray(out.C)[:, :12], np.asarray(sys.C)[:, :12], atol=1e-12)
    f = np.logspace(0, 3.5, 100)
    assert np.max(np.abs(frf(out, f) - frf(sys, f))) < 1e-9 * np.max(np.abs(frf(sys, f)))


# ------------------------------------------------------------ model object
def test_modal_model_validates_and_reports(tmp_path):
    with pytest.raises(InputError, match="mode kind"):
        Mode(kind="torsion", freq_hz=1.0, damping=0.1, b=[1.0], c=[1.0])
    with pytest.raises(InputError, match="mode 0: expected b"):
        ModalModel(
            modes=(Mode(kind="rigid", freq_hz=0, damping=0, b=[1.0, 2.0], c=[1.0]),),
            D=np.zeros((1, 1)),
        )
    sysc, *_ = chain(3, grounded=False)
    mm = ModalModel.from_statespace(sysc)
    text = mm.table_text()
    assert "rigid" in text and "flexible" in text
    rows = json.loads(mm.to_json())["modes"]
    assert [r["kind"] for r in rows] == ["rigid", "flexible", "flexible"]
    assert rows[1]["freq_hz"] == pytest.approx(mm.modes[1].freq_hz)
    plot_model_bode(mm, tmp_path / "bode.png")
    plot_mode_superposition(mm, tmp_path / "sup.png", output=0, input=0)
    assert (tmp_path / "bode.png").stat().st_size > 1000 and (
        tmp_path / "sup.png"
    ).stat().st_size > 1000
    with pytest.raises(InputError, match="output/input"):
        plot_mode_superposition(mm, tmp_path / "x.png", output=7)


def test_cli_modes(tmp_path, capsys):
    sysc, *_ = chain(3, grounded=False)
    path = tmp_path / "m.npz"
    save_model(path, control.c2d(sysc, 1e-4))
    assert main(["modes", str(path), "--json", "--plot", str(tmp_path / "b.png")]) == 0
    rows = json.loads(capsys.readouterr().out)["modes"]
    assert [r["kind"] for r in rows] == ["rigid", "flexible", "flexible"]
    assert main(["modes", str(path), "--plot", str(path)]) == 2
    assert "refusing to write the output over an input file" in capsys.readouterr().err
