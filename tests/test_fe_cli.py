"""workbench update / predict on a synthetic beam FRF (FE truth on a finer mesh)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from plants.beam import BeamConfig, beam_fe_file, beam_prior_config
from workbench.cli.main import main
from workbench.fe import fe_arrays, modal_terms, read_fe, save_fe
from workbench.io.formats import FrfData, load_measurement, save_measurement


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fe")
    truth_cfg = dataclasses.replace(BeamConfig(), n_elements=100)
    truth = read_fe_with_damping(beam_fe_file(truth_cfg), d / "truth.npz")
    freq = np.arange(1.0, 1000.0, 0.5)
    G = modal_terms(truth, n_modes=truth.n_dof).frf(freq)  # (n_f, 5, 3)
    rng = np.random.default_rng(1)
    sigma = 0.01 * np.abs(G) + 1e-12  # 1 % noise, as in seed 001's setting
    noisy = G + sigma / np.sqrt(2) * (
        rng.standard_normal(G.shape) + 1j * rng.standard_normal(G.shape)
    )
    names_in = ("F1", "F2", "F3")
    seen, held = [0, 1, 4], [2, 3]
    save_measurement(
        d / "meas.npz",
        FrfData(freq, noisy[:, seen], sigma[:, seen] ** 2, 2048.0, names_in, ("s1", "s2", "s5")),
    )
    save_measurement(
        d / "valid.npz",
        FrfData(freq, noisy[:, held], sigma[:, held] ** 2, 2048.0, names_in, ("s3", "s4")),
    )
    save_fe(d / "prior.npz", beam_fe_file(beam_prior_config(), damping=0.01))
    return d, truth_cfg


def read_fe_with_damping(fe, path):
    """The truth with a frequency-dependent damping of every mode."""
    save_fe(path, fe, damping=np.linspace(0.006, 0.012, fe.n_dof))
    return read_fe(path)


def test_update_then_predict_held_out_sensors(files, capsys):
    d, truth_cfg = files
    rc = main(
        [
            "update",
            "--fe", str(d / "prior.npz"),
            "--data", str(d / "meas.npz"),
            "--out", str(d / "up.npz"),
            "--json", str(d / "rep.json"),
            "--band", "1", "999",
            "--plots", str(d / "plots"),
        ]
    )  # fmt: skip
    assert rc == 0
    rep = json.loads((d / "rep.json").read_text())
    assert (d / "plots" / "update_mac.png").stat().st_size > 0
    assert (d / "plots" / "update_frequencies.png").stat().st_size > 0
    up = read_fe(d / "up.npz")
    # scalar 0.01 in the file: kept for every unpaired mode, measured for the paired
    assert up.damping.size == up.n_dof and np.all(up.damping[9:] == 0.01)
    np.testing.assert_allclose(up.damping[:9], [m["damping"] for m in rep["modes"]])
    after = np.array([p["after"] for p in rep["parameters"]])
    err = np.abs(after / truth_cfg.alpha - 1)
    assert np.all(err[:2] < 0.01) and np.all(err[2:] < 0.05), err
    assert rep["unpaired_measured"] == []
    prior_raw = np.load(d / "prior.npz")
    up_raw = np.load(d / "up.npz")
    for key in prior_raw.files:
        if key not in ("alpha", "damping"):
            assert np.array_equal(prior_raw[key], up_raw[key]), key
    assert not np.array_equal(prior_raw["alpha"], up_raw["alpha"])
    capsys.readouterr()
    assert (
        main(
            [
                "predict",
                "--fe",
                str(d / "up.npz"),
                "--data",
                str(d / "valid.npz"),
                "--out",
                str(d / "p.npz"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "prediction error (s3, s4)" in out
    # up to the 9th mode (the measure of issue 9): within twice the noise level
    pred, valid = load_measurement(d / "p.npz"), load_measurement(d / "valid.npz")
    f9 = rep["modes"][-1]["freq_measured_hz"]
    sel = valid.freq <= f9
    Gm = valid.G[sel]
    err_up = np.mean(
        np.linalg.norm(pred.G[sel][:, 2:4] - Gm, axis=(1, 2)) / np.linalg.norm(Gm, axis=(1, 2))
    )
    noise = np.mean(np.sqrt(valid.G_var[sel].sum((1, 2))) / np.linalg.norm(Gm, axis=(1, 2)))
    assert err_up < 2 * noise, (err_up, noise)
    assert pred.output_names == ("s1", "s2", "s3", "s4", "s5")
    main(
        [
            "predict",
            "--fe",
            str(d / "prior.npz"),
            "--data",
            str(d / "valid.npz"),
            "--out",
            str(d / "p0.npz"),
        ]
    )
    out0 = capsys.readouterr().out
    assert float(out0.split("mean ")[1].split(",")[0]) > 10 * err_up


def test_refusals_one_line(files, capsys, tmp_path):
    d, _ = files
    fe = read_fe(d / "prior.npz")
    bad = fe_arrays(fe)
    bad["output_names"] = np.array(["s1", "s2", "s3", "s4", "x5"])
    np.savez(tmp_path / "bad_names.npz", **bad)
    rc = main(
        [
            "update",
            "--fe",
            str(tmp_path / "bad_names.npz"),
            "--data",
            str(d / "meas.npz"),
            "--out",
            str(tmp_path / "o.npz"),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "output 's5' is not in the FE model" in err and err.count("\n") == 1
    asym = fe_arrays(fe)
    K0 = np.array(asym["K0"])
    K0[0, 1] += 1.0
    asym["K0"] = K0
    np.savez(tmp_path / "asym.npz", **asym)
    rc = main(
        [
            "predict",
            "--fe",
            str(tmp_path / "asym.npz"),
            "--data",
            str(d / "valid.npz"),
            "--out",
            str(tmp_path / "o.npz"),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "symmetric" in err and err.count("\n") == 1
    rc = main(
        [
            "predict",
            "--fe",
            str(d / "prior.npz"),
            "--data",
            str(d / "valid.npz"),
            "--outputs",
            "s3,s7",
            "--out",
            str(tmp_path / "o.npz"),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "'s7'" in err
    rc = main(
        [
            "update",
            "--fe",
            str(d / "prior.npz"),
            "--data",
            str(d / "meas.npz"),
            "--out",
            str(d / "prior.npz"),
        ]
    )
    assert rc == 2 and not (tmp_path / "o.npz").exists()
