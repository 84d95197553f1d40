"""H-inf synthesis, Riccati (SB10AD on the bilinear image) and LMI: closed form, the two
methods and control.hinfsyn against each other, independent grid norm of the closed loop on
the true plant, double integrator, D22, refusals."""

from __future__ import annotations

import control
import numpy as np
import pytest

from controllers.hinf import (
    design_hinf_mixed,
    hinf_lmi,
    hinf_norm_grid,
    hinf_riccati,
    mixed_sensitivity,
    weight,
)
from controllers.protocol import Controller, StateSpaceController
from workbench.core.blas import limited_blas
from workbench.core.errors import InputError

FS = 1000.0
pytestmark = pytest.mark.filterwarnings("ignore:Solution may be inaccurate")


def _one(dt):
    return control.ss([], [], [], [[1.0]], dt)


def _loop(G, K):
    """S, K S, T of the spec-5 loop (u = K e, e = r - y) as discrete StateSpaces."""
    Ks = K.statespace()  # closed-loop realizations only (no uncancelled plant poles)
    return control.feedback(_one(G.dt), G * Ks), control.feedback(Ks, G), control.feedback(G * Ks)


def _t_zw(P, K):
    """T_zw of the generalized plant P closed by K (u = K v), by python-control's LFT."""
    return P.lft(K.statespace(), K.n_u, K.n_y)


def _const(gain):
    return control.ss([], [], [], [[gain]], 1 / FS)


def _second_order():
    return control.ss(control.tf([0.2, 0.1], [1.0, -1.5, 0.7], 1 / FS))  # stable, poles |z| 0.84


def _double_integrator(m=2.0):
    return control.sample_system(control.ss(control.tf([1 / m], [1.0, 0.0, 0.0])), 1 / FS, "zoh")


#: small mixed-sensitivity problems on stable plants (no pole shift: the design plant is the
#: true one): (G, W1, W2, W3)
SMALL = {
    "2nd-order W1 W2 W3": lambda: (
        _second_order(),
        weight(50.0, 15.0, 0.5, FS),
        _const(0.05),
        weight(0.5, 150.0, 50.0, FS),
    ),
    "2nd-order W1 W2": lambda: (_second_order(), weight(50.0, 15.0, 0.5, FS), _const(0.05), None),
    "biproper (D22) W1 W2": lambda: (
        control.ss(control.tf([0.3, -0.1], [1.0, -0.8], 1 / FS)),
        weight(10.0, 20.0, 0.5, FS),
        _const(0.1),
        None,
    ),
}


def test_first_order_gamma_equals_closed_form():
    # G = b / (z - p) stable, minimum phase, relative degree 1; W1 stable and
    # minimum phase. S(inf) = 1 for every proper K, so by the maximum modulus
    # principle ||W1 S||inf >= |W1(inf)| = |D_W1|, and S = D_W1 / W1 reaches it
    # (Youla Q = (1 - D_W1/W1)/G is proper and stable): gamma_opt = |D_W1|.
    G = control.ss(control.tf([0.5], [1.0, -0.9], 1 / FS))
    W1 = weight(10.0, 20.0, 0.5, FS)
    gamma_ref = abs(float(W1.D[0, 0]))
    K, rep = design_hinf_mixed(G, W1, method="lmi")  # riccati refuses W1 alone, see below
    assert isinstance(K, Controller) and K.fs == FS
    assert rep.pole_shift == 0.0 and rep.solver in ("CLARABEL", "SCS")
    assert rep.gamma == pytest.approx(gamma_ref, rel=0.02)
    S, _, _ = _loop(G, K)
    assert np.max(np.abs(S.poles())) < 1.0
    achieved = hinf_norm_grid(W1 * S, 4000)
    assert achieved <= rep.gamma * (1 + 1e-3)
    assert achieved >= gamma_ref * (1 - 1e-3)  # no controller beats the closed form


def test_weight_gains():
    W = weight(100.0, 20.0, 0.5, FS)
    mag = lambda f: abs(complex(W(np.exp(2j * np.pi * f / FS)).squeeze()))  # noqa: E731
    assert mag(0.0) == pytest.approx(100.0, rel=1e-9)
    assert mag(20.0) == pytest.approx(1.0, rel=1e-9)
    assert mag(FS / 2) == pytest.approx(0.5, rel=1e-9)
    with pytest.raises(InputError, match="opposite sides"):
        weight(2.0, 20.0, 3.0, FS)
    with pytest.raises(InputError, match="fs/2"):
        weight(100.0, 600.0, 0.5, FS)


@pytest.mark.parametrize("method", ["riccati", "lmi"])
def test_mixed_sensitivity_closed_loop_matches_gamma(method):
    G = control.ss(control.tf([0.2, 0.1], [1.0, -1.5, 0.7], 1 / FS))  # stable 2nd order
    W1, W2 = weight(50.0, 15.0, 0.5, FS), control.ss([], [], [], [[0.05]], 1 / FS)
    W3 = weight(0.5, 150.0, 50.0, FS)
    K, rep = design_hinf_mixed(G, W1, W2, W3, method=method)
    assert rep.method == method
    S, KS, T = _loop(G, K)
    assert np.max(np.abs(S.poles())) < 1.0
    nrm = max(
        hinf_norm_grid(W1 * S, 3000), hinf_norm_grid(W2 * KS, 3000), hinf_norm_grid(W3 * T, 3000)
    )
    # The stacked norm is >= each block's norm and <= sqrt(3) times the max.
    assert nrm <= rep.gamma * (1 + 1e-3)
    assert nrm >= rep.gamma / np.sqrt(3) * 0.9


@pytest.mark.parametrize("method", ["riccati", "lmi"])
def test_double_integrator_rigid_body(method):
    G = _double_integrator()
    W1 = weight(100.0, 10.0, 0.5, FS)
    W3 = weight(0.5, 200.0, 100.0, FS)
    K, rep = design_hinf_mixed(G, W1, None, W3, method=method)
    assert rep.pole_shift == pytest.approx(1e-3)
    S, _, T = _loop(G, K)  # the TRUE plant, integrators on the unit circle
    assert np.max(np.abs(S.poles())) < 1.0
    assert hinf_norm_grid(W1 * S, 8000) <= rep.gamma * (1 + 1e-3)
    assert hinf_norm_grid(W3 * T, 8000) <= rep.gamma * (1 + 1e-3)
    # A usable design, not just a stable one: W1 asks |S| < 1 below ~10 Hz.
    f = np.logspace(-1, np.log10(FS / 2.1), 4000)
    s_mag = np.abs(S(np.exp(2j * np.pi * f / FS)).squeeze())
    # -3 dB sensitivity bandwidth (measured 16.6 Hz lmi, 25.1 Hz riccati)
    bw_hz = f[np.argmax(s_mag > 1 / np.sqrt(2))]
    assert bw_hz > 10.0


def test_infeasible_and_bad_input_refused():
    dt = 1 / FS
    # Unstable mode (z = 1.2) that u cannot reach: not stabilizable -> infeasible.
    A = np.diag([1.2, 0.5])
    B = np.array([[1.0, 0.0], [0.0, 1.0]])  # w reaches the unstable state, u does not
    C = np.array([[1.0, 1.0], [1.0, 1.0]])
    D = np.array([[0.0, 1.0], [1.0, 0.0]])
    with pytest.raises(InputError, match="infeasible") as exc:
        hinf_lmi(control.ss(A, B, C, D, dt), 1, 1)
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match="discrete"):
        hinf_lmi(control.ss(A, B, C, D), 1, 1)
    with pytest.raises(InputError, match="exogenous"):
        hinf_lmi(control.ss(A, B, C, D, dt), 1, 2)
    G = control.ss(control.tf([0.5], [1.0, -0.9], dt))
    with pytest.raises(InputError, match="gamma_max"):
        design_hinf_mixed(G, weight(10.0, 20.0, 0.5, FS), gamma_max=0.1)
    with pytest.raises(InputError, match="dt"):
        mixed_sensitivity(G, weight(10.0, 20.0, 0.5, 2 * FS))
    with pytest.raises(InputError, match="at least one weight"):
        mixed_sensitivity(G)


@pytest.mark.parametrize("method", ["riccati", "lmi"])
def test_controller_is_statespace_controller(method):
    G = control.ss(control.tf([0.5], [1.0, -0.9], 1 / FS), inputs=["f"], outputs=["x"])
    K, _ = design_hinf_mixed(G, weight(10.0, 20.0, 0.5, FS), _const(0.1), method=method)
    assert isinstance(K, StateSpaceController)
    assert K.input_names == ("x",) and K.output_names == ("f",)
    u, st = K.step(K.init(), np.array([1.0]))
    assert u.shape == (1,) and np.all(np.isfinite(u))


def test_gamma_against_hinfsyn():
    # hinfsyn (slycot sb10ad) is continuous time; the bilinear map z <-> s keeps
    # the H-inf norm and maps proper controllers to proper controllers, so the
    # optimal gamma of P and of its Tustin inverse agree.
    G = control.ss(control.tf([0.2, 0.1], [1.0, -1.5, 0.7], 1 / FS))
    W1, W2 = weight(50.0, 15.0, 0.5, FS), control.ss([], [], [], [[0.05]], 1 / FS)
    P, nm, nc, _ = mixed_sensitivity(G, W1, W2)
    _, rep = hinf_lmi(P, nm, nc)
    # Inverse Tustin z = (1 + s T/2) / (1 - s T/2), written out (no d2c helper needed).
    A, B, C, D = (np.asarray(x) for x in (P.A, P.B, P.C, P.D))
    T = P.dt
    E = np.linalg.inv(np.eye(A.shape[0]) + A)
    Ac = (2 / T) * E @ (A - np.eye(A.shape[0]))
    Bc = (2 / np.sqrt(T)) * E @ B
    Cc = (2 / np.sqrt(T)) * C @ E
    Dc = D - C @ E @ B
    Pc = control.ss(Ac, Bc, Cc, Dc)
    with limited_blas(1):  # SB10AD's ~330 bisection steps from gamma = 1e100: 0.2 s, not 3 s
        _, _, gam, _ = control.hinfsyn(Pc, nmeas=nm, ncon=nc)  # as its documentation calls it
    assert rep.gamma_opt == pytest.approx(float(gam), rel=0.03)
    # hinf_riccati runs the same SB10AD from a finite start gamma (hinfsyn: 1e100) on a
    # state-scaled image: the same optimum to the bisection's accuracy (measured 7e-9 here,
    # up to 4e-5 on the stage's channel plants)
    _, ric = hinf_riccati(P, nm, nc)
    assert ric.gamma_opt == pytest.approx(float(gam), rel=1e-4)


@pytest.mark.parametrize("case", list(SMALL), ids=list(SMALL))
def test_riccati_gamma_agrees_with_lmi(case):
    # Two independent syntheses of one problem (SB10AD's Riccati gamma iteration on the
    # bilinear image; the discrete bounded-real LMI by an interior-point solver): on these
    # well-scaled plants their optimal gammas agree to 1e-3 (measured <= 8e-4, the LMI
    # above: its "optimal_inaccurate" 2nd-order W1 W2 case is the largest).
    G, W1, W2, W3 = SMALL[case]()
    P, nm, nc, rho = mixed_sensitivity(G, W1, W2, W3)
    assert rho == 1.0  # stable plants: the design plant is the true one
    _, ric = hinf_riccati(P, nm, nc)
    _, lmi = hinf_lmi(P, nm, nc)
    assert ric.method == "riccati" and ric.solver == "slycot.sb10ad" and lmi.method == "lmi"
    assert ric.gamma_opt == pytest.approx(lmi.gamma_opt, rel=1e-3)
    assert ric.gamma == pytest.approx(ric.gamma_opt * (1 + 1e-3), rel=1e-12)  # the backoff


@pytest.mark.parametrize("case", list(SMALL), ids=list(SMALL))
def test_riccati_closed_loop_attains_gamma_on_the_true_plant(case):
    # Oracle: the closed loop T_zw of the TRUE discrete plant (python-control's LFT of the
    # generalized plant, no pole shift needed here) with the controller mapped back by
    # Tustin, its norm by an independent grid evaluation. It is stable, below gamma, and
    # (any stabilizing controller is >= the optimum) above gamma_opt up to the grid.
    G, W1, W2, W3 = SMALL[case]()
    K, rep = design_hinf_mixed(G, W1, W2, W3)
    assert rep.method == "riccati" and rep.pole_shift == 0.0
    P, *_ = mixed_sensitivity(G, W1, W2, W3, pole_shift=0.0)
    T = _t_zw(P, K)
    assert np.max(np.abs(T.poles())) < 1.0
    nrm = hinf_norm_grid(T, 4000)
    # the central controller's loop sits at gamma itself (measured within 1e-6: rounding in
    # the bilinear maps), the grid (a lower bound) within 1e-6 of gamma or gamma_opt
    assert rep.gamma_opt * (1 - 1e-3) <= nrm <= rep.gamma * (1 + 1e-5)


def test_riccati_is_optimal_where_the_lmi_is_not_double_integrator():
    # ZOH double integrator (two poles at z = 1, shifted to 0.999 for the synthesis, its
    # zero at z = -1 shifted to -0.999): the LMI's optimum is 16 % above the Riccati one
    # (measured 0.6763 vs 0.5848), so "agree to 1e-3" does not hold here. What holds, by
    # the grid norm of T_zw on the design plant: the Riccati controller attains its gamma,
    # and the LMI's controller (any stabilizing one) does not beat the Riccati optimum.
    G = _double_integrator()
    W1, W3 = weight(100.0, 10.0, 0.5, FS), weight(0.5, 200.0, 100.0, FS)
    Kr, ric = design_hinf_mixed(G, W1, None, W3)
    Kl, lmi = design_hinf_mixed(G, W1, None, W3, method="lmi")
    P, *_ = mixed_sensitivity(G, W1, None, W3, pole_shift=ric.pole_shift)
    n_ric = hinf_norm_grid(_t_zw(P, Kr), 4000)
    n_lmi = hinf_norm_grid(_t_zw(P, Kl), 4000)
    assert ric.gamma_opt * (1 - 1e-3) <= n_ric <= ric.gamma * (1 + 1e-5)  # 9.5e-7 above
    assert n_lmi >= ric.gamma_opt * (1 - 1e-3)
    assert ric.gamma_opt <= lmi.gamma_opt
    # the true plant (integrators on the unit circle): stable, each block below gamma
    S, _, T = _loop(G, Kr)
    assert np.max(np.abs(S.poles())) < 1.0
    assert hinf_norm_grid(W1 * S, 4000) <= ric.gamma and hinf_norm_grid(W3 * T, 4000) <= ric.gamma


def _not_stabilizable():
    A = np.diag([1.2, 0.5])  # the unstable mode is reached by w only
    B = np.array([[1.0, 0.0], [0.0, 1.0]])
    C = np.array([[1.0, 1.0], [1.0, 1.0]])
    return control.ss(A, B, C, np.array([[0.0, 1.0], [1.0, 0.0]]), 1 / FS), 1, 1


def _z_without_u():
    A, B = np.diag([0.5, 0.5]), np.eye(2)  # x1 from w, x2 from u; z = x1
    C = np.array([[1.0, 0.0], [1.0, 1.0]])
    return control.ss(A, B, C, np.array([[0.0, 0.0], [1.0, 0.0]]), 1 / FS), 1, 1


def _mixed(G, *ws, pole_shift=1e-3):
    P, nm, nc, _ = mixed_sensitivity(G, *ws, pole_shift=pole_shift)
    return P, nm, nc


#: plants SB10AD cannot take, and the part of the message that names why
REFUSED = {
    "not stabilizable": (_not_stabilizable, "stabilizable from u"),
    "z does not see u": (_z_without_u, r"\[A - z I, B2; C1, D12\] of full column rank"),
    "integrators unshifted": (
        lambda: _mixed(
            _double_integrator(), weight(100.0, 10.0, 0.5, FS), _const(0.1), pole_shift=0.0
        ),  # fmt: skip
        r"\[A - z I, B1; C2, D21\] of full row rank.*pole_shift = 0",
    ),
    "P_zu zero at Nyquist": (
        # G(z = -1) = 0 exactly and no weight on u: D12 of the bilinear image is 0
        lambda: _mixed(
            control.ss(control.tf([0.1, 0.1], [1.0, -1.0, 0.25], 1 / FS)),
            weight(10.0, 20.0, 0.5, FS),
        ),  # fmt: skip
        r"D12 of the bilinear image, P_zu\(z = -1\), to have full column rank.*W2",
    ),
    "fewer w than v": (
        lambda: (
            control.ss(
                np.diag([0.5, 0.6]),
                [[1.0, 1.0], [1.0, 0.5]],
                [[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
                [[0.0, 1.0], [1.0, 0.0], [1.0, 0.0]],
                1 / FS,
            ),
            2,
            1,
        ),  # fmt: skip
        "D21 of full row rank, which needs",
    ),
    "W1 only: central controller ill-posed": (
        # D12 != 0 in the image, but the central controller's D_K = -1 / D22: infinite gain
        # at Nyquist in the true loop, at every gamma (the LMI designs it, see the closed form)
        lambda: _mixed(
            control.ss(control.tf([0.5], [1.0, -0.9], 1 / FS)), weight(10.0, 20.0, 0.5, FS)
        ),  # fmt: skip
        r"I \+ DK D22 singular.*add a constant W2",
    ),
}


@pytest.mark.parametrize("case", list(REFUSED), ids=list(REFUSED))
def test_riccati_refusals_name_the_assumption(case):
    make, match = REFUSED[case]
    P, nm, nc = make()
    with pytest.raises(InputError, match=match) as exc:
        hinf_riccati(P, nm, nc)
    assert "\n" not in str(exc.value) and "SB10AD" in str(exc.value)


def test_method_and_options_refused():
    G = control.ss(control.tf([0.5], [1.0, -0.9], 1 / FS))
    W1, W2 = weight(10.0, 20.0, 0.5, FS), _const(0.1)
    with pytest.raises(InputError, match="method: expected one of riccati, lmi, got 'hinfsyn'"):
        design_hinf_mixed(G, W1, W2, method="hinfsyn")
    with pytest.raises(InputError, match="bilinear: an option of method='lmi'"):
        design_hinf_mixed(G, W1, W2, bilinear=True)
    with pytest.raises(InputError, match="gamma_max"):
        design_hinf_mixed(G, W1, W2, gamma_max=0.1)
    P, nm, nc, _ = mixed_sensitivity(G, W1, W2)
    with pytest.raises(InputError, match="backoff"):
        hinf_riccati(P, nm, nc, backoff=0.0)
    with pytest.raises(InputError, match="discrete"):
        hinf_riccati(control.ss(P.A, P.B, P.C, P.D), nm, nc)
    from controllers.hinf import tune_hinf

    with pytest.raises(InputError, match="method"):
        tune_hinf(control.ss(-1.0, 1.0, 1.0, 0.0), fs=FS, method="LMI")


@pytest.mark.parametrize("method", ["riccati", "lmi"])
def test_plant_with_feedthrough_d22(method):
    # A biproper G gives D22 = -D_G != 0: the synthesis designs for D22 = 0 and
    # undoes it by the loop transformation K = K0 (I + D22 K0)^-1 (riccati: on the
    # bilinear image, whose D22 = -G(z = -1) is nonzero even for a strictly proper G).
    G = control.ss(control.tf([0.3, -0.1], [1.0, -0.8], 1 / FS))
    assert abs(float(G.D[0, 0])) > 0
    W1, W2 = weight(10.0, 20.0, 0.5, FS), control.ss([], [], [], [[0.1]], 1 / FS)
    K, rep = design_hinf_mixed(G, W1, W2, method=method)
    S, KS, _ = _loop(G, K)
    assert np.max(np.abs(S.poles())) < 1.0
    nrm = max(hinf_norm_grid(W1 * S, 3000), hinf_norm_grid(W2 * KS, 3000))
    assert nrm <= rep.gamma * (1 + 1e-3)
    assert nrm >= rep.gamma / np.sqrt(2) * 0.9


def test_tune_hinf_two_dof_meets_the_bound_with_all_loops_closed():
    # Two rigid DOFs (2 kg and 3 kg after decoupling) and one flexible mode at 1500 Hz
    # (damping 0.01) seen in both (the stage's situation, small), one sample of delay
    # inside the model at 5 kHz.
    from controllers.hinf import tune_hinf
    from workbench.core.model import LTIModel
    from workbench.modal.model import ModalModel, Mode

    fs = 5000.0
    modes = (
        Mode("rigid", 0.0, 0.0, b=[1 / np.sqrt(2.0), 0.0], c=[1 / np.sqrt(2.0), 0.0]),
        Mode("rigid", 0.0, 0.0, b=[0.0, 1 / np.sqrt(3.0)], c=[0.0, 1 / np.sqrt(3.0)]),
        Mode("flexible", 1500.0, 0.01, b=[0.2, 0.1], c=[0.2, -0.1]),
    )
    sys = ModalModel(modes=modes, D=np.zeros((2, 2))).to_statespace()
    model = LTIModel.from_statespace(
        sys, delay_s=1 / fs, input_names=("F1", "F2"), output_names=("x1", "x2")
    )
    d = tune_hinf(model, ms_max=2.0, fs=fs, n_scan=4, target_range=(0.02, 0.06))
    K = d.controller
    assert K.input_names == ("x1", "x2") and K.output_names == ("F1", "F2") and K.fs == fs
    # decentralized: no path from error 2 to force 1 or back (block-diagonal realization)
    Kf = K.statespace()(np.exp(2j * np.pi * np.array([10.0, 200.0]) / fs))
    assert np.max(np.abs(Kf[0, 1])) == 0.0 and np.max(np.abs(Kf[1, 0])) == 0.0
    # Independent oracle: python-control's ZOH of the continuous model, the delay as z^-1
    # per input, the MIMO loop closed by control.feedback.
    Gd = control.sample_system(control.ss(sys.A, sys.B, sys.C, sys.D), 1 / fs, "zoh")
    z1 = control.ss(control.tf([1.0], [1.0, 0.0], 1 / fs))
    Gd = Gd * control.append(z1, z1)
    S = control.feedback(control.ss([], [], [], np.eye(2), 1 / fs), Gd * K.statespace())
    assert np.max(np.abs(S.poles())) < 1.0
    f = np.geomspace(1.0, fs / 2 * 0.999, 3000)
    Sf = S(np.exp(2j * np.pi * f / fs))  # (2, 2, n_f)
    for i in range(2):
        assert np.max(np.abs(Sf[i, i])) <= 2.0 * (1 + 1e-3)
        Li = 1 / Sf[i, i] - 1  # loop i broken, the other closed (as analyze_loop)
        fc = f[np.argmax(np.abs(Li) < 1.0)]
        assert fc == pytest.approx(d.analysis.loops[i].crossover_hz, rel=0.02)
        assert fc > 30.0  # a working loop, not a token one
