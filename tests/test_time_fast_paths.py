"""The time-domain fast paths: compiled recursion, closed-form ZOH coefficients, crosstalk.

:func:`workbench._filter_kernel.iir_streams` against ``scipy.signal.lfilter`` summed over
streams (every kernel path: a mode, a mode behind lags, a higher order); the partial-
fraction coefficients (:func:`workbench.modal.simulate._pole_coefficients`) against the
matrix-exponential discretization and against the exact line responses; a mode's output by
:func:`mixed_inputs` against :func:`filtered_inputs` mixed by its numerators (delays,
lags, coupling), the time-domain problem's cost against the simulation's, and the
input-side crosstalk's regressors against the parts' outer products summed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from workbench._filter_kernel import iir_streams, transposed
from workbench.diagnosis.problem import TimeProblem
from workbench.io.formats import TimeData
from workbench.modal import simulate as S
from workbench.modal.model import ModalModel, Mode


@pytest.mark.parametrize("n, L", [(1, 2), (2, 3), (2, 4), (3, 5), (4, 6), (4, 3), (5, 7)])
def test_iir_streams_is_lfilter_summed(n, L):
    rng = np.random.default_rng(n * 10 + L)
    a = np.poly(rng.uniform(0.5, 0.99, n))
    b = rng.standard_normal((2, L))
    x = rng.standard_normal((2, 3, 3000))
    ref = sum(scipy.signal.lfilter(b[k], a, x[k], axis=-1) for k in range(2))
    out = iir_streams(b, a, x)
    assert np.max(np.abs(out - ref)) <= 1e-11 * np.max(np.abs(ref))


def test_iir_streams_normalizes_a():
    rng = np.random.default_rng(3)
    a = 2.5 * np.poly([0.9, 0.7])
    b = rng.standard_normal((1, 3))
    x = rng.standard_normal((1, 2, 500))
    ref = scipy.signal.lfilter(b[0], a, x[0], axis=-1)
    assert np.allclose(iir_streams(b, a, x), ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize(
    "S_, C, n", [(1, 1, 2), (1, 4, 2), (2, 5, 2), (1, 5, 3), (2, 2, 4), (2, 1, 4)]
)
def test_iir_streams_takes_the_streams_apart(S_, C, n):
    """Streams given one by one (read-only, as the cached mixed inputs are) filter as the
    stacked array does, for an odd and an even number of signals (the kernels run two
    signals per pass and the last one alone), and as lfilter summed."""
    rng = np.random.default_rng(100 * S_ + 10 * C + n)
    a = np.poly(rng.uniform(0.5, 0.99, n))
    b = rng.standard_normal((S_, n + 2 if n > 2 else 4))
    x = rng.standard_normal((S_, C, 2000))
    streams = [np.ascontiguousarray(x[k]) for k in range(S_)]
    for s_ in streams:
        s_.flags.writeable = False
    out = iir_streams(b, a, streams)
    assert np.array_equal(out, iir_streams(b, a, x))
    ref = sum(scipy.signal.lfilter(b[k], a, x[k], axis=-1) for k in range(S_))
    assert np.max(np.abs(out - ref)) <= 1e-11 * np.max(np.abs(ref))


def test_transposed_is_the_record_layout():
    x = np.random.default_rng(1).standard_normal((5, 1001))
    y = transposed(x)
    assert y.flags.c_contiguous and np.array_equal(y, x.T)


def test_a_record_cache_keeps_its_newest_entries_within_its_bytes():
    store: dict = {}
    for k in range(10):
        S._keep(store, k, np.full(100, float(k)), 3 * 800)
    assert list(store) == [7, 8, 9]
    assert not store[9].flags.writeable


def _expm_coefficients(num, den, dt, frac):
    """The matrix-exponential path of _zoh_coefficients (the reference before)."""
    strict = num[1:] - num[0] * den[1:]
    Ad, B0, B1, t, a = S._zoh_discretization.__wrapped__(den.tobytes(), dt, frac)
    C = (strict * t)[None, :]
    b0 = S._charpoly(Ad - B0 @ C) - a
    b1 = S._charpoly(Ad - B1 @ C) - a
    return np.concatenate([b0, [0.0]]) + np.concatenate([[0.0], b1]), a


def _random_filters(rng, n_cases):
    fs = 4096.0
    for k in range(n_cases):
        f = np.exp(rng.uniform(np.log(5.0), np.log(1800.0)))
        z = np.exp(rng.uniform(np.log(1e-4), np.log(0.9)))
        w = 2 * np.pi * f
        d = np.array([1.0, 2 * z * w, w * w])
        for _ in range(k % 3):  # behind one or two lags
            d = np.convolve(d, [1 / (2 * np.pi * rng.uniform(50, 3000)), 1.0])
        frac = rng.uniform(0, 1 / fs) if k % 2 else 0.0
        yield d, 1 / fs, frac


def test_pole_coefficients_are_the_exact_filter():
    """Partial fractions give the ZOH filter whose response is the exact line response
    (zoh_responses, partial fractions too, but evaluated without the polynomial form) to
    rounding, and the matrix exponential's coefficients to its accuracy."""
    rng = np.random.default_rng(0)
    zl = np.exp(2j * np.pi * np.linspace(0.002, 0.498, 150))
    for d, dt, frac in _random_filters(rng, 300):
        for num0 in ([1.0], [1.0, 0.0]):
            (num,), den = S._monic([num0], d)
            strict = num[1:] - num[0] * den[1:]
            closed = S._pole_coefficients(strict, den, dt, frac)
            assert closed is not None
            b, a = closed
            ref = S.zoh_responses([num0], d, zl, dt, frac)[0]
            H = np.polyval(b[::-1], 1 / zl) / np.polyval(a[::-1], 1 / zl)
            assert np.max(np.abs(H - ref)) <= 1e-8 * np.max(np.abs(ref))
            be, ae = _expm_coefficients(num, den, dt, frac)
            He = np.polyval(be[::-1], 1 / zl) / np.polyval(ae[::-1], 1 / zl)
            assert np.max(np.abs(H - He)) <= 1e-5 * np.max(np.abs(ref))
            assert np.allclose(a, ae, rtol=0, atol=1e-12)


def test_pole_coefficients_leave_coinciding_poles_to_the_exponential():
    dt = 1 / 4096
    w = 2 * np.pi * 50
    critical = np.array([1.0, 2 * w, w * w])  # a double pole
    rigid = np.array([1.0, 0.0, 0.0])
    for den in (critical, rigid):
        assert S._pole_coefficients(np.array([0.0, 1.0]), den, dt, 0.0) is None
        b, a = S._zoh_coefficients(np.array([0.0, 0.0, 1.0]).tobytes(), den.tobytes(), dt, 0.0)
        assert np.all(np.isfinite(b)) and np.all(np.isfinite(a))


def _model(rng, n_y=3, n_u=2, *, delay=0.0, tau_in=None, tau_out=None, T_in=None):
    modes = [
        Mode("flexible", f, z, rng.standard_normal(n_u), rng.standard_normal(n_y))
        for f, z in ((37.0, 0.02), (180.0, 0.005), (640.0, 0.03))
    ]
    modes.append(Mode("rigid", 0.0, 0.0, rng.standard_normal(n_u), rng.standard_normal(n_y)))
    return ModalModel(
        modes=tuple(modes),
        D=np.zeros((n_y, n_u)),
        delay_s=delay,
        tau_in=tau_in,
        tau_out=tau_out,
        T_in=T_in,
    )


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"delay": 2.4 / 4096},
        {"tau_in": np.array([0.0, 1 / (2 * np.pi * 300)])},
        {"tau_out": np.array([1 / (2 * np.pi * 500), 0.0, 0.0]), "delay": 1 / 4096},
        {
            "tau_in": np.array([1 / (2 * np.pi * 800), 1 / (2 * np.pi * 300)]),
            "tau_out": np.array([1 / (2 * np.pi * 500), 0.0, 1 / (2 * np.pi * 900)]),
        },
    ],
)
def test_mixed_inputs_is_the_filtered_inputs_mixed(kw):
    rng = np.random.default_rng(7)
    model = _model(rng, **kw)
    fs = 4096.0
    u = rng.standard_normal((4000, 2))
    products: dict = {}
    for m in model.modes:
        den, (N0, N1) = m.denominator(), m.numerator()
        X, groups = S.filtered_inputs(model, den, u, fs)
        ref = np.zeros((u.shape[0], 3))
        for g, rows in enumerate(groups):
            ref[:, rows] = X[g, :, :, 0] @ N0[rows].T
            if N1 is not None and np.any(N1):
                ref[:, rows] += X[g, :, :, 1] @ N1[rows].T
        for _ in range(2):  # the second time from the kept mixed inputs
            y = S.mixed_inputs(model, den, N0, N1, u, fs, products=products)
            # the additions in another order: rounding, accumulated by the rigid body's
            # double integrator over the record (~5e-11 behind a lag)
            assert np.max(np.abs(y - ref)) <= 1e-9 * np.max(np.abs(ref))
    assert products


def test_time_problem_cost_is_the_simulation_cost():
    """The problem's cost (mode outputs by mixed_inputs, summed from anchors) is the
    residual of the model's simulation from rest, for the model and a moved mode."""
    rng = np.random.default_rng(11)
    T_in = np.eye(2) + 0.05 * rng.standard_normal((2, 2))
    model = _model(rng, delay=1.5 / 4096, tau_in=np.array([0.0, 1 / (2 * np.pi * 400)]), T_in=T_in)
    fs = 4096.0
    u = rng.standard_normal((3000, 2))
    truth = model.modes[0].moved(38.0, 0.021)
    moved = replace(model, modes=(truth,) + model.modes[1:])
    y = S.simulate(moved, u, fs) + 1e-3 * rng.standard_normal((3000, 3))
    problem = TimeProblem(TimeData(fs=fs, u=u, y=y), transient=False)
    for m in (model, moved):
        ref = np.sum(((y - S.simulate(m, u, fs)) / problem.scale) ** 2)
        assert problem.cost(m) == pytest.approx(ref, rel=1e-9)


def _crosstalk_in_reference(problem, model):
    """fit_crosstalk(side="in") as it was written: the regressor of E[j, k], column j of
    the model driven by u_k, summed part by part as outer products."""
    from workbench.diagnosis.problem import _lstsq_std

    e = (problem.target - problem.fitted(model)) / problem.scale
    n_y, n_u = model.n_y, model.n_u
    u_in = problem._u_in(model)
    parts = [(None, model.D, None)] if np.any(model.D) else []
    parts += [(m.denominator(), *m.numerator()) for m in model.modes]
    R = np.zeros((problem.target.shape[0], n_y, n_u, n_u))
    for den, N0, N1 in parts:
        X, groups = problem._filtered(model, den, u_in)
        for g, rows in enumerate(groups):
            R[:, rows] += np.einsum("nk,ij->nijk", X[g, :, :, 0], N0[rows])
            if N1 is not None and np.any(N1):
                R[:, rows] += np.einsum("nk,ij->nijk", X[g, :, :, 1], N1[rows])
    if model.T_out is not None:
        R = np.einsum("ab,nbjk->najk", model.T_out, R)
    R = problem._project(model, R)
    pairs = [(j, k) for j in range(n_u) for k in range(n_u) if j != k]
    Xr = np.stack([R[:, :, j, k].ravel() for j, k in pairs], -1) / problem.scale
    x, s = _lstsq_std(Xr, e.ravel())
    E, S = np.zeros((n_u, n_u)), np.zeros((n_u, n_u))
    for (j, k), xv, sv in zip(pairs, x, s):
        E[j, k], S[j, k] = xv, sv
    return E, S


@pytest.mark.parametrize("transient", [False, True])
def test_fit_crosstalk_inputs_is_the_outer_product_sum(transient):
    """The input-side crosstalk's regressors, one product per input over the stacked parts,
    are the parts' outer products summed (output lags in groups, an output coupling, a
    feedthrough; from rest and from an estimated start)."""
    rng = np.random.default_rng(5)
    n_y, n_u = 3, 3
    model = _model(
        rng,
        n_y=n_y,
        n_u=n_u,
        delay=0.7 / 4096,
        tau_out=np.array([1 / (2 * np.pi * 500), 0.0, 0.0]),
    )
    model = replace(
        model,
        D=0.01 * rng.standard_normal((n_y, n_u)),
        T_out=np.eye(n_y) + 0.02 * rng.standard_normal((n_y, n_y)),
    )
    u = rng.standard_normal((2500, n_u))
    T_in = np.eye(n_u) + 0.03 * (1 - np.eye(n_u)) * rng.standard_normal((n_u, n_u))
    y = S.simulate(replace(model, T_in=T_in), u, 4096.0) + 1e-3 * rng.standard_normal((2500, n_y))
    problem = TimeProblem(TimeData(fs=4096.0, u=u, y=y), transient=transient)
    E, Sd = problem.fit_crosstalk(model, "in")
    E_ref, S_ref = _crosstalk_in_reference(problem, model)
    assert np.allclose(E, E_ref, rtol=1e-9, atol=1e-12)
    assert np.allclose(Sd, S_ref, rtol=1e-9, atol=1e-15)
    assert np.max(np.abs(E - (T_in - np.eye(n_u)))) < 0.01  # and it finds the coupling
