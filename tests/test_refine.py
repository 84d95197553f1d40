"""ML refinement of modal models and the Cramer-Rao bound (workbench.ident.refine).

Oracles: python-control's ZOH discretization (closed form of each mode),
central finite differences (the analytic Jacobian), synthetic modal systems
with known parameters (the estimate against the truth, in units of the bound),
and a Monte Carlo spread (the bound itself).
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg

from workbench.core.errors import InputError
from workbench.ident import identify_subspace
from workbench.ident.refine import (
    PeriodicSpectra,
    modal_crb,
    periodic_spectra,
    refine_modal_model,
    zoh_mode_response,
)
from workbench.io.formats import TimeData
from workbench.modal.model import ModalModel, Mode

FS = 2000.0  # Hz, synthetic examples
PERIOD = 400  # samples: 5 Hz lines


# ------------------------------------------------------------------ helpers
def two_by_two() -> ModalModel:
    """2x2 stage-like system: two rigid modes (one per output) and two flexible modes."""
    return ModalModel(
        modes=(
            Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=[0.3, 0.05], c=[1.0, 0.0]),
            Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=[-0.04, 0.5], c=[0.0, 1.0]),
            Mode(kind="flexible", freq_hz=310.0, damping=0.02, b=[0.6, 0.4], c=[0.7, -0.3]),
            Mode(kind="flexible", freq_hz=455.0, damping=0.015, b=[-0.3, 0.7], c=[0.4, 0.6]),
        ),
        D=np.zeros((2, 2)),
    )


def multisine_lines(rng, n_u, lines, amplitude) -> np.ndarray:
    """(PERIOD // 2 + 1, n_u) one-period DFT of a random-phase multisine on ``lines``."""
    X = np.zeros((PERIOD // 2 + 1, n_u), complex)
    X[lines] = amplitude * np.exp(2j * np.pi * rng.uniform(size=(len(lines), n_u)))
    return X


def model_frf_d(model: ModalModel, z: np.ndarray, delay: int = 0) -> np.ndarray:
    """Discrete FRF (n_l, n_y, n_u) of the ZOH of ``model`` (python-control), delay included."""
    sysd = control.c2d(model.to_statespace(), 1 / FS)
    A, B, C, D = (np.asarray(m) for m in (sysd.A, sysd.B, sysd.C, sysd.D))
    n = A.shape[0]
    G = np.array([C @ np.linalg.solve(zz * np.eye(n) - A, B) + D for zz in z])
    return G * (z ** (-delay))[:, None, None]


def periodic_record(model, rng, *, n_periods=5, sigma, delay=1, lines=None) -> TimeData:
    """Open-loop periodic record in steady state: y = ZOH model response + white noise (m)."""
    if lines is None:
        lines = np.arange(3, 130, 2)  # odd lines 15 .. 645 Hz
    U = multisine_lines(rng, model.n_u, lines, amplitude=PERIOD / 2)
    z = np.exp(2j * np.pi * np.arange(U.shape[0]) / PERIOD)
    Y = np.zeros((U.shape[0], model.n_y), complex)
    Y[lines] = np.einsum("lij,lj->li", model_frf_d(model, z[lines], delay), U[lines])
    u = np.tile(np.fft.irfft(U, n=PERIOD, axis=0), (n_periods, 1))
    y = np.tile(np.fft.irfft(Y, n=PERIOD, axis=0), (n_periods, 1))
    y = y + sigma * rng.standard_normal(y.shape)
    return TimeData(fs=FS, u=u, y=y, period=PERIOD)


def closed_loop_spectra(model, rng, *, n_periods=4, sigma, lines) -> PeriodicSpectra:
    """Closed loop u = r - K y per line and period (frequency domain), K a diagonal PD.

    y = S_o (G r + v), u = r - K y: the averaged U carries the controller's
    share of the output noise, as on the real stage.
    """
    z = np.exp(2j * np.pi * lines / PERIOD)
    G = model_frf_d(model, z, delay=1)
    w = 2 * np.pi * lines * FS / PERIOD
    # PD with crossover ~ 40 Hz on a unit-ish mass: k (1 + j w / w_d)
    k = (2 * np.pi * 40.0) ** 2 * (1 + 1j * w / (2 * np.pi * 40.0))
    K = k[:, None, None] * np.eye(model.n_y)[None]
    S_o = np.linalg.inv(np.eye(model.n_y)[None] + G @ K)
    R = multisine_lines(rng, model.n_u, lines, amplitude=PERIOD / 2)[lines]
    V = (
        sigma
        * np.sqrt(PERIOD / 2)
        * (
            rng.standard_normal((n_periods,) + R.shape)
            + 1j * rng.standard_normal((n_periods,) + R.shape)
        )
    )
    Yp = np.einsum("lij,plj->pli", S_o, np.einsum("lij,lj->li", G, R)[None] + V)
    Up = R[None] - np.einsum("lij,plj->pli", K, Yp)
    Um, Ym = Up.mean(0), Yp.mean(0)
    n_l = len(lines)
    return PeriodicSpectra(
        fs=FS,
        period=PERIOD,
        freq_hz=lines * FS / PERIOD,
        U=Um,
        Y=Ym,
        n_avg=np.full(n_l, n_periods),
        dev_line=np.tile(np.arange(n_l), n_periods),
        dU=(Up - Um).reshape(-1, model.n_u),
        dY=(Yp - Ym).reshape(-1, model.n_y),
    )


def flex(model: ModalModel) -> tuple[np.ndarray, np.ndarray]:
    m = model.modes_of_kind("flexible")
    return np.array([x.freq_hz for x in m]), np.array([x.damping for x in m])


def flex_std(model: ModalModel, std: np.ndarray) -> np.ndarray:
    return np.array([s for m, s in zip(model.modes, std) if m.kind == "flexible"])


# -------------------------------------------------------------------- tests
@pytest.mark.parametrize(
    "omega, zeta", [(2000.0, 0.05), (6000.0, 0.009), (300.0, 0.7)], ids=["mid", "light", "heavy"]
)
def test_zoh_mode_response_matches_c2d_and_finite_differences(omega, zeta):
    T = 1 / 5000.0
    z = np.exp(1j * np.linspace(0.05, 3.0, 40))
    g, g_w, g_z = zoh_mode_response(omega, zeta, z, T)
    # ZOH by the matrix exponential of [[A, B], [0, 0]] T, evaluated as C (zI - Ad)^-1 Bd
    A = np.array([[0.0, 1.0], [-(omega**2), -2 * zeta * omega]])
    M = np.zeros((3, 3))
    M[:2, :2], M[1, 2] = A * T, T
    E = scipy.linalg.expm(M)
    Ad, Bd = E[:2, :2], E[:2, 2]
    ref = np.array([np.linalg.solve(zz * np.eye(2) - Ad, Bd)[0] for zz in z])
    np.testing.assert_allclose(g, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    h_w, h_z = 1e-6 * omega, 1e-6 * zeta
    fd_w = (
        zoh_mode_response(omega + h_w, zeta, z, T)[0]
        - zoh_mode_response(omega - h_w, zeta, z, T)[0]
    ) / (2 * h_w)
    fd_z = (
        zoh_mode_response(omega, zeta + h_z, z, T)[0]
        - zoh_mode_response(omega, zeta - h_z, z, T)[0]
    ) / (2 * h_z)
    np.testing.assert_allclose(g_w, fd_w, rtol=1e-5, atol=1e-7 * np.abs(g_w).max())
    np.testing.assert_allclose(g_z, fd_z, rtol=1e-5, atol=1e-7 * np.abs(g_z).max())


def test_model_jacobian_matches_finite_differences():
    from workbench.ident.refine import _model_jacobian
    from workbench.modal.params import pack

    rng = np.random.default_rng(3)
    model = two_by_two()
    lay, theta = pack(model, feedthrough=True)
    theta = theta + 0.01 * rng.standard_normal(theta.shape) * np.maximum(np.abs(theta), 1e-3)
    z = np.exp(2j * np.pi * np.arange(3, 130, 2) / PERIOD)
    U = rng.standard_normal((z.size, 2)) + 1j * rng.standard_normal((z.size, 2))
    _, J = _model_jacobian(lay, theta, z, U, 1 / FS, 1)
    for j in range(lay.n_par):
        h = 1e-6 * max(abs(theta[j]), 1e-2)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (
            _model_jacobian(lay, tp, z, U, 1 / FS, 1)[0]
            - _model_jacobian(lay, tm, z, U, 1 / FS, 1)[0]
        ) / (2 * h)
        scale = np.abs(J[:, :, j]).max()
        assert np.abs(fd - J[:, :, j]).max() <= 1e-5 * scale, lay.names[j]


def test_periodic_spectra_of_an_exact_record_obey_y_equals_g_u():
    rng = np.random.default_rng(0)
    model = two_by_two()
    data = periodic_record(model, rng, sigma=0.0)
    spec = periodic_spectra(data)
    assert spec.n_lines == 64 and np.all(spec.n_avg == 4)  # 5 periods, the first dropped
    G = model_frf_d(model, spec.z, delay=1)
    np.testing.assert_allclose(
        spec.Y, np.einsum("lij,lj->li", G, spec.U), atol=1e-9 * np.abs(spec.Y).max()
    )


def test_refinement_improves_the_subspace_start_to_within_a_few_crb_sigmas():
    """Open loop, 2x2, noisy: subspace (MOESP) -> modal -> refine, against the truth.

    Over 6 noise realizations the refined flexible-mode frequencies and
    dampings lie within 4 bound standard deviations of the truth (all 24),
    closer in RMS than the subspace start, and the standard errors the
    estimator reports agree with the bound at the truth.
    """
    true = two_by_two()
    sigma = 3e-7  # m per sample: bound ~0.02-0.06 Hz on the two modes
    f0, z0 = flex(true)
    e_start, e_ref, std_ratio, misfit = [], [], [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        data = periodic_record(true, rng, sigma=sigma)
        sub = identify_subspace(data, method="moesp", order=8, block_rows=10, input_delay=1)
        start = ModalModel.from_statespace(sub.model)
        res = refine_modal_model(start, data, input_delay=1)
        assert res.success and not res.notes
        assert len(res.model.modes_of_kind("rigid")) == 2
        crb = modal_crb(true, periodic_spectra(data), noise_cov=sigma**2 * np.eye(2), input_delay=1)
        f_crb, z_crb = flex_std(true, crb.freq_std_hz), flex_std(true, crb.damping_std)
        for model, out in ((start, e_start), (res.model, e_ref)):
            f, z = flex(model)
            out.append(np.r_[(f - f0) / f_crb, (z - z0) / z_crb])
        std_ratio.append(flex_std(res.model, res.freq_std_hz) / f_crb)
        misfit.append(res.misfit)
    e_start, e_ref = np.array(e_start), np.array(e_ref)
    assert np.all(np.abs(e_ref) < 4.0), e_ref
    assert np.sqrt(np.mean(e_ref**2)) < 0.8 * np.sqrt(np.mean(e_start**2))
    # noise estimated from 4 periods: the reported standard errors within 30 % of the bound
    np.testing.assert_allclose(std_ratio, 1.0, atol=0.3)
    assert 0.8 < np.mean(misfit) < 1.3  # weighted misfit at the noise level


def test_closed_loop_refinement_is_unbiased_within_the_bound():
    """Closed loop (u = r - K y): the start perturbed, the estimate back within the bound."""
    rng = np.random.default_rng(5)
    true = two_by_two()
    sigma = 3e-8
    lines = np.arange(3, 130, 2)
    spec = closed_loop_spectra(true, rng, sigma=sigma, lines=lines)
    start = ModalModel(
        modes=tuple(
            Mode(
                kind=m.kind,
                freq_hz=m.freq_hz * 1.003,
                damping=m.damping * 1.2,
                b=m.b * 1.05,
                c=m.c * 0.97,
            )
            for m in true.modes
        ),
        D=true.D,
    )
    res = refine_modal_model(start, spec, input_delay=1)
    crb = modal_crb(true, spec, noise_cov=sigma**2 * np.eye(2), input_delay=1)
    f0, z0 = flex(true)
    f1, z1 = flex(res.model)
    assert np.all(np.abs(f1 - f0) < 4 * flex_std(true, crb.freq_std_hz))
    assert np.all(np.abs(z1 - z0) < 4 * flex_std(true, crb.damping_std))
    assert np.all(np.abs(f1 - f0) < 0.1 * np.abs(f0 * 0.003))  # from a 0.3 % start error


def test_crb_matches_the_monte_carlo_spread_of_a_siso_resonance():
    """One mode, SISO, white noise: the ML spread over 300 runs equals the bound.

    The frequency-domain data Y_l = G U_l + V_l are drawn directly; the
    estimator is the ML (noise covariance known), so its spread must match
    the bound to the Monte Carlo accuracy (std of a std from 300 runs: 4 %).
    """
    rng = np.random.default_rng(2)
    true = ModalModel(
        modes=(Mode(kind="flexible", freq_hz=200.0, damping=0.02, b=[1.0], c=[1.0]),),
        D=np.zeros((1, 1)),
    )
    lines = np.arange(30, 51)  # 150 .. 250 Hz at 5 Hz
    n_avg, sigma = 4, 1e-8
    U = (PERIOD / 2) * np.exp(2j * np.pi * rng.uniform(size=(lines.size, 1)))
    z = np.exp(2j * np.pi * lines / PERIOD)
    Y0 = np.einsum("lij,lj->li", model_frf_d(true, z), U)
    # averaged noise per line: CN(0, PERIOD sigma^2 / n_avg)
    s = sigma * np.sqrt(PERIOD / n_avg / 2)

    def spectra(Y):
        return PeriodicSpectra(
            fs=FS,
            period=PERIOD,
            freq_hz=lines * FS / PERIOD,
            U=U,
            Y=Y,
            n_avg=np.full(lines.size, n_avg),
            dev_line=np.zeros(0, int),
            dU=np.zeros((0, 1)),
            dY=np.zeros((0, 1)),
        )

    crb = modal_crb(true, spectra(Y0), noise_cov=[sigma**2], feedthrough=False)
    est = []
    for _ in range(300):
        V = s * (rng.standard_normal(Y0.shape) + 1j * rng.standard_normal(Y0.shape))
        res = refine_modal_model(
            true, spectra(Y0 + V), noise_cov=[sigma**2], feedthrough=False, reweight=0
        )
        m = res.model.modes[0]
        est.append((m.freq_hz, m.damping))
    est = np.array(est)
    np.testing.assert_allclose(est.std(axis=0), [crb.freq_std_hz[0], crb.damping_std[0]], rtol=0.15)
    # unbiased to the Monte Carlo accuracy
    assert abs(est[:, 0].mean() - 200.0) < 4 * crb.freq_std_hz[0] / np.sqrt(300)
    # the standard error the estimator reports is the bound at its estimate
    np.testing.assert_allclose(res.freq_std_hz[0], crb.freq_std_hz[0], rtol=0.05)


def test_crb_of_a_feedthrough_is_the_closed_form():
    """G = D (no modes): var(D) = PERIOD sigma^2 / (2 n_avg sum |U_l|^2), in closed form."""
    lines = np.arange(5, 25)
    U = np.full((lines.size, 1), PERIOD / 2, complex)
    spec = PeriodicSpectra(
        fs=FS,
        period=PERIOD,
        freq_hz=lines * FS / PERIOD,
        U=U,
        Y=np.zeros((lines.size, 1)),
        n_avg=np.full(lines.size, 3),
        dev_line=np.zeros(0, int),
        dU=np.zeros((0, 1)),
        dY=np.zeros((0, 1)),
    )
    sigma = 2e-9
    crb = modal_crb(ModalModel(modes=(), D=np.zeros((1, 1))), spec, noise_cov=[sigma**2])
    # Fisher of the real D: 2 sum n_avg |U|^2 / (PERIOD sigma^2)
    expected = PERIOD * sigma**2 / (2 * 3 * np.sum(np.abs(U) ** 2))
    np.testing.assert_allclose(crb.covariance[0, 0], expected, rtol=1e-12)


def test_refine_refuses_bad_input():
    rng = np.random.default_rng(0)
    model = two_by_two()
    data = periodic_record(model, rng, sigma=1e-9)
    with pytest.raises(InputError, match="period"):
        refine_modal_model(model, TimeData(fs=FS, u=data.u, y=data.y))
    with pytest.raises(InputError, match="outputs"):
        refine_modal_model(ModalModel(modes=(), D=np.zeros((1, 2))), data)
    with pytest.raises(InputError, match="input_delay"):
        refine_modal_model(model, data, input_delay=-1)
    one = TimeData(fs=FS, u=data.u[: 2 * PERIOD], y=data.y[: 2 * PERIOD], period=PERIOD)
    with pytest.raises(InputError, match="noise_cov"):
        refine_modal_model(model, one)
    with pytest.raises(InputError, match="noise_cov"):
        modal_crb(model, periodic_spectra(data), noise_cov=np.eye(3))


def test_cli_identify_refine(tmp_path, capsys):
    """``identify --modal --refine`` writes the refined modal model and prints its errors."""
    import json

    from workbench.cli.main import main
    from workbench.io.formats import save_measurement

    true = two_by_two()
    data = periodic_record(true, np.random.default_rng(4), sigma=3e-7)
    path, out, modal = tmp_path / "d.npz", tmp_path / "m.npz", tmp_path / "modal.npz"
    save_measurement(path, data)
    argv = ["identify", str(path), "--method", "moesp", "--order", "8", "--block-rows", "10"]
    argv += ["--input-delay", "1", "--out", str(out)]
    assert main(argv + ["--modal", str(modal), "--refine"]) == 0
    text = capsys.readouterr().out
    assert "refined by maximum likelihood on 64 lines" in text
    assert main(["modes", str(modal), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["modes"]
    f = [r["freq_hz"] for r in rows if r["kind"] == "flexible"]
    # the bound is ~0.02-0.06 Hz here (see the test above): 0.3 Hz is a loose, safe tolerance
    assert f == pytest.approx([310.0, 455.0], abs=0.3)
    assert main(argv + ["--refine"]) == 2  # --refine needs --modal
    assert "--modal" in capsys.readouterr().err


def test_docstring_examples_run():
    import doctest

    import workbench.ident.refine as mod

    result = doctest.testmod(mod)
    assert result.attempted >= 2 and result.failed == 0
