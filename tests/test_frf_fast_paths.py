"""The FRF diagnosis's fast paths against independent oracles.

- every analytic structure Jacobian against central differences of the residual;
- every structure's residual compressed per line (``lines``) against the model's residual:
  the cost and the normal equations;
- the cached / anchor-derived core response against the model's own direct sum;
- the added-term linear fits against a per-channel ``numpy.linalg.lstsq``;
- Levenberg-Marquardt on finite-difference normal equations against scipy's trust-region
  reflective search (the engine's reference path, ``fit.FRF_SOLVER = "trf"``).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from test_diagnose_gen import beam, beam_params, frf_case, stage, stage_params

import workbench.diagnosis.fit as fit_engine
from workbench.diagnosis.effects import (
    ActuatorDynamics,
    CommonLag,
    MissingMode,
    ModalMismatch,
    ModalModes,
    ModalPattern,
    SensorDynamics,
    SuspensionStiffness,
    TimeDelay,
    UpperResidual,
)
from workbench.diagnosis.fit import structure_lines
from workbench.diagnosis.modal import decompose
from workbench.diagnosis.problem import FrfProblem
from workbench.modal.model import Mode


def _problem(plant, params, effect: str):
    case = frf_case(
        plant(), effect, params(effect, "clear"), rel=0.005, rng=np.random.default_rng(3)
    )
    return FrfProblem(case.data), decompose(case.nominal)


def _central(structure, theta, problem, base, h: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(theta.size):
        e = np.zeros_like(theta)
        e[i] = h
        hi = problem.residual(structure.build(theta + e, problem, base).model)
        lo = problem.residual(structure.build(theta - e, problem, base).model)
        cols.append((hi - lo) / (2 * h))
    return np.stack(cols, -1)


def _with_outer(base, *, T_in=True, T_out=False):
    """The base with a delay, lags on both sides and static coupling on one side."""
    n_u, n_y = base.n_u, base.n_y
    return replace(
        base,
        delay_s=1.5e-4,
        tau_in=np.linspace(1e-5, 4e-5, n_u),
        tau_out=np.linspace(2e-5, 3e-5, n_y),
        T_in=np.eye(n_u) + 0.02 * np.ones((n_u, n_u)) if T_in else None,
        T_out=np.eye(n_y) + 0.01 * np.ones((n_y, n_y)) if T_out else None,
    )


def _split_modes(base):
    """ModalModes fitting the lower half of the pattern's modes, the upper half moved by a
    shared factor."""
    f = sorted(base.modes[k].freq_hz for k in ModalPattern().indices(base))
    return ModalModes(max_freq_hz=f[(len(f) - 1) // 2], scale=(1.02, 1.3), scale_std=(0.001, 0.05))


@pytest.mark.parametrize("plant,params", [(stage, stage_params), (beam, beam_params)])
def test_mode_by_mode_refinement_starts_at_the_patterns_model(plant, params):
    """A pattern refined mode by mode (each mode the record shows on its own, those above
    by the pattern's factor) starts at the pattern's model, and its report lists every
    mode: the fitted ones, then those moved by the shared factor."""
    from workbench.diagnosis.fit import FitResult

    problem, base = _problem(plant, params, "modal_mismatch")
    theta = np.log([1.02, 1.3])
    mm = _split_modes(base)
    ks, above = mm.indices(base), mm._above(base)
    assert ks and above
    pattern = ModalPattern().build(theta, problem, base).model
    split = mm.build(mm.from_pattern(theta, base), problem, base).model
    for a, b in zip(pattern.modes, split.modes):
        assert a.freq_hz == pytest.approx(b.freq_hz, rel=1e-12)
        assert a.damping == pytest.approx(b.damping, rel=1e-12)
    th = mm.from_pattern(theta, base)
    realized = mm.build(th, problem, base)
    fr = FitResult(mm, th, np.full(th.size, 0.01), realized, 0.0, 0.0, th.size, 0.0)
    params, std = mm.report(fr, problem, base)
    assert len(params["modes"]) == len(ks) + len(above) == len(std["modes"])
    for m in params["modes"][len(ks) :]:
        assert m["freq_hz"] == pytest.approx(1.02 * m["model_freq_hz"], rel=1e-12)


@pytest.mark.parametrize("plant,params", [(stage, stage_params), (beam, beam_params)])
def test_analytic_jacobians_match_central_differences(plant, params):
    problem, base0 = _problem(plant, params, "modal_mismatch")
    base = _with_outer(base0, T_in=False, T_out=True)
    structures = [
        (TimeDelay(), np.array([0.07]), base),
        (ActuatorDynamics(), np.linspace(0.2, 1.5, base.n_u), base),  # T_out allowed
        (CommonLag(), np.array([0.7]), base),
        (SensorDynamics(), np.linspace(0.3, 2.0, base.n_y), _with_outer(base0)),
        (ModalMismatch(index=1), None, base),
        (ModalPattern(), None, base),
        (ModalModes(), None, base),
        (_split_modes(base), None, base),
    ]
    if any(m.kind == "rigid" for m in base.modes):
        structures.append((SuspensionStiffness(), None, base))
    for s, theta, b in structures:
        if theta is None:
            grid = s.grid(problem, b)
            theta = np.asarray(grid[len(grid) // 3], float) + 0.013
        J = s.jacobian(theta, problem, b)
        Jc = _central(s, theta, problem, b)
        assert J.shape == Jc.shape == (problem.n_obs, theta.size)
        err = np.max(np.abs(J - Jc)) / np.max(np.abs(Jc))
        assert err < 1e-5, (type(s).__name__, err)


@pytest.mark.parametrize("plant,params", [(stage, stage_params), (beam, beam_params)])
def test_lines_match_the_model_residual(plant, params):
    """A structure's lines: the model's cost, J^T J and J^T r (where it has a Jacobian)."""
    problem, base0 = _problem(plant, params, "modal_mismatch")
    for base in (base0, _with_outer(base0, T_in=False, T_out=True)):
        structures = [TimeDelay(), ActuatorDynamics(), CommonLag(), ModalPattern(), ModalModes()]
        structures.append(_split_modes(base))
        structures += [
            ModalMismatch(index=k) for k, m in enumerate(base.modes) if m.kind == "flexible"
        ]
        if any(m.kind == "rigid" for m in base.modes):
            structures.append(SuspensionStiffness())
        if base.T_out is None:  # the added terms and the output lags: no output coupling
            structures += [SensorDynamics(), MissingMode(), UpperResidual()]
        for s in structures:
            lines = structure_lines(s, problem, base)
            lo, hi = s.bounds(problem, base)
            grid = s.grid(problem, base)
            for g in grid[:: max(1, len(grid) // 3)]:
                g = np.clip(np.asarray(g, float), lo, hi)
                r = problem.residual(s.build(g, problem, base).model)
                assert abs(lines.cost(g) / (r @ r) - 1) < 1e-12, type(s).__name__
                if lines.jacobian is None:
                    continue
                rc, Jc, J = lines.residual(g), lines.jacobian(g), s.jacobian(g, problem, base)
                scale = np.max(np.abs(J.T @ J))
                assert np.max(np.abs(Jc.T @ Jc - J.T @ J)) < 1e-12 * scale, type(s).__name__
                assert np.allclose(
                    Jc.T @ rc, J.T @ r, rtol=0, atol=1e-12 * np.sqrt(scale * (r @ r))
                )
    # coupling on the lags' side or with an added term: no lines (the model's residual)
    coupled = _with_outer(base0, T_in=True, T_out=True)
    for s in (ActuatorDynamics(), SensorDynamics(), MissingMode(), UpperResidual()):
        assert structure_lines(s, problem, coupled) is None
    assert structure_lines(TimeDelay(), SimpleNamespace(kind="time"), base0) is None


def test_jacobians_step_aside_where_they_do_not_apply():
    problem, base0 = _problem(stage, stage_params, "actuator_dynamics")
    theta = np.full(base0.n_u, 0.5)
    # coupling after the lag mixes the channels: finite differences instead
    assert ActuatorDynamics().jacobian(theta, problem, _with_outer(base0, T_in=True)) is None
    assert SensorDynamics().jacobian(theta, problem, _with_outer(base0, T_out=True)) is None
    time_problem = SimpleNamespace(kind="time")
    for s in (TimeDelay(), ActuatorDynamics(), ModalMismatch(index=1), ModalModes()):
        assert s.jacobian(np.zeros(2), time_problem, base0) is None


@pytest.mark.parametrize("plant,params", [(stage, stage_params), (beam, beam_params)])
def test_cached_core_equals_the_direct_sum(plant, params):
    problem, base = _problem(plant, params, "modal_mismatch")
    base = _with_outer(base)
    models = [base]
    for s in (ModalMismatch(index=1), ModalPattern()):
        models += [s.build(g, problem, base).model for g in s.grid(problem, base)[::7]]
    # an added mode (one more than the anchor) and two moved ones
    k = len(base.modes) - 1
    models.append(replace(base, modes=base.modes + (base.modes[k].moved(1234.5, 0.02),)))
    moved = list(base.modes)
    moved[k] = moved[k].moved(moved[k].freq_hz * 1.01, 0.03)
    moved[k - 1] = moved[k - 1].moved(moved[k - 1].freq_hz * 0.99, 0.02)
    models.append(replace(base, modes=tuple(moved)))
    for m in models + models[::-1]:  # twice: cache hits too
        direct = _direct_core(m, problem.s)
        got = problem.core(m)
        assert np.max(np.abs(got - direct)) <= 1e-12 * np.max(np.abs(direct))


def _direct_core(model, s):
    """``D + sum_k (N0_k + s N1_k) / den_k(s)`` by broadcasting, mode by mode (the oracle)."""
    G = np.zeros((s.size,) + model.D.shape, complex) + model.D
    for m in model.modes:
        N0, N1 = m.numerator()
        if m.kind == "rigid":
            den = s**2
        elif m.kind == "real":
            den = s - m.pole.real
        else:
            den = s**2 + 2 * m.damping * m.omega * s + m.omega**2
        G += (N0[None] + s[:, None, None] * N1[None]) / den[:, None, None]
    return G


def test_mode_responses_match_the_closed_form_off_the_axis_too():
    problem, base = _problem(stage, stage_params, "modal_mismatch")
    modes = base.modes + (replace(base.modes[-1], N1=0.3 * base.modes[-1].numerator()[0]),)
    model = replace(base, modes=modes)
    for s in (problem.s, problem.s * (1 + 0.2j) - 50.0):  # the jw axis and a general s
        ref = _direct_core(model, s) - model.D
        assert np.max(np.abs(sum(m.response(s) for m in modes) - ref)) < 1e-13 * np.max(np.abs(ref))
    f = problem.freq
    ref = _direct_core(model, problem.s)
    assert np.max(np.abs(model.core_frf(f) - ref)) < 1e-13 * np.max(np.abs(ref))


def _lstsq_channel(problem, columns, target, i, j):
    """Real coefficients of complex ``columns`` (n_f, p) for channel (i, j), weighted."""
    w = problem.w[:, i, j]
    A = columns * w[:, None]
    b = target[:, i, j] * w
    A_r = np.vstack([A.real, A.imag])
    b_r = np.concatenate([b.real, b.imag])
    return np.linalg.lstsq(A_r, b_r, rcond=None)[0]


def test_added_term_fits_match_per_channel_least_squares():
    problem, base0 = _problem(beam, beam_params, "missing_mode")
    base = _with_outer(base0)
    # a term added to the coupled model reaches the lines through T_in like its modes: it is
    # fitted to the misfit unmixed, e T_in^-1 (FrfProblem._unmixed)
    e = (problem.data.G - problem.predict(base)) @ np.linalg.inv(base.T_in)
    h = base.channel_factor(problem.freq)
    s = problem.s
    w0, z0 = 2 * np.pi * 530.0, 0.01
    den = np.array([2 * z0 * w0, w0 * w0])
    d = s**2 + den[0] * s + den[1]
    N0, N1, _, _ = problem.fit_new_term(base, den)
    wu = 2 * np.pi * 1.2 * problem.band_hz[1]  # near the band: a well-posed 3-column fit
    den_u = np.array([2 * 0.05 * wu, wu * wu])
    d_u = s**2 + den_u[0] * s + den_u[1]
    dD, U0, U1, *_ = problem.fit_upper_residual(base, den_u)
    for i, j in ((0, 0), (2, 1), (4, 2)):
        ref = _lstsq_channel(problem, np.stack([h[:, i, j] / d, h[:, i, j] * s / d], -1), e, i, j)
        assert np.allclose([N0[i, j], N1[i, j]], ref, rtol=1e-7, atol=0)
        cols = np.stack([h[:, i, j], h[:, i, j] / d_u, h[:, i, j] * s / d_u], -1)
        ref = _lstsq_channel(problem, cols, e, i, j)
        assert np.allclose([dD[i, j], U0[i, j], U1[i, j]], ref, rtol=1e-6, atol=0)


def test_two_pseudo_modes_are_fitted_jointly_with_d_per_channel():
    # the two-pole upper residual: D and both pseudo-modes' numerators in one least squares
    problem, base0 = _problem(beam, beam_params, "missing_mode")
    base = _with_outer(base0)
    e = (problem.data.G - problem.predict(base)) @ np.linalg.inv(base.T_in)
    h = base.channel_factor(problem.freq)
    s = problem.s
    dens = np.array(
        [
            [2 * z * w, w * w]
            for w, z in (
                (2 * np.pi * 1.2 * problem.band_hz[1], 0.05),
                (2 * np.pi * 2.1 * problem.band_hz[1], 0.02),
            )
        ]
    )
    dD, U0, U1, sD, s0, s1 = problem.fit_upper_residual(base, dens)
    assert U0.shape == U1.shape == s0.shape == (2, *dD.shape)
    d = [s**2 + a1 * s + a0 for a1, a0 in dens]
    for i, j in ((0, 0), (2, 1), (4, 2)):
        hij = h[:, i, j]
        cols = np.stack([hij, hij / d[0], hij * s / d[0], hij / d[1], hij * s / d[1]], -1)
        ref = _lstsq_channel(problem, cols, e, i, j)
        got = [dD[i, j], U0[0, i, j], U1[0, i, j], U0[1, i, j], U1[1, i, j]]
        assert np.allclose(got, ref, rtol=1e-6, atol=0)


def test_two_pseudo_modes_reach_two_truncated_modes_exactly():
    # a noiseless FRF of two modes above the band, each with its own rank-one residue: one
    # pseudo-mode leaves a misfit, two at the modes' poles fit it to rounding, and the
    # static matrix is the modes' compliance (b c^T / w^2 summed)
    problem, base = _problem(stage, stage_params, "missing_mode")
    rng = np.random.default_rng(8)
    f_hi = problem.band_hz[1]
    extra = tuple(
        Mode(
            "flexible", a * f_hi, 0.02, rng.standard_normal(base.n_u), rng.standard_normal(base.n_y)
        )
        for a in (1.2, 1.6)
    )
    truth = replace(base, modes=base.modes + extra)
    G = truth.frf(problem.freq)
    exact = FrfProblem(replace(problem.data, G=G))
    theta = np.log([[m.freq_hz, m.damping] for m in extra]).ravel()
    two = UpperResidual(n_poles=2).build(theta, exact, base)
    assert exact.error(two.model) < 1e-9
    compliance = sum(np.outer(m.c, m.b) / m.omega**2 for m in extra)
    np.testing.assert_allclose(
        two.linear["matrix"], compliance, rtol=1e-6, atol=1e-9 * abs(compliance).max()
    )
    one = UpperResidual()
    best = min(exact.error(one.build(g, exact, base).model) for g in one.grid(exact, base))
    assert best > 1e3 * exact.error(two.model)


@pytest.mark.parametrize(
    "structure,effect", [(ModalMismatch(index=1), "modal_mismatch"), (TimeDelay(), "time_delay")]
)
def test_levenberg_marquardt_path_matches_trust_region_reference(structure, effect, monkeypatch):
    problem, base = _problem(stage, stage_params, effect)
    ours = fit_engine.fit(structure, problem, base)
    monkeypatch.setattr(fit_engine, "FRF_SOLVER", "trf")
    ref = fit_engine.fit(structure, FrfProblem(problem.data), base)
    assert ours.cost <= ref.cost * (1 + 1e-6)
    assert np.allclose(ours.theta, ref.theta, rtol=1e-4, atol=1e-6)
    # standard deviations from the Gram matrix agree with the reference's Jacobian
    assert np.allclose(ours.theta_std, ref.theta_std, rtol=0.05)


@pytest.mark.parametrize("plant,params", [(stage, stage_params), (beam, beam_params)])
def test_composite_jacobian_matches_central_differences(plant, params):
    """A joint refit's analytic Jacobian (parts moving the model by factors: delay, lags,
    moved modes) against central differences of the composite's model residual; a part
    that solves linear parameters from the misfit leaves it to finite differences."""
    problem, base0 = _problem(plant, params, "modal_mismatch")
    base = _with_outer(base0, T_in=False, T_out=False)
    parts = [TimeDelay(), ActuatorDynamics(), SensorDynamics(), ModalMismatch(index=1)]
    thetas = [
        np.array([0.07]),
        np.linspace(0.2, 1.5, base.n_u),
        np.linspace(0.3, 2.0, base.n_y),
        np.log([base.modes[1].freq_hz * 1.01, base.modes[1].damping * 1.3]),
    ]
    if any(m.kind == "rigid" for m in base.modes):
        parts.append(SuspensionStiffness())
        thetas.append(np.log([0.5 * problem.band_hz[0], 0.1]))
    bases, model = [], base
    for p, th in zip(parts, thetas):
        bases.append(model)
        model = p.build(th, problem, model).model
    comp = fit_engine.Composite(parts=tuple(parts), bases=tuple(bases))
    theta = np.concatenate(thetas)
    lines = structure_lines(comp, problem, base)
    J = lines.jacobian(theta)
    Jc = _central(comp, theta, problem, base)
    assert J.shape == Jc.shape == (problem.n_obs, theta.size)
    assert np.max(np.abs(J - Jc)) < 1e-5 * np.max(np.abs(Jc))
    assert np.array_equal(
        lines.residual(theta), problem.residual(comp.build(theta, problem, base).model)
    )
    # an added mode's residue moves with the other parts: finite differences
    mm = MissingMode()
    th_mm = np.log([0.5 * sum(problem.band_hz), 0.02])
    comp2 = fit_engine.Composite(parts=(TimeDelay(), mm), bases=(base, base))
    assert comp2.jacobian(np.concatenate([[0.07], th_mm]), problem, base) is None


@pytest.mark.parametrize("m", [3, 16])
def test_line_terms_keep_norms_and_inner_products(m):
    """LineTerms against the weighted residual ``w (G - fixed - sum_k phi_k terms_k)`` formed
    directly: the cost, J^T J and J^T r, with fewer terms than channels (a QR per line) and
    with as many or more (the lines as they are)."""
    problem, _ = _problem(beam, beam_params, "modal_mismatch")
    rng = np.random.default_rng(5)
    G = problem.data.G
    n_f = G.shape[0]
    scale = np.max(np.abs(G))

    def cplx(*shape):
        return scale * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))

    fixed, terms = cplx(*G.shape), cplx(m, *G.shape)
    phi, dphi = cplx(m, n_f) / scale, cplx(2, m, n_f) / scale
    lines = problem.lines(fixed, terms)
    r = ((G - fixed - np.einsum("mf,mfyu->fyu", phi, terms)) * problem.w).view(float).ravel()
    J = np.stack(
        [(-np.einsum("mf,mfyu->fyu", d, terms) * problem.w).view(float).ravel() for d in dphi],
        -1,
    )
    rc, Jc = lines.residual(phi), lines.jacobian(dphi)
    assert abs(rc @ rc / (r @ r) - 1) < 1e-12
    assert np.max(np.abs(Jc.T @ Jc - J.T @ J)) < 1e-12 * np.max(np.abs(J.T @ J))
    assert np.allclose(Jc.T @ rc, J.T @ r, rtol=0, atol=1e-12 * np.sqrt(np.max(J.T @ J) * (r @ r)))


@pytest.mark.parametrize("plant,params", [(stage, stage_params), (beam, beam_params)])
def test_a_common_lag_is_one_lag_on_every_channel_of_either_side(plant, params):
    # the one-cutoff lag on the inputs is the per-input lag at that cutoff on every input,
    # and the same response as that lag on every output (a scalar factor: l G = G l)
    problem, base = _problem(plant, params, "modal_mismatch")
    common = CommonLag().build(np.array([0.4]), problem, base).model
    per_input = ActuatorDynamics().build(np.full(base.n_u, 0.4), problem, base).model
    per_output = SensorDynamics().build(np.full(base.n_y, 0.4), problem, base).model
    G = problem.predict(common)
    np.testing.assert_allclose(problem.predict(per_input), G, rtol=1e-12, atol=0)
    np.testing.assert_allclose(
        problem.predict(per_output), G, rtol=1e-10, atol=1e-14 * abs(G).max()
    )
    assert CommonLag().bounds(problem, base)[1].shape == (1,)
