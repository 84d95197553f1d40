"""A flexible body on a spring: the spring couples the suspended body to its flexible modes.

Oracle: an independent three-mass chain ``M q'' + D q' + K q = B u``, ``y = C q``
(masses 1.0 / 0.5 / 0.8 kg, springs 40 / 60 kN/m between them), hung on a 2 kN/m
spring to the world at mass 1. The nominal model is the free chain (one rigid mode,
two flexible ones at 36.50 and 81.53 Hz; the truth's 4.646, 36.86 and 81.54 Hz),
modal damping 0.02 in every mode; the truth's modes come from scipy's generalized
symmetric eigenproblem ``K phi = w^2 M phi`` and its FRF is evaluated directly
(``C (-w^2 M + j w D + K)^-1 B``). The spring acts at one mass, so in the free
chain's modes it adds ``k phi phi^T``: the suspended mode carries a little of the
flexible shapes and the flexible modes a little rigid motion and stiffness. A
suspension that only moves the rigid mode (and modal mismatches that only move the
flexible ones) leaves that: 30.9x the noise floor before the coupled suspension
(:class:`workbench.diagnosis.effects.CoupledSuspension`), 1.00x with it (1.22x while its
damping was the free chain's damping matrix: the truth damps its own modes, 0.02 each),
the suspended frequency off by 6.5e-5 before, 4e-6 with it.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from workbench.diagnosis import diagnose
from workbench.diagnosis.effects import CoupledSuspension, SuspensionStiffness, refinements
from workbench.diagnosis.fit import fit, fit_budget
from workbench.diagnosis.modal import decompose
from workbench.diagnosis.problem import FrfProblem, make_problem
from workbench.io.formats import FrfData, TimeData

MASS = np.array([1.0, 0.5, 0.8])  # kg
K_CHAIN = (4.0e4, 6.0e4)  # N/m, between masses 1-2 and 2-3
K_SPRING = 2.0e3  # N/m, mass 1 to the world
ZETA = 0.02  # modal damping of every mode
B = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])  # forces on masses 1 and 3 (N)
C = np.eye(3)  # the three positions (m)
NOISE = 1e-3  # relative noise of each FRF element


def _stiffness(k_spring: float) -> np.ndarray:
    """(3, 3) N/m: the chain, and the spring from mass 1 to the world."""
    k1, k2 = K_CHAIN
    K = np.array([[k1, -k1, 0.0], [-k1, k1 + k2, -k2], [0.0, -k2, k2]])
    K[0, 0] += k_spring
    return K


def _modal_damping(K: np.ndarray, zeta: float = ZETA) -> tuple[np.ndarray, np.ndarray]:
    """(natural frequencies (3,) Hz, damping matrix (3, 3) N s/m) of ``zeta`` in every mode."""
    Mm = np.diag(MASS)
    lam, phi = scipy.linalg.eigh(K, Mm)  # phi^T M phi = I
    w = np.sqrt(np.maximum(lam, 0.0))
    inv = np.linalg.inv(phi)
    return w / (2 * np.pi), inv.T @ np.diag(2 * zeta * w) @ inv


def _frf(freq: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(n_f, 3, 2) m/N."""
    Mm = np.diag(MASS)
    return np.stack([C @ np.linalg.solve(-((2 * np.pi * f) ** 2) * Mm + 2j * np.pi * f * D + K, B)
                     for f in freq])  # fmt: skip


def _nominal(zeta: float = ZETA) -> control.StateSpace:
    """The free chain (no spring to the world), its modal damping, as a state-space model."""
    K = _stiffness(0.0)
    _, D = _modal_damping(K, zeta)
    Minv = np.diag(1 / MASS)
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-Minv @ K, -Minv @ D]])
    return control.ss(A, np.vstack([np.zeros((3, 2)), Minv @ B]), np.hstack([C, 0 * C]), 0)


def _case(seed: int = 0, zeta: float = ZETA):
    """(nominal, FrfData with G_var, true frequencies (3,) Hz, noise floor error)."""
    K = _stiffness(K_SPRING)
    f_true, D = _modal_damping(K, zeta)
    freq = np.geomspace(0.5, 300.0, 500)
    G = _frf(freq, K, D)
    rng = np.random.default_rng(seed)
    sd = NOISE * np.abs(G) + 1e-15
    Gm = G + sd / np.sqrt(2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    data = FrfData(freq=freq, G=Gm, G_var=sd**2, fs=5000.0)
    floor = float(np.mean(np.linalg.norm(Gm - G, axis=(1, 2)) / np.linalg.norm(Gm, axis=(1, 2))))
    return _nominal(zeta), data, f_true, floor


def test_coupled_suspension_at_zero_coupling_is_the_rigid_one():
    """The refinement starts where the rigid suspension ended: the same model, same cost."""
    nominal, data, _, _ = _case()
    base = decompose(nominal)
    problem = FrfProblem(data)
    rigid = fit(SuspensionStiffness(), problem, base)
    cs = CoupledSuspension()
    assert cs.flexible(base) and len(cs.flexible(base)) == 2
    at_zero = cs.build(cs.start(rigid.theta, base), problem, base).model
    assert np.isclose(problem.cost(at_zero), rigid.cost, rtol=1e-9)


def test_suspension_of_a_flexible_body_reaches_the_noise_floor():
    nominal, data, f_true, floor = _case()
    res = diagnose(nominal, data)
    top = res.findings[0]
    assert top.effect == "suspension_stiffness", [f.effect for f in res.findings]
    # the coupled suspended frequency is the truth's lowest mode (a rigid-only one is off)
    assert abs(top.parameters["freq_hz"] / f_true[0] - 1) < 1e-3, (top.parameters, f_true)
    # one finding at the floor: the coupled modes damped as the truth damps its modes
    assert len(res.findings) == 1, [(f.effect, f.error_after / floor) for f in res.findings]
    assert top.error_after <= 1.1 * floor, top.error_after / floor


def test_the_coupled_modes_keep_their_damping_ratios():
    """Modal damping in the coupled modes: away from zero coupling (a, g, the flexible
    modes stiffened) the suspended mode has the suspension's damping ratio and each
    flexible mode the model's own, at frequencies the coupling moved; the damping matrix
    is diagonal in the stiffness's eigenvectors (it commutes with K)."""
    nominal, data, _, _ = _case()
    base = decompose(nominal)
    problem = FrfProblem(data)
    rigid = fit(SuspensionStiffness(), problem, base)
    cs = CoupledSuspension()
    theta = cs.start(rigid.theta, base).copy()
    theta[2:4] = (0.3, -0.2)  # a (R = 1, n_f = 2)
    theta[4:6] = (0.4, 0.25)  # g
    theta[6:] = (0.05, 0.01, 0.01, 0.08)  # d
    K, D = cs._stiffness_damping(theta, base)
    assert np.allclose(K @ D, D @ K, rtol=0, atol=1e-9 * np.abs(K @ D).max())
    model = cs.build(theta, problem, base).model
    flex = cs.flexible(base)
    sus = [m for m in model.modes if m.effect == cs.effect]
    assert len(sus) == 1 and np.isclose(sus[0].damping, np.exp(theta[1]), rtol=1e-9)
    for k in flex:
        assert np.isclose(model.modes[k].damping, base.modes[k].damping, rtol=1e-9)
        assert abs(model.modes[k].freq_hz / base.modes[k].freq_hz - 1) > 1e-3  # moved
    # the rigid fit's own frequency moved too: the coupling acts on every mode
    assert abs(sus[0].freq_hz / np.exp(theta[0]) - 1) > 1e-4


PERIOD = 1024  # samples of one excitation period
FS = 1000.0  # Hz


def _periodic_record(seed: int = 0, n_periods: int = 4):
    """(TimeData, noise floor error): the suspended chain driven from rest by a multisine.

    Both inputs on every line from 1 to 200 Hz with random phases, ``n_periods`` periods
    (the first one the transient), the response by :func:`_simulated`.
    """
    rng = np.random.default_rng(seed)
    lines = np.arange(1, int(200 * PERIOD / FS))
    one = np.zeros((PERIOD, 2))
    for j in range(2):
        X = np.zeros(PERIOD // 2 + 1, complex)
        X[lines] = np.exp(2j * np.pi * rng.random(lines.size))
        one[:, j] = np.fft.irfft(X, PERIOD)
    u = np.tile(one / one.std(axis=0), (n_periods, 1))
    y, floor = _simulated(u, rng)
    return TimeData(fs=FS, u=u, y=y, period=PERIOD), floor


def _simulated(u: np.ndarray, rng) -> tuple[np.ndarray, float]:
    """(y (N, 3) m with sensor noise, noise floor error): the suspended chain from rest
    driven by ``u`` (N, 2) N, by scipy's exact ZOH discretization of ``M q'' + D q' + K q =
    B u`` and ``dlsim``; sensor noise 1e-3 of each output's rms."""
    K = _stiffness(K_SPRING)
    _, D = _modal_damping(K)
    Minv = np.diag(1 / MASS)
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-Minv @ K, -Minv @ D]])
    Bs = np.vstack([np.zeros((3, 2)), Minv @ B])
    sysd = scipy.signal.cont2discrete((A, Bs, np.hstack([C, 0 * C]), np.zeros((3, 2))), 1 / FS)
    _, y, _ = scipy.signal.dlsim(sysd[:4] + (1 / FS,), u)
    v = NOISE * y.std(axis=0) * rng.standard_normal(y.shape)
    return y + v, float(np.linalg.norm(v) / np.linalg.norm(y + v))


def _record_from_rest(seed: int = 0, n_samples: int = 4096):
    """(TimeData, noise floor error): the suspended chain driven from rest by random
    noise (no period: fitted as a simulation, TimeProblem), the response by
    :func:`_simulated`."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n_samples, 2))
    y, floor = _simulated(u, rng)
    return TimeData(fs=FS, u=u, y=y), floor


@pytest.mark.parametrize("record", ["periodic", "from_rest"])
def test_suspension_of_a_flexible_body_on_a_time_record(record):
    """A periodic record is fitted at its lines (PeriodicProblem), a record from rest
    without periods as a simulation (TimeProblem); the coupled suspension is offered on
    both (on the simulation its coupling within RECORD_COUPLING): one finding at the
    noise floor, the suspended frequency the truth's."""
    from workbench.diagnosis.problem import PeriodicProblem, TimeProblem

    data, floor = _periodic_record() if record == "periodic" else _record_from_rest()
    kind = PeriodicProblem if record == "periodic" else TimeProblem
    assert type(make_problem(data)) is kind and (
        kind is TimeProblem or make_problem(data).domain == "frequency"
    )
    _, _, f_true, _ = _case()
    res = diagnose(_nominal(), data)
    top = res.findings[0]
    assert top.effect == "suspension_stiffness", [f.effect for f in res.findings]
    assert top.parameters.get("coupled_flexible_modes") == 2, top.parameters
    assert abs(top.parameters["freq_hz"] / f_true[0] - 1) < 1e-3, (top.parameters, f_true)
    assert len(res.findings) == 1, [(f.effect, f.error_after / floor) for f in res.findings]
    assert top.error_after <= 1.1 * floor, top.error_after / floor


def test_the_record_coupling_budget_couples_the_lowest_modes():
    """Where an evaluation costs a simulation, the coupling is cut to the lowest flexible
    modes whose 2 R n_f + n_f^2 parameters fit RECORD_COUPLING; on an FRF every one (up to
    n_couple) is coupled."""
    import workbench.diagnosis.effects as effects

    nominal, data, _, _ = _case()
    base = decompose(nominal)
    record = make_problem(_record_from_rest(n_samples=1024)[0])
    assert record.domain == "time"
    rigid = fit(SuspensionStiffness(), record, base)
    for budget, n_coupled in ((24, 2), (7, 1), (2, 0)):
        effects.RECORD_COUPLING, saved = budget, effects.RECORD_COUPLING
        try:
            pairs = [s for s, _ in refinements(rigid, base, record)]
        finally:
            effects.RECORD_COUPLING = saved
        coupled = [s for s in pairs if type(s) is CoupledSuspension]
        assert len(coupled) == (n_coupled > 0), (budget, pairs)
        if coupled:
            assert coupled[0].flexible(base) == cs_lowest(base, n_coupled)
    frf = FrfProblem(data)
    ((cs, _),) = refinements(fit(SuspensionStiffness(), frf, base), base, frf)
    assert len(cs.flexible(base)) == 2


def cs_lowest(base, n: int) -> list[int]:
    """Indices of the model's ``n`` lowest flexible modes."""
    return CoupledSuspension().flexible(base)[:n]


def test_a_lightly_damped_flexible_mode_stiffened_by_the_spring_is_found():
    """At damping 0.002 the spring moves the first flexible mode (36.50 -> 36.86 Hz) by 2.5
    half-power widths: from zero stiffening the coupled fit did not see it (38x the floor);
    the stiffening screened first (CoupledSuspension.start with the problem), every
    frequency is the truth's and the misfit the noise."""
    nominal, data, f_true, floor = _case(zeta=0.002)
    base = decompose(nominal)
    problem = FrfProblem(data)
    rigid = fit(SuspensionStiffness(), problem, base)
    ((cs, start),) = refinements(rigid, base, problem)
    fr = fit(cs, problem, base, starts=[start], n_starts=1, max_nfev=fit_budget(cs))
    freqs = sorted(m.freq_hz for m in fr.model.modes if m.freq_hz > 0)
    assert np.allclose(freqs, f_true, rtol=1e-4), (freqs, f_true)
    assert fr.error <= 2.0 * floor, fr.error / floor


def test_an_overdamped_rigid_fit_gives_no_coupled_start_instead_of_a_crash():
    """A rigid suspension fit may end overdamped (damping 2: an indepgen3 planar FRF, a
    sensor-lag case, whose rigid fit ran to its damping bound). The coupled realization
    has no second-order form there: no refinement is offered, the diagnosis goes on (it
    raised LinAlgError out of ``diagnose`` before)."""
    nominal, data, _, _ = _case()
    base = decompose(nominal)
    problem = FrfProblem(data)
    rigid = fit(SuspensionStiffness(), problem, base)
    theta = rigid.theta.copy()
    theta[1] = np.log(2.0)  # the shared damping ratio
    cs = CoupledSuspension()
    with pytest.raises(np.linalg.LinAlgError):
        cs.build(cs.start(theta, base), problem, base)  # the premise: no coupled form
    assert cs.start(theta, base, problem) is None


def _two_bodies(zeta_suspension=(0.001, 0.05)):
    """(nominal StateSpace, FrfData with G_var, true suspension frequencies (2,) Hz, their
    damping (2,), noise floor error): two free chains side by side (masses 1.0 / 0.5 / 0.8
    kg and 0.7 / 0.6 kg; springs 40 / 60 and 50 kN/m), each hung on its own spring to the
    world at its first mass (2 and 3 kN/m), pushed there; every mass measured. The truth's
    suspension modes are damped differently (a damper on one spring only), its flexible
    modes 0.02; the nominal model is the two free chains, damped 0.02 in every mode."""
    masses = np.array([1.0, 0.5, 0.8, 0.7, 0.6])
    K = np.zeros((5, 5))
    for i, j, k in ((0, 1, 4.0e4), (1, 2, 6.0e4), (3, 4, 5.0e4)):
        K[np.ix_([i, j], [i, j])] += k * np.array([[1.0, -1.0], [-1.0, 1.0]])
    Bf = np.zeros((5, 2))
    Bf[0, 0] = Bf[3, 1] = 1.0
    Mm = np.diag(masses)

    def damping(Kx, zetas):
        lam, phi = scipy.linalg.eigh(Kx, Mm)
        w = np.sqrt(np.maximum(lam, 0.0))
        inv = np.linalg.inv(phi)
        return w / (2 * np.pi), inv.T @ np.diag(2 * np.asarray(zetas) * w) @ inv

    _, D0 = damping(K, np.full(5, ZETA))
    Minv = np.diag(1 / masses)
    A = np.block([[np.zeros((5, 5)), np.eye(5)], [-Minv @ K, -Minv @ D0]])
    nominal = control.ss(
        A, np.vstack([np.zeros((5, 2)), Minv @ Bf]), np.hstack([np.eye(5), np.zeros((5, 5))]), 0
    )
    Ks = K.copy()
    Ks[0, 0] += 2.0e3
    Ks[3, 3] += 3.0e3
    f_all, _ = damping(Ks, np.zeros(5))
    # the two lowest modes are the suspension's (the bodies' bounce on their springs)
    zetas = np.concatenate([zeta_suspension, np.full(3, ZETA)])
    f_true, Ds = damping(Ks, zetas)
    freq = np.geomspace(0.5, 300.0, 500)
    G = np.stack([np.linalg.solve(-((2 * np.pi * f) ** 2) * Mm + 2j * np.pi * f * Ds + Ks, Bf)
                  for f in freq])  # fmt: skip
    rng = np.random.default_rng(3)
    sd = NOISE * np.abs(G) + 1e-15
    Gm = G + sd / np.sqrt(2) * (rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape))
    data = FrfData(freq=freq, G=Gm, G_var=sd**2, fs=5000.0)
    floor = float(np.mean(np.linalg.norm(Gm - G, axis=(1, 2)) / np.linalg.norm(Gm, axis=(1, 2))))
    return nominal, data, f_true[:2], np.asarray(zeta_suspension), floor


def test_suspension_modes_damped_differently_are_refined_with_their_coupling():
    """Two suspension modes damped 0.001 and 0.05: one shared damping cannot fit both, so
    the coupling is fitted from the structure with a damping per mode
    (``CoupledSuspension(per_mode_damping=True)``): both frequencies and both dampings
    are the truth's, the misfit the noise."""
    nominal, data, f_true, z_true, floor = _two_bodies()
    res = diagnose(nominal, data)
    top = res.findings[0]
    assert top.effect == "suspension_stiffness", [f.effect for f in res.findings]
    assert "coupled_flexible_modes" in top.parameters, top.parameters
    modes = sorted(top.parameters["modes"], key=lambda m: m["freq_hz"])
    assert np.allclose([m["freq_hz"] for m in modes], f_true, rtol=1e-3), (modes, f_true)
    assert np.allclose([m["damping"] for m in modes], z_true, rtol=0.1), (modes, z_true)
    assert top.error_after <= 2.0 * floor, (top.error_after / floor, res.findings)


def test_per_mode_damping_coupling_starts_at_the_uncoupled_model():
    """CoupledSuspension(per_mode_damping=True) at zero coupling is SuspensionModes' model."""
    from workbench.diagnosis.effects import SuspensionModes

    nominal, data, _, _, _ = _two_bodies()
    base = decompose(nominal)
    problem = FrfProblem(data)
    sm = fit(SuspensionModes(), problem, base)
    cs = CoupledSuspension(per_mode_damping=True)
    assert len(cs.theta_names) == len(SuspensionModes().theta_names) + 3
    at_zero = cs.build(cs.start(sm.theta, base), problem, base).model
    # (the mode damped 0.001 makes the cost sensitive to the eigen-solution's rounding)
    assert np.isclose(problem.cost(at_zero), sm.cost, rtol=1e-5)
    pairs = refinements(sm, base, problem)
    assert any(type(s) is CoupledSuspension and s.per_mode_damping for s, _ in pairs)


def test_a_growing_trial_is_scored_as_infeasible_not_raised():
    """A trial point whose mode grows past a float's range over the record (a transient
    basis keyed on |p| ** settle raises OverflowError) is scored as infeasible, not raised
    out of the diagnosis (an indepgen beam suspension's coupled fit crashed there)."""
    from workbench.diagnosis.fit import NUMERICAL_FAILURES

    nominal, data, _, _ = _case()
    base = decompose(nominal)
    problem = FrfProblem(data)

    class Overflowing(SuspensionStiffness):
        def build(self, theta, problem, base):
            if theta[0] > np.log(5.0):  # a trial past 5 Hz: a growing pole's power
                raise OverflowError((34, "Numerical result out of range"))
            return super().build(theta, problem, base)

    assert issubclass(OverflowError, NUMERICAL_FAILURES)
    fr = fit(Overflowing(), problem, base)
    assert np.isfinite(fr.cost) and np.exp(fr.theta[0]) <= 5.0


def _coupled_on_the_record():
    """(data, base, problem, CoupledSuspension, its fit, a missing mode fitted on top): the
    periodic record fitted as a simulation (``domain`` "time")."""
    from workbench.diagnosis.effects import MissingMode

    data, _ = _periodic_record()
    base = decompose(_nominal())
    problem = make_problem(data, domain="time")
    rigid = fit(SuspensionStiffness(), problem, base)
    cs = CoupledSuspension()
    coupled = fit(cs, problem, base, starts=[cs.start(rigid.theta, base)], n_starts=1,
                  max_nfev=200)  # fmt: skip
    return data, base, problem, cs, coupled, fit(MissingMode(), problem, coupled.model)


def _spy_fit_joint(monkeypatch, module):
    """(the structure names of every fit_joint call in ``module``, the original)."""
    import workbench.diagnosis.fit as fit_module

    sizes = []
    original = fit_module.fit_joint

    def spy(parts, thetas, *a, **k):
        sizes.append([type(p).__name__ for p in parts])
        return original(parts, thetas, *a, **k)

    monkeypatch.setattr(module, "fit_joint", spy)
    return sizes, original


def test_later_candidates_are_compared_with_the_coupling_held_and_refitted_whole(monkeypatch):
    """On a record fitted as a simulation (``domain`` "time"), a later round refits each
    candidate jointly with a coupled suspension found earlier, its coupling held (Held:
    only the suspended frequency and damping free), and the candidate taken is refitted
    with every parameter free: the findings carry the real structures, and the whole
    refit is no worse than the held one. On an FRF alike; on a periodic record's lines
    nothing is held, and the refit on the whole record holds it."""
    import sys

    from workbench.diagnosis.effects import MissingMode

    module = sys.modules["workbench.diagnosis.diagnose"]
    data, base, problem, cs, coupled, mode = _coupled_on_the_record()
    assert problem.domain == "time"
    held = cs.held(coupled.theta, problem, base)
    n_rigid = len(held.free)
    assert n_rigid == 2 and len(held.bounds(problem, base)[0]) == n_rigid  # ln f, ln z
    m_held = held.build(coupled.theta[:n_rigid], problem, base).model
    assert np.isclose(problem.cost(m_held), coupled.cost, rtol=1e-12)
    sizes, original = _spy_fit_joint(monkeypatch, module)
    fits, _ = module._joint_candidates([coupled], [mode], problem, base, problem.n_obs)
    assert sizes == [["Held", "MissingMode"], ["CoupledSuspension", "MissingMode"]]
    assert type(fits[0].structure) is CoupledSuspension and type(fits[1].structure) is MissingMode
    assert fits[0].theta.size == coupled.theta.size
    held_fits, _ = original([held, MissingMode()], [coupled.theta[:n_rigid], mode.theta],
                            problem, base)  # fmt: skip
    assert fits[-1].cost <= held_fits[-1].cost * (1 + 1e-9)
    # on an FRF held alike; on the periodic record's lines every parameter free at once
    sizes.clear()
    _, frf_data, _, _ = _case()
    frf_problem = FrfProblem(frf_data)
    module._joint_candidates([coupled], [mode], frf_problem, base, frf_problem.n_obs)
    assert sizes == [["Held", "MissingMode"], ["CoupledSuspension", "MissingMode"]]
    sizes.clear()
    lines = make_problem(data)
    assert lines.domain == "frequency" and lines.kind != "frf"
    fits, _ = module._joint_candidates([coupled], [mode], lines, base, lines.n_obs)
    # every parameter free on the lines; where the suspended modes between them leave the
    # chain above the noise floor, the whole record's refit holds the coupling (as a single
    # effect's refit there does), never refits it whole
    assert sizes[0] == ["CoupledSuspension", "MissingMode"]
    assert all(s == ["Held", "MissingMode"] for s in sizes[1:]), sizes
    assert type(fits[0].structure) is CoupledSuspension and fits[0].theta.size == coupled.theta.size
    whole, _ = original([cs, MissingMode()], [coupled.theta, mode.theta], lines, base)
    assert fits[-1].n_params == whole[-1].n_params  # the held parameters counted
    assert np.isfinite(fits[0].theta_std).sum() == np.isfinite(whole[0].theta_std).sum()


def test_a_held_candidate_far_from_a_finding_is_not_refitted_whole(monkeypatch):
    """With ``reach`` (the current model and its error, where a finding must lower its record
    cost or its error by a large factor), a held best that stays near the current model (a
    missing mode fitted to the noise of a record the coupled suspension already explains)
    is returned unheld at the held coupling: one joint fit, not two. The results carry
    the coupled structure with its full theta (the coupling's std NaN, not fitted) and
    count its held parameters. A candidate that lowers the cost enough is refitted whole."""
    import sys

    from workbench.diagnosis.effects import MissingMode

    module = sys.modules["workbench.diagnosis.diagnose"]
    _, base, problem, cs, coupled, mode = _coupled_on_the_record()
    sizes, original = _spy_fit_joint(monkeypatch, module)
    reach = (coupled.model, coupled.error)
    fits, _ = module._joint_candidates([coupled], [mode], problem, base, problem.n_obs,
                                       reach=reach)  # fmt: skip
    assert sizes == [["Held", "MissingMode"]]
    premise = module.HELD_NEAR * problem.record_cost(coupled.model)
    assert problem.record_cost(fits[-1].model) > premise
    assert type(fits[0].structure) is CoupledSuspension
    assert fits[0].theta.size == coupled.theta.size
    n_held = coupled.theta.size - 2  # the coupling: all but ln f, ln z
    assert np.all(np.isnan(fits[0].theta_std[2:])) and np.all(np.isfinite(fits[0].theta_std[:2]))
    assert np.allclose(fits[0].theta[2:], coupled.theta[2:])
    held_fit, _ = original([cs.held(coupled.theta, problem, base), MissingMode()],
                           [coupled.theta[:2], mode.theta], problem, base)  # fmt: skip
    assert fits[-1].n_params == held_fit[-1].n_params + n_held
    assert np.isclose(fits[-1].cost, held_fit[-1].cost, rtol=1e-9)
    # a current model far above (the free body): the held best is a large drop, refitted
    sizes.clear()
    far = (base, problem.error(base))
    module._joint_candidates([coupled], [mode], problem, base, problem.n_obs, reach=far)
    assert sizes == [["Held", "MissingMode"], ["CoupledSuspension", "MissingMode"]]


def test_a_coupled_suspension_is_refitted_on_the_record_with_its_coupling_held(monkeypatch):
    """A periodic record's candidate is refitted on the whole record where its modes fall
    between the lines: a coupled suspension there only in its suspended modes (frequency,
    damping), its coupling held at the lines' values; the result is the whole structure's."""
    import sys

    from workbench.diagnosis.fit import Held

    module = sys.modules["workbench.diagnosis.diagnose"]
    data, _ = _periodic_record()
    base = decompose(_nominal())
    problem = make_problem(data)
    assert problem.domain == "frequency"
    rigid = fit(SuspensionStiffness(), problem, base)
    ((cs, start),) = refinements(rigid, base, problem)
    coupled = fit(cs, problem, base, starts=[start], n_starts=1, max_nfev=fit_budget(cs))
    seen = []
    original = module.fit
    monkeypatch.setattr(module, "fit", lambda s, *a, **k: seen.append(s) or original(s, *a, **k))
    # a start off in the suspended frequency: the record refit has something to move
    off = coupled.theta.copy()
    off[0] += 0.01
    moved = _at_theta(coupled, off, problem, base)
    out = module._refit_on_record(moved, problem, base)
    assert len(seen) == 1 and type(seen[0]) is Held
    n_rigid = len(seen[0].free)
    assert type(out.structure) is CoupledSuspension and out.theta.size == coupled.theta.size
    assert out.n_params == coupled.n_params
    assert out.error < moved.error
    np.testing.assert_array_equal(out.theta[n_rigid:], off[n_rigid:])  # the coupling held


def _at_theta(fr, theta, problem, base):
    """``fr`` at another theta (its model, cost and error there)."""
    from dataclasses import replace

    r = fr.structure.build(theta, problem, base)
    return replace(fr, theta=theta, realized=r, cost=problem.cost(r.model),
                   error=problem.error(r.model))  # fmt: skip


@pytest.mark.parametrize("per_mode", [False, True])
def test_the_analytic_frf_jacobian_is_the_residual_s_derivative(per_mode):
    """CoupledSuspension.jacobian (-Cm X (s dDm + dK) X Bm per line) against central
    differences of the model's residual, at a point with coupling, stiffening and mixing
    away from zero; held parameters keep their columns; None on a time record."""
    from workbench.diagnosis.effects import RigidSuspension, SuspensionModes

    nominal, data, _, _, _ = _two_bodies()
    base = decompose(nominal)
    problem = FrfProblem(data)
    cs = CoupledSuspension(per_mode_damping=per_mode)
    rigid = fit(SuspensionModes() if per_mode else RigidSuspension(), problem, base)
    lo, hi = cs.bounds(problem, base)
    rng = np.random.default_rng(1)
    theta = cs.start(rigid.theta, base)
    theta = np.clip(theta + 0.05 * rng.standard_normal(theta.size), lo + 0.01, hi - 0.01)

    def residual(t):
        return problem.residual(cs.build(t, problem, base).model)

    J = cs.jacobian(theta, problem, base)
    assert J.shape == (problem.n_obs, theta.size)
    for i in range(theta.size):
        # the quotient's best step: a mode damped 0.001 (Q 500) needs a small one (its error
        # ~ (h Q)^2), the eigen-solution's rounding a large one (~ 1e-13 / h)
        errors = []
        for h in (1e-4, 1e-5, 1e-6, 1e-7):
            up, down = theta.copy(), theta.copy()
            up[i] += h
            down[i] -= h
            column = (residual(up) - residual(down)) / (2 * h)
            errors.append(np.linalg.norm(J[:, i] - column) / np.linalg.norm(column))
        assert min(errors) <= 1e-6, (i, errors)
    held = cs.held(theta, problem, base)
    free = theta[list(held.free)]
    assert np.allclose(held.jacobian(free, problem, base), J[:, list(held.free)])
    record = make_problem(_periodic_record()[0], domain="time")
    assert cs.jacobian(theta, record, base) is None  # differences there


def test_a_coupled_suspension_is_fitted_by_levenberg_marquardt_on_a_record_too():
    """On a record simulated in the time domain a coupled suspension gets the normal
    equations of difference quotients (Levenberg-Marquardt, as on FRF data: scipy's trust
    region had stopped far above the optimum on a strongly coupled beam record); another
    structure there keeps the trust region."""
    from workbench.diagnosis import fit as fit_engine

    class Record:
        domain = "time"

    def residual(theta):
        return np.array([theta[0] - 1.0, 2.0 * theta[1], theta[0] * theta[1]])

    lo, hi = np.full(2, -5.0), np.full(2, 5.0)
    normal = fit_engine._normal_equations(CoupledSuspension(), Record(), None, residual, lo, hi)
    theta = np.array([0.5, 0.25])
    JTJ, JTr = normal(theta, residual(theta))
    J = np.array([[1.0, 0.0], [0.0, 2.0], [theta[1], theta[0]]])
    assert np.allclose(JTJ, J.T @ J, rtol=1e-5) and np.allclose(
        JTr, J.T @ residual(theta), rtol=1e-5
    )
    other = SuspensionStiffness()
    assert fit_engine._normal_equations(other, Record(), None, residual, lo, hi) is None
