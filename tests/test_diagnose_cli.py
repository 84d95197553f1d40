"""`workbench diagnose` and `workbench augment` through the CLI: formats, exit codes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_diagnose_gen import frf_case, stage, stage_params

from workbench.cli.main import main
from workbench.io.formats import load_model, read_npz, save_measurement, save_model


@pytest.fixture
def delay_case(tmp_path):
    case = frf_case(
        stage(),
        "time_delay",
        stage_params("time_delay", "clear"),
        rel=0.005,
        rng=np.random.default_rng(9),
    )
    save_model(tmp_path / "model.npz", case.nominal)
    save_measurement(tmp_path / "data.npz", case.data)
    return tmp_path, case


def test_diagnose_writes_spec_json(delay_case, capsys):
    folder, case = delay_case
    out = folder / "findings.json"
    rc = main(
        [
            "diagnose",
            "--model",
            str(folder / "model.npz"),
            "--data",
            str(folder / "data.npz"),
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    js = json.loads(out.read_text())
    assert set(js) >= {"error_before", "findings"}
    f0 = js["findings"][0]
    assert f0["effect"] == "time_delay"
    assert set(f0) >= {
        "effect",
        "inputs",
        "outputs",
        "band_hz",
        "parameters",
        "error_after",
        "explanation",
    }
    assert f0["parameters"]["delay_s"] == pytest.approx(2e-4, rel=0.1)
    assert "time_delay" in capsys.readouterr().out


def test_diagnose_refuses_mismatched_model(delay_case, tmp_path, capsys):
    folder, case = delay_case
    import control

    save_model(tmp_path / "small.npz", control.ss(-1.0, 1.0, 1.0, 0.0))
    rc = main(
        ["diagnose", "--model", str(tmp_path / "small.npz"), "--data", str(folder / "data.npz")]
    )
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err


def test_diagnose_refuses_output_over_input(delay_case, capsys):
    folder, _ = delay_case
    rc = main(
        [
            "diagnose",
            "--model",
            str(folder / "model.npz"),
            "--data",
            str(folder / "data.npz"),
            "--json",
            str(folder / "data.npz"),
        ]
    )
    assert rc == 2
    assert read_npz(folder / "data.npz")["kind"] == "frf"  # untouched


def test_diagnose_refuses_bad_file(tmp_path, capsys):
    (tmp_path / "bad.npz").write_text("not a zip")
    rc = main(
        ["diagnose", "--model", str(tmp_path / "bad.npz"), "--data", str(tmp_path / "bad.npz")]
    )
    assert rc == 2


def test_augment_writes_model_with_delay(delay_case, capsys):
    folder, case = delay_case
    out = folder / "aug.npz"
    rc = main(
        [
            "augment",
            "--model",
            str(folder / "model.npz"),
            "--data",
            str(folder / "data.npz"),
            "--effect",
            "time_delay",
            "--out",
            str(out),
            "--plots",
            str(folder / "plots"),
        ]
    )
    assert rc == 0
    arrays = read_npz(out)
    assert float(arrays["delay_s"]) == pytest.approx(2e-4, rel=0.05)
    assert "A_pade" in arrays
    load_model(out)  # a valid spec model
    assert (folder / "plots" / "bode.png").is_file()
    text = capsys.readouterr().out
    assert "error before" in text and "error after" in text and "Pade" in text


def test_augment_python_api_missing_mode():
    from workbench.diagnosis.augment import augment

    truth = stage_params("missing_mode", "clear")
    case = frf_case(stage(), "missing_mode", truth, rel=0.005, rng=np.random.default_rng(2))
    res = augment(case.nominal, case.data, "missing_mode")
    assert res.parameters["freq_hz"] == pytest.approx(1320.0, rel=0.01)
    assert res.error_after < 2 * case.noise_floor < res.error_before
    assert res.model.n_x == case.nominal.nstates + 2  # a rank-one residue: 2 states
