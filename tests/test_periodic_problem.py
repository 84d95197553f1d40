"""The frequency-domain fit of periodic time records (workbench.diagnosis.problem.PeriodicProblem).

Oracles, independent of the code under test: scipy.signal.cont2discrete (ZOH) with
scipy.signal.freqz for the sampled filters' responses, and records simulated by
scipy.signal.dlsim of the exactly sampled state space (or a plain state recursion
with a PD loop), started at rest or cut from mid-motion. On a noise-free record the
true model must fit to rounding on the steady-state lines, although lightly damped
slow modes and the rigid body have not settled (the transient term takes them), and
the linear fits must recover a missing mode's numerator exactly.
"""

from __future__ import annotations

from dataclasses import replace

import control
import numpy as np
import pytest
import scipy.linalg
import scipy.signal

import workbench.diagnosis.fit as fit_engine
from workbench.core.errors import InputError
from workbench.diagnosis.diagnose import base_model, diagnose
from workbench.diagnosis.effects import ActuatorDynamics, ModalMismatch, TimeDelay
from workbench.diagnosis.problem import SETTLED, PeriodicProblem, TimeProblem, make_problem
from workbench.io.formats import TimeData
from workbench.modal.model import ModalModel, Mode
from workbench.modal.simulate import (
    filtered_inputs,
    filtered_lines,
    simulate,
    zoh_filter,
    zoh_response,
)

FS = 1000.0
PERIOD = 1000


def _multisine(rng, n_in: int, periods: int) -> np.ndarray:
    """Random-phase multisine, lines 1..300 of the period, repeated ``periods`` times."""
    U = np.zeros((PERIOD // 2 + 1, n_in), complex)
    U[1:301] = np.exp(2j * np.pi * rng.random((300, n_in)))
    u = np.fft.irfft(U, n=PERIOD, axis=0)
    return np.tile(u / u.std(axis=0), (periods, 1))


@pytest.mark.parametrize(
    "num, den, delay",
    [
        ([1.0], [1.0, 2 * 0.02 * 300.0, 300.0**2], 0.0),
        ([1.0, 0.0], [1.0, 2 * 0.05 * 800.0, 800.0**2], 0.0),
        ([2.0, 1.0], [1.0, 30.0], 0.003),  # proper, with a direct term, a whole-sample delay
        ([1.0], [1e-3, 1.0, 0.0, 0.0], 0.0),  # a rigid body behind a lag
    ],
)
def test_zoh_response_equals_scipy_zoh_and_freqz(num, den, delay):
    dt = 1.0 / FS
    (b, a, _) = scipy.signal.cont2discrete((num, den), dt, method="zoh")
    w = np.linspace(0.01, np.pi - 0.01, 200)
    m = round(delay / dt)
    _, h_ref = scipy.signal.freqz(np.ravel(b), a, worN=w)
    h_ref = h_ref * np.exp(-1j * w * m)
    h = zoh_response(num, den, np.exp(1j * w), dt, delay)
    assert np.max(np.abs(h - h_ref)) <= 1e-9 * np.max(np.abs(h_ref))


def _physical_rigid_body(taus):
    """(A, B) of a unit mass behind first-order lags ``taus`` (s): states (position, velocity,
    then the lags' outputs, the force last but one), a state space independent of the
    companion form the code under test factors."""
    n = 2 + len(taus)
    A, B = np.zeros((n, n + 1)), np.zeros((n, 1))
    A[0, 1] = A[1, 2] = 1.0  # x' = v, v' = the first lag's output (or u: column n)
    for i, tau in enumerate(taus):  # lag i: y_i' = (y_{i+1} - y_i) / tau, the last one's input u
        A[2 + i, 2 + i] = -1.0 / tau
        A[2 + i, 3 + i] = 1.0 / tau
    B[:, 0], A = A[:, n], A[:, :n]
    return A, B


def _held_response(A, B, C, z, dt, frac):
    """C (zI - Ad)^-1 (B0 + B1 / z) of the ZOH with an input delay ``frac`` < dt (the two-interval
    integral of c2d_zoh, by the block matrix exponential), solved per point."""

    def phi_gamma(h):
        n = A.shape[0]
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n:] = A * h, B * h
        E = scipy.linalg.expm(M)
        return E[:n, :n], E[:n, n:]

    Ad, B0 = phi_gamma(dt - frac)
    B1 = np.zeros_like(B0)
    if frac > 0:
        P, G = phi_gamma(frac)
        Ad, B1 = Ad @ P, Ad @ G
    eye = np.eye(A.shape[0])
    return np.array([(C @ np.linalg.solve(zz * eye - Ad, B0 + B1 / zz)).item() for zz in z])


@pytest.mark.parametrize("taus", [(), (3e-4,), (1e-4, 5e-4), (2e-2,)])
@pytest.mark.parametrize("frac", [0.0, 0.3, 0.97])
def test_rigid_body_behind_lags_responds_as_its_physical_state_space(taus, frac, monkeypatch):
    """1/s^2 and s/s^2 behind lags, with a fractional delay: the closed form's line
    responses equal those of the physical state space sampled by the matrix exponential,
    to 1e-9 at every line (the companion form's characteristic polynomials lost up to 1e-5
    at the low lines), and the closed form needs no matrix exponential of its own."""
    import workbench.modal.simulate as sim

    def no_expm(*args):
        raise AssertionError("the rigid body fell back to the matrix exponential")

    monkeypatch.setattr(sim, "_zoh_coefficients", no_expm)
    dt = 1.0 / 5000.0
    z = np.exp(1j * np.linspace(0.003, np.pi - 0.003, 300))
    den = np.array([1.0, 0.0, 0.0])
    for tau in taus:
        den = np.convolve(den, [tau, 1.0])
    A, B = _physical_rigid_body(list(taus))
    delay = (2 + frac) * dt  # whole samples too
    for num, row in (([1.0], 0), ([1.0, 0.0], 1)):
        h_ref = _held_response(A, B, np.eye(A.shape[0])[row : row + 1], z, dt, frac * dt)
        h_ref = h_ref * z**-2
        h = zoh_response(num, den, z, dt, delay)
        assert np.max(np.abs(h - h_ref) / np.abs(h_ref)) <= 1e-9


def test_filtered_lines_are_the_steady_state_dft_of_filtered_inputs():
    """With lags and a fractional delay: the DFT of the last period of the time filter."""
    rng = np.random.default_rng(1)
    sys = _two_mode_plant()
    model = ModalModel.from_statespace(sys, exact=True)
    model = replace(model, delay_s=0.37e-3)
    u = _multisine(rng, 2, 40)
    den = np.array([2 * 0.05 * 2 * np.pi * 50.0, (2 * np.pi * 50.0) ** 2])
    X, _ = filtered_inputs(model, den, u, FS)
    lines = np.arange(1, 301)
    U = np.fft.rfft(u[-PERIOD:], axis=0)[lines]
    Xl, _ = filtered_lines(model, den, U, np.exp(2j * np.pi * lines / PERIOD), FS)
    ref = np.fft.rfft(X[:, -PERIOD:], axis=1)[:, lines]
    assert np.max(np.abs(Xl - ref)) <= 1e-9 * np.max(np.abs(ref))
    # and one filter alone against zoh_filter's steady state
    y = zoh_filter([1.0], [1.0, *den], u[:, :1], 1 / FS, 0.37e-3)
    H = zoh_response([1.0], [1.0, *den], np.exp(2j * np.pi * lines / PERIOD), 1 / FS, 0.37e-3)
    Y = np.fft.rfft(y[-PERIOD:], axis=0)[lines, 0]
    assert np.max(np.abs(Y - H * U[:, 0])) <= 1e-9 * np.max(np.abs(Y))


def _two_mode_plant(slow_hz: float = 3.0) -> control.StateSpace:
    """2 x 2 open-loop: a slow, lightly damped mode (0.5 %) and a 120 Hz mode (2 %)."""
    blocks = []
    for f, z in ((slow_hz, 0.005), (120.0, 0.02)):
        w = 2 * np.pi * f
        blocks.append(np.array([[0.0, 1.0], [-(w**2), -2 * z * w]]))
    A = scipy.linalg.block_diag(*blocks)
    B = np.array([[0, 0], [1.0, 0.5], [0, 0], [0.4, -1.0]])
    # the 120 Hz mode weighted up: its response is (120 / 3)^2 below the slow mode's
    C = np.array([[1.0, 0, 600.0, 0], [0.5, 0, -400.0, 0]]) * 1e-3
    return control.ss(A, B, C, np.zeros((2, 2)))


def _open_loop_record(sys, periods: int = 4, n_skip: int = 0, seed: int = 0) -> TimeData:
    rng = np.random.default_rng(seed)
    u = _multisine(rng, 2, periods + n_skip // PERIOD)
    d = scipy.signal.cont2discrete((sys.A, sys.B, sys.C, sys.D), 1 / FS, method="zoh")
    _, y, _ = scipy.signal.dlsim(d[:4] + (1 / FS,), u)
    u, y = u[n_skip:], y[n_skip:]
    return TimeData(FS, u, y, period=PERIOD, input_names=("F1", "F2"), output_names=("y1", "y2"))


def test_true_model_fits_to_rounding_although_the_slow_mode_has_not_settled():
    sys = _two_mode_plant()  # the 3 Hz mode at 0.5 % decays by 1/e in 10 s: 10 periods
    data = _open_loop_record(sys)
    problem = make_problem(data)
    assert isinstance(problem, PeriodicProblem)
    base = base_model(sys, data)
    wrong = base_model(_two_mode_plant(slow_hz=3.1), data)
    c_true, c_wrong = problem.cost(base), problem.cost(wrong)
    # rms misfit per row <= SETTLED of the record's rms: the 120 Hz mode's start transient is
    # 3e-7 of its value after the dropped period, below SETTLED, and left out of the basis
    assert c_true <= SETTLED**2 * problem.n_obs
    assert c_wrong >= 1e8 * c_true
    # without the transient term the unsettled mode's leakage is a misfit far above rounding
    saved = problem._start_basis
    problem._start_basis = lambda model: None
    problem._cache.clear()
    assert problem.cost(base) >= 1e6 * max(c_true, 1e-30)
    problem._start_basis = saved
    # the reported error is the time-domain measure, the same number as the time problem's
    assert problem.error(base) == TimeProblem(data).error(base)


def test_a_record_cut_mid_motion_fits_the_same():
    sys = _two_mode_plant()
    data = _open_loop_record(sys, n_skip=3 * PERIOD)
    problem = make_problem(data)
    assert isinstance(problem, PeriodicProblem)
    assert problem.cost(base_model(sys, data)) <= SETTLED**2 * problem.n_obs


def test_linear_fit_recovers_a_missing_modes_numerator():
    sys = _two_mode_plant()
    data = _open_loop_record(sys)
    problem = make_problem(data)
    full = base_model(sys, data)
    k = max(range(len(full.modes)), key=lambda i: full.modes[i].freq_hz)  # the 120 Hz mode
    missing = replace(full, modes=tuple(m for i, m in enumerate(full.modes) if i != k))
    N0, N1, _, _ = problem.fit_new_term(missing, full.modes[k].denominator())
    N0_true, N1_true = full.modes[k].numerator()
    scale = np.max(np.abs(N0_true))
    assert np.max(np.abs(N0 - N0_true)) <= 1e-7 * scale
    assert np.max(np.abs(N1 - (0 if N1_true is None else N1_true))) <= 1e-7 * scale


def test_domain_choice_and_refusals():
    sys = _two_mode_plant()
    data = _open_loop_record(sys)
    assert isinstance(make_problem(data, domain="time"), TimeProblem)
    assert isinstance(make_problem(data, domain="frequency"), PeriodicProblem)
    # one period, or a period set but an excitation that never repeats, from rest: no steady
    # state to fit on, the simulation; "frequency" the whole record's (test_record_problem.py)
    one_period = TimeData(FS, data.u[:PERIOD], data.y[:PERIOD], period=PERIOD)
    noise = np.random.default_rng(2).standard_normal(data.u.shape)
    not_periodic = TimeData(FS, noise, data.y, period=PERIOD)
    for record in (one_period, not_periodic):
        assert isinstance(make_problem(record), TimeProblem)
        assert make_problem(record, domain="frequency").whole
    assert not make_problem(data, domain="frequency").whole
    # too few lines for the transient terms: the simulation; "frequency" refuses it
    short = TimeData(FS, data.u[:20], data.y[:20])
    assert isinstance(make_problem(short), TimeProblem)
    with pytest.raises(InputError, match="domain 'frequency': expected >= 20 lines"):
        make_problem(short, domain="frequency")
    with pytest.raises(InputError, match="domain: expected one of"):
        make_problem(data, domain="fourier")


def test_both_domains_find_the_same_mismatch():
    """A 120 Hz mode modelled at 126 Hz, 0.5 % output noise: both name it, within 0.2 %."""
    truth = _two_mode_plant()
    data = _open_loop_record(truth, periods=5)
    rng = np.random.default_rng(5)
    y = data.y + 0.005 * data.y.std(axis=0) * rng.standard_normal(data.y.shape)
    data = TimeData(FS, data.u, y, period=PERIOD)
    A = np.array(truth.A)
    w = 2 * np.pi * 126.0
    A[3, 2], A[3, 3] = -(w**2), -2 * 0.02 * w
    model = control.ss(A, truth.B, truth.C, truth.D)
    found = {}
    for domain in ("frequency", "time"):
        top = diagnose(model, data, domain=domain).findings[0]
        assert top.effect == "modal_mismatch", (domain, top.effect)
        found[domain] = top.parameters["freq_hz"]
    assert found["frequency"] == pytest.approx(120.0, rel=2e-3)
    assert found["time"] == pytest.approx(120.0, rel=2e-3)


def _suspended_body_between_lines(seed=3, fs=512.0, period=625, n_per=4, noise=2e-3):
    """A two-DOF body on springs (suspension modes 2.55 / 2.68 Hz, zeta 0.10 / 0.12) under a
    periodic odd multisine from its 3rd line (2.46 Hz; the next 4.10 Hz), from rest.

    Returns (free-body nominal, TimeData, true frequencies, noise floor error). The record
    by scipy's ZOH discretization and ``dlsim``; sensor noise ``noise`` of each output's rms.
    """
    rng = np.random.default_rng(seed)
    M = np.diag([2.0, 0.05])
    f, z = np.array([2.55, 2.68]), np.array([0.10, 0.12])
    Q, _ = np.linalg.qr(rng.standard_normal((2, 2)))
    Mh = np.sqrt(M)
    K = Mh @ Q @ np.diag((2 * np.pi * f) ** 2) @ Q.T @ Mh
    lam, phi = scipy.linalg.eigh(K, M)
    w = np.sqrt(lam)
    inv = np.linalg.inv(phi)
    D = inv.T @ np.diag(2 * z * w) @ inv  # lam ascending, f ascending: z in mode order
    B = np.array([[1.0, 1.0, 0.0], [0.1, -0.1, 0.05]])
    C = np.array([[1.0, 0.2], [1.0, -0.2], [0.0, 1.0]])
    Minv = np.linalg.inv(M)

    def state_space(Kx, Dx):
        A = np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv @ Kx, -Minv @ Dx]])
        return A, np.vstack([np.zeros((2, 3)), Minv @ B]), np.hstack([C, 0 * C]), np.zeros((3, 3))

    k = np.arange(3, int(40 * period / fs), 2)
    t = np.arange(period)
    one = np.stack(
        [
            np.cos(2 * np.pi * np.outer(t, k) / period + rng.uniform(0, 2 * np.pi, k.size)).sum(1)
            for _ in range(3)
        ],
        axis=1,
    )
    u = np.tile(one / one.std(axis=0), (n_per, 1))
    sysd = scipy.signal.cont2discrete(state_space(K, D), 1 / fs, "zoh")
    _, y, _ = scipy.signal.dlsim(sysd[:4] + (1 / fs,), u)
    v = noise * y.std(axis=0) * rng.standard_normal(y.shape)
    floor = float(np.linalg.norm(v) / np.linalg.norm(y + v))
    nominal = control.ss(*state_space(0 * K, 0 * D))
    return nominal, TimeData(fs=fs, u=u, y=y + v, period=period), w / (2 * np.pi), floor


def test_modes_between_the_excited_lines_are_refitted_on_the_record():
    """Two suspension modes inside one gap of the excited lines: the lines' optimum leaves
    them poorly determined (4.0x the floor on the record and a false nonlinearity before
    the refit); refitted on the record (start and first period included) they are exact."""
    nominal, data, f_true, floor = _suspended_body_between_lines()
    d = diagnose(nominal, data)
    assert d.data_kind == "time"
    assert [f.effect for f in d.findings] == ["suspension_stiffness"]
    top = d.findings[0]
    found = sorted(m["freq_hz"] for m in top.parameters["modes"])
    assert np.allclose(found, f_true, rtol=2e-3), (found, f_true)
    assert top.error_after < 1.2 * floor, top.error_after / floor


def _noisy_periodic_record(truth: ModalModel, periods: int = 4, seed: int = 7) -> TimeData:
    """The record of ``truth`` (exact ZOH simulation, :func:`simulate`) to the multisine, 0.5 %
    output noise."""
    rng = np.random.default_rng(seed)
    u = _multisine(rng, truth.n_u, periods)
    y = simulate(truth, u, FS)
    y = y + 0.005 * y.std(axis=0) * rng.standard_normal(y.shape)
    return TimeData(FS, u, y, period=PERIOD)


@pytest.mark.parametrize("effect", ["modal_mismatch", "time_delay", "actuator_dynamics"])
def test_levenberg_marquardt_on_the_lines_matches_trust_region_reference(effect, monkeypatch):
    """A periodic record's fits (Levenberg-Marquardt on finite-difference normal equations)
    reach the optimum scipy's trust-region reflective search (``FRF_SOLVER = "trf"``, the
    engine before) reaches from the same starts, with the same standard deviations."""
    base = base_model(_two_mode_plant(), TimeData(FS, np.zeros((4, 2)), np.zeros((4, 2))))
    k = max(range(len(base.modes)), key=lambda i: base.modes[i].freq_hz)  # the 120 Hz mode
    if effect == "modal_mismatch":
        modes = list(base.modes)
        modes[k] = modes[k].moved(114.0, 0.03)
        truth, structure = replace(base, modes=tuple(modes)), ModalMismatch(index=k)
    elif effect == "time_delay":
        truth, structure = replace(base, delay_s=1.37e-3), TimeDelay()
    else:  # a 90 Hz lag on input 0, none on input 1
        truth = replace(base, tau_in=np.array([1 / (2 * np.pi * 90.0), 0.0]))
        structure = ActuatorDynamics()
    data = _noisy_periodic_record(truth)
    problem = make_problem(data)
    assert isinstance(problem, PeriodicProblem)
    ours = fit_engine.fit(structure, problem, base)
    monkeypatch.setattr(fit_engine, "FRF_SOLVER", "trf")
    ref = fit_engine.fit(structure, make_problem(data), base)
    assert ours.cost <= ref.cost * (1 + 1e-6)
    assert np.allclose(ours.theta, ref.theta, rtol=1e-4, atol=1e-6)
    assert np.allclose(ours.theta_std, ref.theta_std, rtol=0.05)
    # and the optimum is the truth's, within the noise
    assert ours.cost <= 1.1 * problem.cost(truth)


def test_cached_line_responses_are_the_responses_computed_afresh():
    """filtered_lines with a response cache shared by models whose lags differ on one input:
    every filter the cache gives is the one computed without it, bit for bit."""
    base = replace(ModalModel.from_statespace(_two_mode_plant(), exact=True), delay_s=0.37e-3)
    lines = np.arange(1, 301)
    z = np.exp(2j * np.pi * lines / PERIOD)
    U = np.exp(2j * np.pi * np.random.default_rng(4).random((lines.size, 2)))
    responses: dict = {}
    for tau_in in ([0.0, 0.0], [1e-3, 0.0], [1e-3, 2e-4], [1e-3, 0.0], [0.0, 2e-4]):
        model = replace(base, tau_in=np.array(tau_in), tau_out=np.array([0.0, 5e-4]))
        for m in model.modes:
            den = m.denominator()
            X, groups = filtered_lines(model, den, U, z, FS, responses=responses)
            X_ref, groups_ref = filtered_lines(model, den, U, z, FS)
            assert np.array_equal(X, X_ref)
            assert all(np.array_equal(a, b) for a, b in zip(groups, groups_ref))
    assert len(responses) < 5 * len(base.modes) * 4  # filters reused across the models


def test_transient_basis_extended_by_a_moved_or_added_pole_spans_the_basis_afresh():
    """The basis a fit's moved (or added) slow mode gets from the other poles' basis
    (:meth:`PeriodicProblem._basis_near`) projects as the basis computed afresh does."""
    data = _open_loop_record(_two_mode_plant(), periods=3)
    problem = make_problem(data)
    base = base_model(_two_mode_plant(), data)
    k = min(range(len(base.modes)), key=lambda i: base.modes[i].freq_hz)  # 3 Hz, unsettled
    fresh = []
    problem._basis_of = lambda key, f=problem._basis_of: fresh.append(key) or f(key)
    models = []
    for j in range(5):
        modes = list(base.modes)
        modes[k] = modes[k].moved(3.0 * (1 + 0.01 * j), 0.005 * (1 + 0.1 * j))
        models.append(replace(base, modes=tuple(modes)))
    extra = Mode("flexible", 7.0, 0.004, np.zeros(2), np.zeros(2))
    models.append(replace(base, modes=base.modes + (extra,)))
    for model in models:
        Q = problem._start_basis(model)
        key = problem._transient_key(model)
        C = problem._columns(key[1], drift=True, n_delay=key[0])
        Q_ref = np.linalg.qr(np.concatenate([C.real, C.imag]))[0]
        assert Q.shape == Q_ref.shape
        assert np.max(np.abs(Q @ Q.T - Q_ref @ Q_ref.T)) <= 1e-9
    # computed afresh: the first model, the rest of the second; the others were extended
    assert len(fresh) == 2


def test_mixed_lines_is_the_filtered_inputs_mixed_by_the_numerators():
    """mixed_lines (a part's output at the lines from the filters' responses, lags per
    channel gathered) against filtered_lines' filtered inputs mixed by the numerators as the
    simulation mixes them; with lags on some inputs and outputs (several filters, the lag
    poles' roots given in closed form) and without (one filter)."""
    from workbench.modal.simulate import mixed_lines

    base = replace(ModalModel.from_statespace(_two_mode_plant(), exact=True), delay_s=0.37e-3)
    lines = np.arange(1, 301)
    z = np.exp(2j * np.pi * lines / PERIOD)
    rng = np.random.default_rng(5)
    U = rng.normal(size=(lines.size, 2)) + 1j * rng.normal(size=(lines.size, 2))
    for tau_in, tau_out in (([0.0, 0.0], [0.0, 0.0]), ([1e-3, 0.0], [0.0, 5e-4])):
        model = replace(base, tau_in=np.array(tau_in), tau_out=np.array(tau_out))
        for den, (N0, N1) in [(None, (base.D + 0.3, None))] + [
            (m.denominator(), m.numerator()) for m in model.modes
        ]:
            N1 = None if N1 is None else N1 + rng.normal(size=N1.shape)  # s/den used too
            X, groups = filtered_lines(model, den, U, z, FS)
            ref = np.zeros((lines.size, 2), complex)
            for g, rows in enumerate(groups):
                ref[:, rows] = X[g, :, :, 0] @ N0[rows].T
                if N1 is not None and den is not None and len(den) == 2:
                    ref[:, rows] += X[g, :, :, 1] @ N1[rows].T
            Y = mixed_lines(model, den, N0, N1, U, z, FS)
            assert np.max(np.abs(Y - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_a_grid_evaluated_together_costs_what_each_model_costs_alone():
    """PeriodicProblem.costs (a screen's grid: the same modes moved, numerators kept) against
    cost() model by model: a slow mode that has not settled (its transient columns extend
    the basis per point, some points settled), a settled one, both moved by a shared scale,
    and a grid with a model of another pattern (evaluated alone)."""
    from workbench.diagnosis.effects import ModalPattern

    data = _open_loop_record(_two_mode_plant(), periods=3, seed=3)
    problem = make_problem(data)
    base = base_model(_two_mode_plant(), data)
    slow = min(range(len(base.modes)), key=lambda i: base.modes[i].freq_hz)
    grids = []
    for k in range(len(base.modes)):
        s = ModalMismatch(k)
        # damping up to 0.5: the slow mode settles within the dropped period at some points
        thetas = [
            np.log([base.modes[k].freq_hz * a, zd])
            for a in (0.9, 1.0, 1.1)
            for zd in (0.002, 0.005, 0.05, 0.5)
        ]
        grids.append([s.build(t, problem, base).model for t in thetas])
    p = ModalPattern()
    grids.append(
        [
            p.build(np.log([a, b]), problem, base).model
            for a in (0.95, 1.05)
            for b in (0.5, 1.0, 2.0, 4.0)
        ]
    )
    grids.append(grids[0][:6] + [None] + grids[1][:4])  # two patterns, a failed build
    for models in grids:
        together = problem.costs(models)
        alone = np.array([np.inf if m is None else problem.cost(m) for m in models])
        # rounding: ~1e-16 of the rows' squared size (a true model's cost is itself rounding)
        scale = np.max(alone[np.isfinite(alone)])
        assert np.allclose(together, alone, rtol=1e-9, atol=1e-12 * scale)
    # the first grids were evaluated together, not model by model
    assert problem._moved_costs(grids[0]) is not None
    assert np.all(np.isfinite(problem._moved_costs(grids[0])[1][:8]))
    assert base.modes[slow].freq_hz < 10
