"""`workbench modalfit FRF.npz --out MODAL.npz [--modes N | --band F1 F2] [--json] [--plots]`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_modalfit import FREQ, LINES, frf_data, known_model

from workbench.cli.main import main
from workbench.core import lti
from workbench.io.formats import TimeData, load_model, read_npz, save_measurement


@pytest.fixture(scope="module")
def frf_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("modalfit")
    save_measurement(d / "frf.npz", frf_data(known_model(), noise=0.01, seed=2))
    return d / "frf.npz"


def test_writes_a_spec2_model_whose_frf_is_the_fit(frf_file, tmp_path, capsys):
    out = tmp_path / "modal.npz"
    rc = main(["modalfit", str(frf_file), "--out", str(out), "--json", "--plots", str(tmp_path)])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_modes"] == 4 and summary["status"] == "ok"
    freq = [m["freq_hz"] for m in summary["modes"]]
    np.testing.assert_allclose(freq, FREQ, rtol=5e-4)
    assert all(m["freq_std_hz"] > 0 for m in summary["modes"])
    # the file: a continuous state space (spec 2) with the mode table beside it
    sys = load_model(out)
    G_file = lti.frf(sys, LINES)
    G_true = known_model().frf(LINES)
    rel = np.linalg.norm(G_file - G_true, axis=(1, 2)) / np.linalg.norm(G_true, axis=(1, 2))
    assert np.mean(rel) < 0.01  # the fit is within the 1 % noise of the truth
    arrays = read_npz(out)
    np.testing.assert_allclose(arrays["modal_freq_hz"], freq)
    assert arrays["modal_b"].shape == (4, 2) and arrays["modal_c"].shape == (4, 3)
    for name in ("stabilization.png", "fit_overlay.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_modes_and_band_select(frf_file, tmp_path, capsys):
    out = tmp_path / "m2.npz"
    assert main(["modalfit", str(frf_file), "--out", str(out), "--modes", "2", "--json"]) == 0
    two = json.loads(capsys.readouterr().out)
    assert two["n_modes"] == 2
    out = tmp_path / "m3.npz"
    argv = ["modalfit", str(frf_file), "--out", str(out), "--band", "100", "200", "--json"]
    assert main(argv) == 0
    band = json.loads(capsys.readouterr().out)
    # the 42 Hz mode below the band enters as the lower residual L / s^2 (automatic with
    # --band), the 310 Hz one as the upper residual
    assert band["n_modes"] == 2 and band["rigid"]
    freq = [m["freq_hz"] for m in band["modes"]]
    np.testing.assert_allclose(freq, FREQ[1:3], rtol=5e-4)


def test_collocated_pair_scales_the_model(frf_file, tmp_path, capsys):
    out = tmp_path / "m.npz"
    assert main(["modalfit", str(frf_file), "--out", str(out), "--collocated", "s1:F1"]) == 0
    arrays = read_npz(out)
    assert list(arrays["modal_collocated"]) == ["s1", "F1"]
    phi_s, phi_a = arrays["modal_phi_sensors"], arrays["modal_phi_actuators"]
    ok = np.isfinite(phi_s[:, 0])
    np.testing.assert_allclose(phi_s[ok, 0], phi_a[ok, 0], rtol=1e-12)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--collocated", "s1"], "--collocated: expected SENSOR:ACTUATOR"),
        (["--collocated", "s9:F1"], "collocated sensor: expected one of s1, s2, s3"),
        (["--modes", "50"], "modes: expected at most"),
        (["--band", "100", "101"], "band: expected at least 8 lines"),
        (["--max-order", "0"], "max_order: expected an integer"),
    ],
)
def test_bad_input_one_line_no_file(frf_file, tmp_path, capsys, extra, message):
    out = tmp_path / "o.npz"
    rc = main(["modalfit", str(frf_file), "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("\n") == 1, err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_time_record_and_output_over_input_refused(frf_file, tmp_path, capsys):
    rec = tmp_path / "t.npz"
    save_measurement(rec, TimeData(1000.0, np.ones((64, 2)), np.ones((64, 3))))
    assert main(["modalfit", str(rec), "--out", str(tmp_path / "o.npz")]) == 2
    assert "expected an FRF" in capsys.readouterr().err
    before = frf_file.read_bytes()
    assert main(["modalfit", str(frf_file), "--out", str(frf_file)]) == 2
    assert "over an input file" in capsys.readouterr().err
    assert frf_file.read_bytes() == before
