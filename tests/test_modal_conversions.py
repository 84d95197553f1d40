"""Conversions of the one modal model (workbench.modal.model.ModalModel).

Oracle independent of the code: a free-free mass-spring chain with Rayleigh
damping, whose modes come from the generalized eigenproblem K phi = w^2 M phi
(scipy.linalg.eigh, mass-normalized phi): frequencies w_k, damping
zeta_k = alpha / (2 w_k) + beta w_k / 2 and residues c_k b_k^T = (S phi_k)(F^T phi_k)^T.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg

from workbench import sim
from workbench.core import lti
from workbench.core.errors import InputError
from workbench.core.model import LTIModel
from workbench.diagnosis.modal import decompose
from workbench.modal.model import ModalModel, Mode, split_rigid_gain

FREQ = np.geomspace(0.3, 3000.0, 400)


def chain(n_dof: int = 4, *, anchored: bool = False, seed: int = 3):
    """A chain of masses and springs, forces at DOFs 0 and n-1, positions at 0, 1, n-1.

    Returns the physical state space and the analytic modes (w rad/s, zeta,
    residues (n_m, n_y, n_u)), lowest first.
    """
    rng = np.random.default_rng(seed)
    m = rng.uniform(0.5, 2.0, n_dof)
    k = rng.uniform(2e5, 8e5, n_dof - 1)
    M = np.diag(m)
    K = np.zeros((n_dof, n_dof))
    for i, ki in enumerate(k):
        K[i : i + 2, i : i + 2] += ki * np.array([[1, -1], [-1, 1]])
    if anchored:
        K[0, 0] += 5e4  # a suspension (~20 Hz, above the 5 Hz rigid threshold): no rigid mode
    alpha, beta = 0.0, 2e-6  # Rayleigh: rigid mode undamped
    Cd = alpha * M + beta * K
    F = np.zeros((n_dof, 2))
    F[0, 0] = F[-1, 1] = 1.0
    S = np.zeros((3, n_dof))
    S[0, 0] = S[1, 1] = S[2, -1] = 1.0
    w2, Phi = scipy.linalg.eigh(K, M)  # Phi^T M Phi = I
    w = np.sqrt(np.clip(w2, 0, None))
    w[np.abs(w2) < 1e-6 * w2.max()] = 0.0
    zeta = np.where(w > 0, alpha / (2 * np.where(w > 0, w, 1)) + beta * w / 2, 0.0)
    res = np.einsum("yk,uk->kyu", S @ Phi, F.T @ Phi)
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n_dof, n_dof)), np.eye(n_dof)], [-Mi @ K, -Mi @ Cd]])
    B = np.vstack([np.zeros((n_dof, 2)), Mi @ F])
    C = np.hstack([S, np.zeros((3, n_dof))])
    return control.ss(A, B, C, np.zeros((3, 2))), w, zeta, res


def rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def check_against_oracle(mm: ModalModel, w, zeta, res, tol=1e-7):
    assert np.allclose(2 * np.pi * mm.freq_hz, w, rtol=tol, atol=tol * w.max())
    flex = w > 0
    assert np.allclose(mm.damping[flex], zeta[flex], rtol=1e-6)
    for mode, r in zip(mm.modes, res):
        got = np.outer(mode.c, mode.b)
        assert np.max(np.abs(got - r)) < tol * np.max(np.abs(res))


def test_statespace_to_modal_matches_the_generalized_eigenproblem():
    sys, w, zeta, res = chain()
    mm = ModalModel.from_statespace(sys)
    assert mm.kinds == ("rigid", "flexible", "flexible", "flexible")
    check_against_oracle(mm, w, zeta, res)
    assert rel(mm.frf(FREQ), lti.frf(sys, FREQ)) < 1e-9
    # the exact form agrees on the same chain (a mass-spring mode is ideal: N1 = 0)
    ex = ModalModel.from_statespace(sys, exact=True)
    check_against_oracle(ex, w, zeta, res)
    assert max(np.max(np.abs(m.numerator()[1])) for m in ex.modes) < 1e-9 * np.max(np.abs(res))


@pytest.mark.parametrize("form", ["companion", "scaled"])
def test_modal_lti_round_trip_keeps_frf_modes_and_delay(form):
    sys, w, zeta, res = chain(anchored=True)
    mm = ModalModel.from_statespace(LTIModel.from_statespace(sys, delay_s=3e-4))
    assert mm.delay_s == 3e-4 and mm.kinds == ("flexible",) * 4
    lti_model = mm.to_lti(form=form)
    assert isinstance(lti_model, LTIModel) and lti_model.delay_s == 3e-4
    G = lti.frf(sys, FREQ, delay_s=3e-4)
    assert rel(lti_model.frf(FREQ), G) < 1e-9
    assert rel(mm.frf(FREQ), G) < 1e-9
    back = ModalModel.from_statespace(lti_model)
    check_against_oracle(back, w, zeta, res)
    assert back.delay_s == 3e-4


def test_discrete_model_goes_through_the_one_d2c():
    sys, w, zeta, res = chain()
    mm = ModalModel.from_statespace(control.c2d(sys, 1e-4, "zoh"))
    check_against_oracle(mm, w, zeta, res, tol=1e-6)


def test_exact_form_keeps_what_the_ideal_form_drops():
    """A velocity numerator (N1), a near-rigid pair, a real pole, a single integrator and D:
    the exact decomposition reproduces the FRF and realizes it with as many states."""
    rng = np.random.default_rng(5)
    s_pair = -2 * np.pi * 3.0 * 0.02 + 2j * np.pi * 300.0
    near = 2j * np.pi * 0.4 + 0.5  # a slightly unstable near-rigid pair (identified models)
    blocks = [np.array([[z.real, z.imag], [-z.imag, z.real]]) for z in (s_pair, near)] + [
        np.array([[-2 * np.pi * 50.0]]),
        np.zeros((1, 1)),
    ]
    A = scipy.linalg.block_diag(*blocks)
    B, C, D = rng.standard_normal((6, 2)), rng.standard_normal((2, 6)), rng.standard_normal((2, 2))
    sys = control.ss(A, B, C, D)
    G = lti.frf(sys, FREQ)
    ex = ModalModel.from_statespace(sys, exact=True)
    assert sorted(ex.kinds) == ["flexible", "flexible", "real", "rigid"]
    assert rel(ex.frf(FREQ), G) < 1e-9
    ss = ex.to_statespace()
    assert ss.nstates == 6
    assert rel(lti.frf(ss, FREQ), G) < 1e-9
    assert np.allclose(ex.D, D)
    f_near = [m.freq_hz for m in ex.modes if m.kind == "flexible"]
    assert min(f_near) == pytest.approx(abs(near) / (2 * np.pi), rel=1e-9)


def test_exact_form_refuses_a_triple_integrator():
    A = np.diag([1.0, 1.0], 1)
    sys = control.ss(A, [[0], [0], [1]], [[1, 0, 0]], 0)
    with pytest.raises(InputError) as exc:
        ModalModel.from_statespace(sys, exact=True)
    assert "order above two" in str(exc.value) and "\n" not in str(exc.value)


def test_rigid_merged_form_round_trip():
    """The diagnosis's form of the one modal model: the rigid modes as one mode over s^2
    with their summed numerator; split again by split_rigid_gain, the oracle's modes."""
    sys, w, zeta, res = chain()
    mm = ModalModel.from_statespace(LTIModel.from_statespace(sys, delay_s=1e-4))
    merged = mm.with_rigid_merged()
    assert isinstance(merged, ModalModel)
    assert merged.kinds == ("rigid", "flexible", "flexible", "flexible")
    assert merged.delay_s == 1e-4
    assert rel(merged.frf(FREQ), mm.frf(FREQ)) < 1e-12
    assert rel(merged.to_lti().frf(FREQ), mm.frf(FREQ)) < 1e-9
    N0, N1 = merged.rigid_residue()
    assert np.allclose(N0, sum(res[w == 0]), rtol=0, atol=1e-9 * np.abs(res).max())
    assert not np.any(N1)
    n_r = len(mm.modes_of_kind("rigid"))
    C, B = split_rigid_gain(N0, n_r)
    split = ModalModel(
        modes=tuple(Mode("rigid", 0.0, 0.0, B[k], C[:, k]) for k in range(n_r)) + merged.modes[1:],
        D=merged.D,
    )
    assert split.is_ideal
    check_against_oracle(split, w, zeta, res)


def test_extended_terms_live_in_the_modal_model():
    """Lags, crosstalk, delay, residual compliance (D), a suspension (the rigid s^2 mode
    moved to a denominator) and an added mode with an exact numerator, all fields of the
    one ModalModel: its FRF against an independent evaluation (python-control on each
    part, then the lags, coupling and delay by hand), its realization, its ZOH simulation."""
    sys, w, zeta, res = chain()
    em = decompose(sys)
    rng = np.random.default_rng(2)
    N0, N1 = rng.standard_normal((3, 2)), rng.standard_normal((3, 2))
    added = Mode("flexible", 700.0, 0.03, np.zeros(2), np.zeros(3), N0=N0, N1=N1, effect="x")
    modes = (em.modes[0].moved(3.0, 0.1, effect="suspension_stiffness"), *em.modes[1:], added)
    tau_in, tau_out = np.array([1e-4, 0.0]), np.array([0.0, 3e-4, 5e-5])
    T_out = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    T_in = np.eye(2) + 0.05 * rng.standard_normal((2, 2))
    D = em.D + 1e-7 * rng.standard_normal((3, 2))
    mm = ModalModel(
        modes=modes, D=D, delay_s=2e-4, tau_in=tau_in, tau_out=tau_out, T_in=T_in, T_out=T_out
    )
    assert mm.has_outer and mm.delay_s == 2e-4 and "rigid" not in mm.kinds
    assert mm.modes[0].effect == "suspension_stiffness" and mm.modes[1].effect == ""
    # independent evaluation: the rigid residue over the suspension's denominator, the
    # chain's flexible modes from python-control (the rigid part removed), the added mode
    s = 2j * np.pi * FREQ
    wr = 2 * np.pi * 3.0
    core = np.einsum("f,yu->fyu", 1 / (s**2 + 2 * 0.1 * wr * s + wr**2), sum(res[w == 0]))
    for r, wk, zk in zip(res[w > 0], w[w > 0], zeta[w > 0]):
        core += np.einsum("f,yu->fyu", 1 / (s**2 + 2 * zk * wk * s + wk**2), r)
    w7 = 2 * np.pi * 700.0
    core += (N0[None] + s[:, None, None] * N1[None]) / (s**2 + 2 * 0.03 * w7 * s + w7**2)[
        :, None, None
    ]
    core += D[None]
    Hu = 1 / (1 + s[:, None] * tau_in[None])
    Hy = 1 / (1 + s[:, None] * tau_out[None])
    G = np.einsum("ab,fb,fbu,fu,uc->fac", T_out, Hy, core, Hu, T_in)
    G *= np.exp(-s * 2e-4)[:, None, None]
    assert rel(mm.frf(FREQ), G) < 1e-9
    ss = mm.to_lti()
    assert rel(ss.frf(FREQ), G) < 1e-9
    assert ss.n_x == 2 + 2 * 3 + 2 * 2 + 3  # rigid (rank 1), 3 modes, added (rank 2), 3 lags
    # ZOH simulation mode by mode = the realization's ZOH simulation
    u = rng.standard_normal((2000, 2))
    y_ref = sim.simulate_zoh(ss.without_delay().to_statespace(), u, 5000.0, delay_s=2e-4)
    assert rel(mm.simulate(u, 5000.0), y_ref) < 1e-7
    # what the modal model cannot hold is refused in one line
    with pytest.raises(InputError) as exc:
        ModalModel(modes=(), D=np.zeros((3, 2)), tau_in=np.array([1e-4]))
    assert "tau_in" in str(exc.value) and "\n" not in str(exc.value)


def test_overdamped_moved_mode_is_realized():
    """A rigid body on a stiff, overdamped suspension (z = 1.5, the diagnosis allows up to 2)
    with a full-rank residue: the realization reproduces N0 / (s^2 + 2 z w s + w^2)."""
    rng = np.random.default_rng(4)
    N0 = rng.standard_normal((2, 2))
    rigid = Mode("rigid", 0.0, 0.0, np.zeros(2), np.zeros(2), N0=N0, N1=np.zeros((2, 2)))
    mm = ModalModel(modes=(rigid.moved(20.0, 1.5),), D=np.zeros((2, 2)))
    s = 2j * np.pi * FREQ
    w0 = 2 * np.pi * 20.0
    G = N0[None] / (s**2 + 3.0 * w0 * s + w0**2)[:, None, None]
    assert rel(mm.frf(FREQ), G) < 1e-12
    for form in ("companion", "scaled"):
        ss = mm.to_statespace(form=form)
        assert ss.nstates == 4 and rel(lti.frf(ss, FREQ), G) < 1e-9
    with pytest.raises(InputError, match="real pole"):
        Mode("real", 10.0, 1.0, np.ones(2), np.ones(2)).moved(5.0, 0.1)


def test_decompose_is_the_exact_modal_decomposition():
    """Diagnosis's decompose: the rigid modes as one s^2 mode with their summed,
    full-rank residue (one rigid mode per output DOF here), equal to the oracle."""
    sys, w, zeta, res = chain(n_dof=3)
    sys = control.ss(sys.A, sys.B, sys.C[:2], sys.D[:2])  # 2 outputs
    em = decompose(LTIModel.from_statespace(sys, delay_s=2e-4))
    assert isinstance(em, ModalModel) and em.delay_s == 2e-4
    assert rel(em.frf(FREQ), lti.frf(sys, FREQ, delay_s=2e-4)) < 1e-9
    assert em.modes[0].kind == "rigid"
    assert np.allclose(em.modes[0].numerator()[0], res[0][:2], atol=1e-9 * np.abs(res).max())
    for m, wk, zk in zip(em.modes[1:], w[1:], zeta[1:]):
        assert m.freq_hz == pytest.approx(wk / (2 * np.pi), rel=1e-9)
        assert m.damping == pytest.approx(zk, rel=1e-6)
    # two rigid bodies: the summed residue has rank two
    sys2 = control.append(control.ss([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], 0), sys[0, 0])
    em2 = decompose(sys2)
    assert em2.modes[0].kind == "rigid"
    assert np.linalg.matrix_rank(em2.modes[0].numerator()[0]) == 2
    assert rel(em2.frf(FREQ), lti.frf(sys2, FREQ)) < 1e-9


def test_plant_modal_set_to_modal_model():
    from plants.modal import ModalSet

    sys, w, zeta, res = chain()
    # the oracle's modes as a plant ModalSet (b_k, c_k from the rank-one residues)
    U, sv, Vt = zip(*(np.linalg.svd(r) for r in res))
    c = np.array([u[:, 0] * np.sqrt(s[0]) for u, s in zip(U, sv)])
    b = np.array([v[0] * np.sqrt(s[0]) for v, s in zip(Vt, sv)])
    ms = ModalSet(w / (2 * np.pi), zeta, b, c, ("rigid",) + ("flexible",) * 3)
    mm = ms.to_modal(delay_s=1e-4)
    assert mm.kinds == ("rigid", "flexible", "flexible", "flexible") and mm.delay_s == 1e-4
    assert rel(mm.frf(FREQ), lti.frf(sys, FREQ, delay_s=1e-4)) < 1e-9
    assert rel(mm.frf(FREQ, with_delay=False), ms.frf(FREQ)) < 1e-12


@pytest.mark.parametrize("name", ["wafer_stage", "beam"])
def test_plant_nominal_modes_as_modal_model(name):
    """The plants' ModalSet (their physical truth) through ModalSet.to_modal equals the
    plant's own nominal state space, and the one decomposition recovers its modes."""
    import plants

    plant = plants.get_plant(name)
    mm = plant.nominal_modal_model()
    G = lti.frf(plant.nominal_model(), FREQ)
    assert rel(mm.frf(FREQ), G) < 1e-9
    assert mm.input_names == tuple(plant.input_names)
    back = ModalModel.from_statespace(plant.nominal_model(), rigid_threshold_hz=1e-3)
    flex = [m for m in mm.modes if m.kind == "flexible"]
    got = [m for m in back.modes if m.kind == "flexible"]
    assert len(got) == len(flex)
    for a, b in zip(flex, got):
        assert b.freq_hz == pytest.approx(a.freq_hz, rel=1e-9)
        assert b.damping == pytest.approx(a.damping, rel=1e-7)
        assert np.allclose(
            np.outer(b.c, b.b),
            np.outer(a.c, a.b),
            atol=1e-8 * np.abs(a.c).max() * np.abs(a.b).max(),
        )


def test_mode_validation_is_one_line():
    with pytest.raises(InputError) as exc:
        Mode("flexible", 10.0, 0.01, np.ones(2), np.ones(3), N0=np.ones((2, 2)))
    assert "N0" in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(InputError):
        ModalModel(modes=(), D=np.zeros((1, 1)), delay_s=-1.0)


def test_minimality_refuses_what_its_lemmas_do_not_cover():
    from workbench.modal.minimality import check_minimality

    sys, _, _, _ = chain()
    check_minimality(ModalModel.from_statespace(sys))  # the ideal form: accepted
    with pytest.raises(InputError) as exc:
        check_minimality(ModalModel.from_statespace(sys, exact=True))
    assert "ideal modal model" in str(exc.value) and "\n" not in str(exc.value)
