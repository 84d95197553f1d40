"""The whole record's DFT as the frequency-domain problem (PeriodicProblem on one block).

For a sampled LTI system the N-point DFT of a record obeys exactly ``Y(k) = G(z_k) U(k) +
T(z_k)`` (Pintelon & Schoukens 2012, section 6.3), ``T`` rational with the system's own
poles: the modes', the channels' lags' and, for a delay, the delay line's (poles at
z = 0). A noise-free record of the model's own ZOH simulation (:func:`simulate`, the time
problem's reference), cut from a longer run so that every state (modes, lags, the delay
line's held inputs) starts away from rest, must fit to rounding; and without the lag or
delay terms it must not.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from workbench.core.errors import InputError
from workbench.diagnosis.problem import (
    PeriodicProblem,
    TimeProblem,
    make_problem,
    moving_start,
    record_block,
)
from workbench.io.formats import TimeData
from workbench.modal.model import ModalModel, Mode
from workbench.modal.simulate import simulate

FS = 1000.0


def _model(delay_s=2.37e-3, tau_in=(2e-3, 0.0), tau_out=(0.0, 4e-3), rigid=False):
    """2 x 2: modes at 40 Hz (1 %) and 170 Hz (3 %), a feedthrough, a delay of 2.37
    samples, a lag on input 1 and on output 2 (and a rigid body when ``rigid``)."""
    rng = np.random.default_rng(11)
    modes = [
        Mode("flexible", 40.0, 0.01, rng.normal(size=2), rng.normal(size=2)),
        Mode("flexible", 170.0, 0.03, rng.normal(size=2), rng.normal(size=2)),
    ]
    if rigid:
        modes.append(Mode("rigid", 0.0, 0.0, rng.normal(size=2), rng.normal(size=2)))
    D = 1e-4 * rng.normal(size=(2, 2))
    return ModalModel(
        modes=tuple(modes),
        D=D,
        delay_s=delay_s,
        tau_in=np.array(tau_in),
        tau_out=np.array(tau_out),
    )


def _record(model, n=4096, n_skip=3000, seed=0, band=0.3, closed=False):
    """The model's own simulation of filtered noise (band ``band`` fs), the first ``n_skip``
    samples cut: a record starting in motion. ``closed``: white noise instead (every line)."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n + n_skip, model.n_u))
    if not closed:
        b, a = scipy.signal.butter(4, band * 2)
        u = scipy.signal.lfilter(b, a, u, axis=0)
    y = simulate(model, u, FS)
    return TimeData(FS, u[n_skip:], y[n_skip:])


@pytest.mark.parametrize("lines", ["band", "all"])
@pytest.mark.parametrize("rigid", [False, True])
def test_the_models_own_record_from_a_moving_start_fits_to_rounding(lines, rigid, monkeypatch):
    import workbench.diagnosis.problem as problem_module

    monkeypatch.setattr(problem_module, "RECORD_LINES", lines)
    model = _model(rigid=rigid)
    data = _record(model)
    assert moving_start(data)
    problem = make_problem(data, domain="frequency")
    assert isinstance(problem, PeriodicProblem) and problem.whole
    total = float(np.sum((problem.target / problem.scale) ** 2))
    assert problem.cost(model) <= 1e-18 * total
    # every term is needed: without the lag poles or the delay line's terms the leakage of
    # their start stays a misfit far above rounding
    key = problem._transient_key(model)
    for reduced in (
        (0, key[1]),  # no delay-line terms
        (key[0], tuple(p for p in key[1] if abs(p.imag) > 0 or p.real < 0.5)),  # no lag poles
    ):
        C = problem._columns(reduced[1], drift=True, n_delay=reduced[0])
        Q = np.linalg.qr(np.concatenate([C.real, C.imag]))[0]
        e = problem.target - problem._parts_sum(
            model, problem._u_in(model), problem._channels_key(model)
        )
        e -= Q @ (Q.T @ e)
        assert np.sum((e / problem.scale) ** 2) >= 1e-10 * total
    # a slightly wrong model does not fit
    wrong = replace(model, delay_s=model.delay_s * 1.01)
    assert problem.cost(wrong) >= 1e6 * max(problem.cost(model), 1e-30 * total)
    # the reported numbers are the time domain's
    time = TimeProblem(data)
    assert problem.error(model) == time.error(model)
    assert problem.record_cost(model) == time.cost(model)
    assert problem.residual_peaks(model) == time.residual_peaks(model)


def test_a_record_from_rest_and_a_delay_of_whole_samples_fit_to_rounding():
    for delay_s in (0.0, 3e-3):
        model = _model(delay_s=delay_s)
        data = _record(model, n_skip=0, closed=True)
        problem = make_problem(data, domain="frequency")
        assert isinstance(problem, PeriodicProblem) and problem.whole
        assert problem._transient_key(model)[0] == round(delay_s * FS)
        total = float(np.sum((problem.target / problem.scale) ** 2))
        assert problem.cost(model) <= 1e-18 * total


def test_a_linear_fit_recovers_a_missing_modes_numerator_exactly():
    """The regressors of an added mode are projected with its own leakage terms too."""
    model = _model()
    data = _record(model)
    problem = make_problem(data, domain="frequency")
    missing = replace(model, modes=model.modes[:1])
    N0, N1, _, _ = problem.fit_new_term(missing, model.modes[1].denominator())
    N0_true, N1_true = model.modes[1].numerator()
    scale = np.max(np.abs(N0_true))
    assert np.max(np.abs(N0 - N0_true)) <= 1e-7 * scale
    assert np.max(np.abs(N1 - N1_true)) <= 1e-7 * scale


def test_record_block_lines():
    rng = np.random.default_rng(1)
    N = 1000
    U = np.zeros((N // 2 + 1, 2), complex)
    U[1:101] = rng.normal(size=(100, 2)) + 1j * rng.normal(size=(100, 2))
    u = np.fft.irfft(U, n=N, axis=0)  # lines 1 .. 100, no period given
    data = TimeData(FS, u, simulate(_model(), u, FS))
    every = record_block(data, "all")
    assert every.period == N and every.n_blocks == 1 and np.all(every.n_dropped == 0)
    assert np.array_equal(np.flatnonzero(every.excited[0]), np.arange(1, N // 2))
    assert np.allclose(every.U[0], np.fft.rfft(data.u, axis=0))
    band = record_block(data, "band")
    assert np.array_equal(np.flatnonzero(band.excited[0]), np.arange(1, 101))
    with pytest.raises(InputError, match="lines"):
        record_block(data, "some")


def test_make_problem_picks_the_record_for_what_is_not_steady_state_periodic():
    """ "frequency": the steady-state lines of a periodic record, else the whole record's;
    "auto": the steady-state lines, else the whole record's from a moving start and the
    simulation from rest; "time": the simulation."""
    model = _model()
    rng = np.random.default_rng(4)
    P = 500
    U = np.zeros((P // 2 + 1, 2), complex)
    U[1:101] = np.exp(2j * np.pi * rng.random((100, 2)))
    period = np.fft.irfft(U, n=P, axis=0)
    u = np.tile(period, (4, 1))
    y = simulate(model, u, FS)
    periodic = TimeData(FS, u, y, period=P)
    for domain in ("auto", "frequency"):
        p = make_problem(periodic, domain=domain)
        assert isinstance(p, PeriodicProblem) and not p.whole
    assert isinstance(make_problem(periodic, domain="time"), TimeProblem)
    # one period, cut in motion; not periodic (filtered noise), from rest and in motion;
    # closed loop (r recorded)
    one = TimeData(FS, u[P + 100 : 2 * P + 100], y[P + 100 : 2 * P + 100], period=P)
    records = [one, _record(model, n_skip=0), _record(model)]
    records.append(TimeData(FS, records[-1].u, records[-1].y, r=records[-1].u + 0.1))
    for data in records:
        p = make_problem(data, domain="frequency")
        assert isinstance(p, PeriodicProblem) and p.whole
        auto = make_problem(data)
        if moving_start(data):
            assert isinstance(auto, PeriodicProblem) and auto.whole
        else:
            assert isinstance(auto, TimeProblem)
        assert isinstance(make_problem(data, domain="time"), TimeProblem)
    assert [moving_start(d) for d in records] == [True, False, True, True]
    # too short for the transient terms: "frequency" refuses it
    short = TimeData(FS, u[:30], y[:30])
    assert isinstance(make_problem(short), TimeProblem)
    with pytest.raises(InputError, match="domain 'frequency'"):
        make_problem(short, domain="frequency")


def _two_rigid_model():
    """2 x 2 with a rigid body of rank 2 (two rigid DOFs merged in one rigid mode) and the
    modes of :func:`_model`, no lags: a suspension screen's model."""
    rng = np.random.default_rng(13)
    base = _model(delay_s=1.3e-3, tau_in=(0.0, 0.0), tau_out=(0.0, 0.0))
    rigid = Mode("rigid", 0.0, 0.0, rng.normal(size=2), rng.normal(size=2))
    rigid = replace(rigid, N0=rng.normal(size=(2, 2)))
    return replace(base, modes=base.modes + (rigid,))


def test_a_whole_records_grid_in_batches_costs_what_each_model_costs_alone(monkeypatch):
    """PeriodicProblem.costs on a whole record, in batches of a few points
    (TOGETHER_ROWS), against cost() model by model: a suspension's grid (its DOFs started at
    one shared frequency: a pole met twice, left out of the point's columns as
    _transient_key leaves it out of the basis) and a moved mode's. The grids are evaluated
    together, not point by point."""
    from workbench.diagnosis.effects import ModalMismatch, RigidSuspension

    truth = _model(delay_s=1.3e-3, tau_in=(0.0, 0.0), tau_out=(0.0, 0.0))
    data = _record(truth)
    problem = make_problem(data, domain="frequency")
    assert isinstance(problem, PeriodicProblem) and problem.whole
    monkeypatch.setattr(PeriodicProblem, "TOGETHER_ROWS", 20 * problem.n_obs)  # 20 a batch
    base = _two_rigid_model()
    alone_calls = []
    cost = problem.cost
    monkeypatch.setattr(problem, "cost", lambda m: alone_calls.append(m) or cost(m))
    for s in (RigidSuspension(), ModalMismatch(0)):
        grid = s.grid(problem, base)
        assert len(grid) > 40
        models = [s.build(g, problem, base).model for g in grid]
        together = problem.costs(models)
        # every point in a batch, but the suspension's few far below the band whose slow
        # pole is overdamped (evaluated alone by design, PeriodicProblem._moved_costs)
        slow = [m for m in alone_calls if min(x.freq_hz for x in m.modes) < problem.band_hz[0] / 10]
        assert len(alone_calls) == len(slow) <= 9  # 3 frequencies x 3 dampings
        alone_calls.clear()
        alone = np.array([cost(m) for m in models])
        assert np.allclose(together, alone, rtol=1e-9, atol=1e-12 * np.max(alone))


def test_a_pole_met_twice_is_one_basis_term():
    """Two modes at one frequency and damping: their pole is one transient term (the same
    span as Householder QR's rank decision on the columns with it twice)."""
    data = _record(_model())
    problem = make_problem(data, domain="frequency")
    model = _model()
    twin = replace(model.modes[0], b=model.modes[0].b[::-1].copy())
    doubled = replace(model, modes=model.modes + (twin,))
    key = problem._transient_key(doubled)
    assert key == problem._transient_key(model)
    # the reference: the 40 Hz pole's columns twice, the repeated ones dropped by the QR
    C = problem._columns(list(key[1]) + [key[1][0]], drift=True, n_delay=key[0])
    Q, R = np.linalg.qr(np.concatenate([C.real, C.imag]))
    Q = Q[:, np.abs(np.diag(R)) > 1e-10 * np.max(np.abs(np.diag(R)))]
    P = problem._start_basis(doubled)
    assert P.shape[1] == Q.shape[1]
    assert np.max(np.abs(P @ P.T - Q @ Q.T)) <= 1e-9


def test_a_screen_in_batches_is_the_screen_of_the_whole_grid(monkeypatch):
    """fit.screen builds and evaluates a grid in the problem's batches (an added mode's
    basis kept between its build and its cost): the same costs and order as the whole grid
    at once."""
    from workbench.diagnosis.effects import MissingMode
    from workbench.diagnosis.fit import screen

    data = _record(_model(delay_s=1.3e-3, tau_in=(0.0, 0.0), tau_out=(0.0, 0.0)))
    base = replace(
        _model(delay_s=1.3e-3, tau_in=(0.0, 0.0), tau_out=(0.0, 0.0)),
        modes=_model().modes[:1],
    )
    out = {}
    for rows in (2**40, 1):  # one batch; batches of 2 MIN_TOGETHER
        monkeypatch.setattr(PeriodicProblem, "TOGETHER_ROWS", rows)
        problem = make_problem(data, domain="frequency")
        assert rows > 1 or problem.batch == 2 * PeriodicProblem.MIN_TOGETHER
        out[rows] = screen(MissingMode(), problem, base)
    a, b = out[2**40], out[1]
    assert a.cost == pytest.approx(b.cost, rel=1e-12)
    assert all(np.array_equal(x, y) for x, y in zip(a.starts[:10], b.starts[:10]))


def _projector_afresh(problem, key) -> np.ndarray:
    """The projector on the transient columns of ``key`` by Householder QR (the reference)."""
    C = problem._columns(key[1], drift=True, n_delay=key[0])
    Q = np.linalg.qr(np.concatenate([C.real, C.imag]))[0]
    return Q @ Q.T


def test_delay_line_terms_are_the_powers_of_z():
    """The delay line's columns (exact phase reduction) are ``z^-j``, from any first term."""
    problem = make_problem(_record(_model()), domain="frequency")
    C = problem._columns((), drift=False, n_delay=40, first_delay=7)
    ref = np.column_stack([problem.z ** (-j) for j in range(7, 40)])
    assert C.shape == ref.shape
    assert np.max(np.abs(C - ref)) <= 1e-12


def test_a_longer_delay_line_or_several_moved_poles_extend_a_kept_basis():
    """The basis of a longer delay line (a delay's grid) from the kept basis of a shorter one,
    and of a model whose two modes moved together (a suspension's DOFs) from the kept basis
    of the other poles (:meth:`PeriodicProblem._basis_near`): the projector of the basis
    afresh, and no basis computed afresh but the first and the other poles'."""
    model = _model(tau_in=(0.0, 0.0), tau_out=(0.0, 0.0), rigid=True)
    quiet = [Mode("flexible", f, 0.01, np.zeros(2), np.zeros(2)) for f in (80.0, 300.0)]
    model = replace(model, modes=model.modes + tuple(quiet))  # 4 poles, two of them move
    problem = make_problem(_record(model), domain="frequency")
    fresh = []
    problem._basis_of = lambda key, f=problem._basis_of: fresh.append(key) or f(key)
    models = [replace(model, delay_s=d / FS) for d in (2.37, 5.0, 11.5, 31.0)]
    for j in range(1, 4):  # the first two modes moved, the others (and the drift) kept
        modes = [m.moved(m.freq_hz * (1 + 0.02 * j), m.damping) for m in model.modes[:2]]
        models.append(replace(models[-1], modes=tuple(modes) + model.modes[2:]))
    for m in models:
        Q = problem._start_basis(m)
        P_ref = _projector_afresh(problem, problem._transient_key(m))
        assert np.max(np.abs(Q @ Q.T - P_ref)) <= 1e-10
    keys = [problem._transient_key(m) for m in models]
    assert [k[0] for k in keys[:4]] == [3, 5, 12, 31]
    # afresh: the first model's, and (moved twice in the same places) the unmoved poles'
    assert fresh == [keys[0], (31, keys[0][1][2:])]
