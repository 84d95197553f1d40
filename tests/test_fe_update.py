"""workbench.fe: spec-4 FE file, eigen-sensitivities, pairing, updating, prediction, reduction."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from plants.beam import BeamConfig, beam_fe_file, beam_prior_config
from workbench.core.errors import InputError
from workbench.fe import (
    MeasuredModes,
    eigen_sensitivities,
    fe_arrays,
    fe_from_arrays,
    fe_residues,
    modal_terms,
    pair_modes,
    predict_frf,
    read_fe,
    reduce_fe,
    save_fe,
    solve_modes,
    update_fe,
)

SEEN = ("s1", "s2", "s5")
INPUTS = ("F1", "F2", "F3")


def _measured(fe, n=9, outputs=SEEN, noise=0.0, seed=0):
    modes = solve_modes(*fe.matrices(), n)
    R = fe_residues(fe, modes.Phi, fe.output_index(outputs), fe.input_index(INPUTS))
    rng = np.random.default_rng(seed)
    f = modes.freq_hz * (1 + noise * 0.05 * rng.standard_normal(n))
    R = R + noise * np.sqrt(np.mean(R**2, axis=(1, 2)))[:, None, None] * rng.standard_normal(
        R.shape
    )
    return MeasuredModes(f, np.linspace(0.01, 0.02, n), R, outputs, INPUTS)


@pytest.fixture(scope="module")
def prior():
    return beam_fe_file(beam_prior_config(), damping=0.01)


def test_sensitivities_match_finite_differences():
    # a coarse mesh: lambda_max small, so finite differences are not round-off bound
    prior = beam_fe_file(dataclasses.replace(beam_prior_config(), n_elements=10))
    alpha = prior.alpha
    modes = solve_modes(*prior.matrices(alpha), 8)
    dlam, dPhi = eigen_sensitivities(prior, modes, alpha)
    lam_max = solve_modes(*prior.matrices(alpha)).lam[-1]
    for i in range(prior.n_par):
        # central differences in log(alpha); the step is large enough that the
        # eigen-solver's round-off (~ eps lambda_max) stays below the tolerance
        h = 1e-3
        ap, am = alpha.copy(), alpha.copy()
        ap[i] *= np.exp(h)
        am[i] *= np.exp(-h)
        mp, mm = solve_modes(*prior.matrices(ap), 8), solve_modes(*prior.matrices(am), 8)
        fd = (mp.lam - mm.lam) / (2 * h)
        an = dlam[:, i] * alpha[i]
        assert np.all(np.abs(an - fd) <= 1e-4 * np.abs(fd) + 1e-12 * lam_max / h), (i, an, fd)
        # shapes: align signs with the unperturbed ones before differencing
        sp = np.sign(np.sum(mp.Phi * modes.Phi, 0))
        sm = np.sign(np.sum(mm.Phi * modes.Phi, 0))
        fdPhi = (mp.Phi * sp - mm.Phi * sm) / (2 * h)
        anPhi = dPhi[i] * alpha[i]
        scale = np.abs(modes.Phi).max(axis=0)
        assert np.all(
            np.abs(anPhi - fdPhi).max(axis=0) <= 1e-5 * scale + 1e-3 * np.abs(fdPhi).max(axis=0)
        )
    # the mass-matrix term: density lowers every eigenvalue, by at most lambda / rho
    # (all of it when the beam's own mass is all the mass; lumped masses take a share)
    d_rho = dlam[:, 1] * alpha[1]
    assert np.all(d_rho < 0) and np.all(-d_rho <= modes.lam * (1 + 1e-9))


def test_update_recovers_alpha_from_a_finer_mesh(prior):
    true_cfg = dataclasses.replace(BeamConfig(), n_elements=150)
    meas = _measured(beam_fe_file(true_cfg))
    res = update_fe(prior, meas)
    # the 50-element file against a 150-element truth: discretization error only
    np.testing.assert_allclose(res.alpha, true_cfg.alpha, rtol=1e-3)
    assert res.unpaired == ()
    assert len(res.pairs) == 9
    # the prior was 8 % / 30 % off: the update must really have moved it
    assert np.all(np.abs(res.alpha_nominal / true_cfg.alpha - 1)[[0, 2, 3]] > 0.07)
    assert np.all(res.alpha_std > 0)
    np.testing.assert_allclose(res.freq_after_hz[:9], meas.freq_hz, rtol=1e-4)
    np.testing.assert_allclose(res.damping[:9], meas.damping)


def test_update_with_noise_std_covers_error(prior):
    true_cfg = BeamConfig()
    meas = _measured(beam_fe_file(true_cfg), noise=0.01, seed=3)
    res = update_fe(prior, meas, freq_rel_std=5e-4, residue_rel_std=0.01)
    err = np.abs(res.alpha / true_cfg.alpha - 1)
    assert np.all(err[:2] < 0.01) and np.all(err[2:] < 0.05)
    assert np.all(np.abs(res.alpha - true_cfg.alpha) < 5 * res.alpha_std)


def test_unmatched_measured_mode_left_unpaired(prior):
    meas = _measured(beam_fe_file(BeamConfig()))
    # an extra mode that only a (tilted) sensor s5 sees: no FE partner
    R = np.zeros((1, 3, 3))
    R[0, 2] = [1.0, 0.5, -0.3]
    extra = MeasuredModes(
        np.r_[meas.freq_hz, 572.0],
        np.r_[meas.damping, 0.01],
        np.concatenate([meas.residues, R * np.abs(meas.residues[5]).max()]),
        SEEN,
        INPUTS,
    )
    res = update_fe(prior, extra)
    assert res.unpaired == (9,)
    # same mesh, no noise: only the (weak) pull toward the nominal remains
    np.testing.assert_allclose(res.alpha, BeamConfig().alpha, rtol=1e-3)
    pairs, unpaired, mac = pair_modes(
        extra,
        res.freq_after_hz,
        fe_residues(
            prior,
            solve_modes(*prior.matrices(res.alpha), res.freq_after_hz.size).Phi,
            [0, 1, 4],
            [0, 1, 2],
        ),
    )
    assert unpaired == [9] and mac.shape == (10, res.freq_after_hz.size)


def test_measured_std_shape_refused():
    with pytest.raises(InputError, match="freq_std_hz"):
        MeasuredModes([10.0], [0.01], np.ones((1, 1, 1)), ("s1",), ("F1",), freq_std_hz=[1.0, 2.0])


def test_unknown_channel_refused(prior):
    meas = _measured(beam_fe_file(BeamConfig()))
    bad = MeasuredModes(meas.freq_hz, meas.damping, meas.residues, ("s1", "s2", "s9"), INPUTS)
    with pytest.raises(InputError, match="'s9' is not in the FE model"):
        update_fe(prior, bad)


def test_prediction_matches_direct_solve(prior):
    """Modal sum over all modes = (K - w^2 M + j w Cd)^-1 with the modal damping matrix."""
    f = np.array([5.0, 77.0, 400.0])
    G = predict_frf(prior, f, outputs=["s3", "s4"], inputs=["F2"])
    K, M = prior.matrices()
    modes = solve_modes(K, M)
    w = np.sqrt(np.clip(modes.lam, 0, None))
    Minv_phi = M @ modes.Phi
    Cd = Minv_phi @ np.diag(2 * 0.01 * w) @ Minv_phi.T
    B = prior.B[:, [1]]
    C = prior.C[[2, 3]]
    for j, fj in enumerate(f):
        s = 2j * np.pi * fj
        ref = C @ np.linalg.solve(K + s * Cd + s**2 * M, B)
        np.testing.assert_allclose(G[j], ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


def test_reduction_keeps_static_gain(prior):
    n = 6
    model = reduce_fe(prior, n)
    t_all = modal_terms(prior)
    # below the last kept mode (384 Hz) the residual compliance carries the rest;
    # without it the error at 150 Hz would be ~ the dropped modes' static share
    f = np.array([0.7, 50.0, 150.0])
    G, G_all = model.frf(f), t_all.frf(f)
    err = np.abs(G - G_all).max(axis=(1, 2)) / np.abs(G_all).max(axis=(1, 2))
    assert np.all(err < 0.01), err
    no_res = model.frf(f) - model.D
    assert np.abs(no_res - G_all).max() > 3 * np.abs(G - G_all).max()
    assert len(model.modes) == n
    sys = model.to_statespace()
    assert sys.nstates == 2 * n


# ------------------------------------------------------------------ the file
def _arrays(prior):
    return {k: np.array(v) for k, v in fe_arrays(prior).items()}


@pytest.mark.parametrize(
    "change, match",
    [
        (
            lambda a: a.__setitem__("K0", a["K0"] + np.triu(np.ones_like(a["K0"]), 1)),
            "'K0'.*symmetric",
        ),
        (lambda a: a.__setitem__("M0", a["M0"] - 1e3 * np.eye(len(a["M0"]))), "positive definite"),
        (lambda a: a.__setitem__("C", a["C"][:, :-1]), "'C'.*expected shape"),
        (lambda a: a.__setitem__("K_i", a["K_i"][:3]), "'K_i'.*expected shape"),
        (lambda a: a.pop("output_names"), "missing key 'output_names'"),
        (lambda a: a.__setitem__("parameter_names", a["parameter_names"][:2]), "parameter_names"),
        (lambda a: a.__setitem__("kind", np.array("frf")), "'kind'"),
        (lambda a: a.__setitem__("damping", np.array(-0.1)), "damping"),
    ],
)
def test_bad_fe_file_refused_in_one_line(prior, change, match):
    arrays = _arrays(prior)
    change(arrays)
    with pytest.raises(InputError, match=match) as exc:
        fe_from_arrays(arrays, src="f.npz")
    assert "\n" not in str(exc.value)


def test_file_round_trip_keeps_matrices_exactly(prior, tmp_path):
    path = tmp_path / "fe.npz"
    save_fe(path, prior)
    back = read_fe(path)
    for key in ("K0", "M0", "K_i", "M_i", "B", "C"):
        assert np.array_equal(getattr(back, key), getattr(prior, key))
    new = prior.alpha * 1.01
    save_fe(tmp_path / "up.npz", back, alpha=new, damping=np.array([0.02, 0.03]))
    up = read_fe(tmp_path / "up.npz")
    assert np.array_equal(up.alpha, new) and np.array_equal(up.K_i, prior.K_i)
    np.testing.assert_array_equal(up.mode_damping(3), [0.02, 0.03, np.nan])


def test_sparse_eigen_solve_against_dense():
    # same matrices, 50 elements: the two solvers agree to round-off
    fe = beam_fe_file()
    K, M = fe.matrices()
    a = solve_modes(K, M, 12, method="banded")
    b = solve_modes(K, M, 12, method="dense")
    np.testing.assert_allclose(a.lam, b.lam, rtol=1e-5)  # dense: ~eps lambda_max on the lowest
    np.testing.assert_allclose(np.abs(np.sum(a.Phi * (M @ b.Phi), 0)), 1.0, atol=1e-5)
    # a finer mesh (302 DOF) through the sparse path: it converges to the coarse answer
    # within the coarse mesh's discretization error. (Much finer meshes are round-off
    # bound on the suspension modes for any solver: K's entries ~ lambda_max, and
    # eps lambda_max / lambda_1 is 2e-4 at 150 elements, 0.17 at 800.)
    fine = beam_fe_file(dataclasses.replace(BeamConfig(), n_elements=150))
    c = solve_modes(*fine.matrices(), 8, method="banded")
    np.testing.assert_allclose(c.lam, b.lam[:8], rtol=1e-4)
