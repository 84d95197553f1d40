"""Boundary validation of the exchange formats (shared/spec/data-format.md).

Every bad file is refused through the CLI (``workbench info FILE``, or
``workbench compare`` for a model/data mismatch) with exit status 2 and one
line on stderr naming the file, the key, what was expected and what came.
The three shared examples are read and their ``nominal_error`` reproduced.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_EXAMPLES, require_shared

from workbench import sim
from workbench.cli.main import main
from workbench.core import lti
from workbench.io import formats

EXAMPLES = SHARED_EXAMPLES
N = 64  # samples of the small synthetic records: any N >= 2 would do


# ----------------------------------------------------------------- fixtures
def time_arrays(rng: np.random.Generator, *, n_u: int = 2, n_y: int = 3) -> dict:
    return {
        "kind": np.array("time"),
        "fs": np.array(1000.0),
        "u": rng.standard_normal((N, n_u)),
        "y": rng.standard_normal((N, n_y)),
        "r": rng.standard_normal((N, n_u)),
        "loop": np.array("closed"),
    }


def frf_arrays(rng: np.random.Generator, *, n_f: int = 20) -> dict:
    G = rng.standard_normal((n_f, 3, 2)) + 1j * rng.standard_normal((n_f, 3, 2))
    return {
        "kind": np.array("frf"),
        "freq": np.linspace(1.0, 100.0, n_f),
        "G": G,
        "G_var": np.full(G.shape, 0.01),
    }


def model_arrays(rng: np.random.Generator) -> dict:
    return {
        "A": -np.eye(4) + 0.1 * rng.standard_normal((4, 4)),
        "B": rng.standard_normal((4, 2)),
        "C": rng.standard_normal((3, 4)),
        "D": np.zeros((3, 2)),
        "dt": np.array(0.0),
    }


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


def refuse(path, capsys, *needles, argv=None) -> str:
    """Run the CLI on ``path``; assert exit 2 and one error line containing ``needles``."""
    status = main(argv or ["info", str(path)])
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith("error: ")
    assert str(path) in line
    for needle in needles:
        assert needle in line, (needle, line)
    return line


def write(tmp_path: Path, name: str, arrays: dict) -> Path:
    p = tmp_path / name
    np.savez(p, **arrays)
    return p


# ------------------------------------------------------------ bad contents
def _drop(d, k):
    d = dict(d)
    del d[k]
    return d


# (case id, builder of the arrays, base, strings the error line must hold)
TIME_CASES = [
    ("missing-y", lambda a: _drop(a, "y"), ["missing key 'y'", "keys present"]),
    ("missing-fs", lambda a: _drop(a, "fs"), ["missing key 'fs'"]),
    ("missing-kind", lambda a: _drop(a, "kind"), ["expected a measurement", "got keys"]),
    (
        "u-1d",
        lambda a: {**a, "u": a["u"][:, 0]},
        ["key 'u'", "expected shape (N, n_channels)", "(64,)"],
    ),
    ("y-3d", lambda a: {**a, "y": a["y"][:, :, None]}, ["key 'y'", "expected shape", "(64, 3, 1)"]),
    ("y-short", lambda a: {**a, "y": a["y"][:-1]}, ["key 'y'", "expected 64 samples", "got 63"]),
    (
        "r-short",
        lambda a: {**a, "r": a["r"][:-1]},
        ["key 'r'", "expected shape (64, 2)", "(63, 2)"],
    ),
    (
        "r-channels",
        lambda a: {**a, "r": a["r"][:, :1]},
        ["key 'r'", "expected shape (64, 2)", "(64, 1)"],
    ),
    (
        "y-nan",
        lambda a: {**a, "y": np.where(np.arange(N)[:, None] == 5, np.nan, a["y"])},
        ["key 'y'", "expected finite", "nan"],
    ),
    (
        "u-inf",
        lambda a: {**a, "u": np.where(np.arange(N)[:, None] == 7, np.inf, a["u"])},
        ["key 'u'", "expected finite", "inf"],
    ),
    ("u-complex", lambda a: {**a, "u": a["u"] + 1j}, ["key 'u'", "expected real", "complex"]),
    ("u-strings", lambda a: {**a, "u": a["u"].astype(str)}, ["key 'u'", "expected a real numeric"]),
    (
        "fs-zero",
        lambda a: {**a, "fs": np.array(0.0)},
        ["key 'fs'", "expected a finite value > 0", "got 0"],
    ),
    ("fs-negative", lambda a: {**a, "fs": np.array(-5.0)}, ["key 'fs'", "> 0", "got -5"]),
    ("fs-nan", lambda a: {**a, "fs": np.array(np.nan)}, ["key 'fs'", "> 0", "got nan"]),
    (
        "fs-vector",
        lambda a: {**a, "fs": np.array([1000.0, 2000.0])},
        ["key 'fs'", "expected a scalar", "(2,)"],
    ),
    ("fs-string", lambda a: {**a, "fs": np.array("1kHz")}, ["key 'fs'", "expected a real scalar"]),
    (
        "empty",
        lambda a: {**a, "u": a["u"][:0], "y": a["y"][:0], "r": a["r"][:0]},
        ["key 'u'", "at least 2 samples", "got 0"],
    ),
    (
        "one-sample",
        lambda a: {**a, "u": a["u"][:1], "y": a["y"][:1], "r": a["r"][:1]},
        ["key 'u'", "at least 2 samples", "got 1"],
    ),
    (
        "no-channels",
        lambda a: {**a, "u": a["u"][:, :0], "r": a["r"][:, :0]},
        ["key 'u'", "at least one channel"],
    ),
    (
        "loop-bad",
        lambda a: {**a, "loop": np.array("half")},
        ["key 'loop'", "'open' or 'closed'", "'half'"],
    ),
    (
        "kind-bad",
        lambda a: {**a, "kind": np.array("spectrum")},
        ["key 'kind'", "'time' or 'frf'", "'spectrum'"],
    ),
    (
        "period-not-divisor",
        lambda a: {**a, "period": np.array(10)},
        ["key 'period'", "divisor of N=64", "10"],
    ),
    (
        "period-fraction",
        lambda a: {**a, "period": np.array(2.5)},
        ["key 'period'", "expected an integer"],
    ),
    (
        "period-nan",
        lambda a: {**a, "period": np.array(np.nan)},
        ["key 'period'", "expected an integer"],
    ),
    (
        "names-count",
        lambda a: {**a, "input_names": np.array(["a", "b", "c"])},
        ["key 'input_names'", "expected 2 names", "got 3"],
    ),
]


@pytest.mark.parametrize(
    "build,needles", [c[1:] for c in TIME_CASES], ids=[c[0] for c in TIME_CASES]
)
def test_bad_time_file_is_refused(tmp_path, capsys, rng, build, needles):
    p = write(tmp_path, "bad_time.npz", build(time_arrays(rng)))
    refuse(p, capsys, *needles)


FRF_CASES = [
    ("missing-G", lambda a: _drop(a, "G"), ["missing key 'G'"]),
    ("missing-freq", lambda a: _drop(a, "freq"), ["missing key 'freq'"]),
    (
        "freq-2d",
        lambda a: {**a, "freq": a["freq"][:, None]},
        ["key 'freq'", "expected shape (n_f,)", "(20, 1)"],
    ),
    (
        "freq-decreasing",
        lambda a: {**a, "freq": a["freq"][::-1].copy()},
        ["key 'freq'", "strictly increasing", "followed by"],
    ),
    (
        "freq-repeated",
        lambda a: {**a, "freq": np.r_[a["freq"][:10], a["freq"][9:19]]},
        ["key 'freq'", "strictly increasing"],
    ),
    (
        "freq-zero",
        lambda a: {**a, "freq": np.linspace(0.0, 100.0, 20)},
        ["key 'freq'", "> 0 Hz", "got minimum 0"],
    ),
    (
        "freq-negative",
        lambda a: {**a, "freq": np.linspace(-1.0, 100.0, 20)},
        ["key 'freq'", "> 0 Hz"],
    ),
    ("freq-complex", lambda a: {**a, "freq": a["freq"] + 0j}, ["key 'freq'", "expected real"]),
    (
        "freq-nan",
        lambda a: {**a, "freq": np.r_[a["freq"][:-1], np.nan]},
        ["key 'freq'", "expected finite"],
    ),
    (
        "G-lines",
        lambda a: {**a, "G": a["G"][:-1]},
        ["key 'G'", "expected shape (20, n_y, n_u)", "(19, 3, 2)"],
    ),
    (
        "G-2d",
        lambda a: {**a, "G": a["G"][:, :, 0]},
        ["key 'G'", "expected shape (20, n_y, n_u)", "(20, 3)"],
    ),
    (
        "G-inf",
        lambda a: {**a, "G": np.where(np.arange(20)[:, None, None] == 3, np.inf, a["G"])},
        ["key 'G'", "expected finite"],
    ),
    (
        "G-strings",
        lambda a: {**a, "G": a["G"].astype(str)},
        ["key 'G'", "expected a complex array"],
    ),
    (
        "G_var-shape",
        lambda a: {**a, "G_var": a["G_var"][:, :, :1]},
        ["key 'G_var'", "(20, 3, 2)", "(20, 3, 1)"],
    ),
    ("G_var-complex", lambda a: {**a, "G_var": a["G_var"] + 0j}, ["key 'G_var'", "expected real"]),
    (
        "G_var-negative",
        lambda a: {**a, "G_var": -a["G_var"]},
        ["key 'G_var'", "expected variances >= 0"],
    ),
    ("fs-negative", lambda a: {**a, "fs": np.array(-1.0)}, ["key 'fs'", "> 0", "got -1"]),
]


@pytest.mark.parametrize("build,needles", [c[1:] for c in FRF_CASES], ids=[c[0] for c in FRF_CASES])
def test_bad_frf_file_is_refused(tmp_path, capsys, rng, build, needles):
    p = write(tmp_path, "bad_frf.npz", build(frf_arrays(rng)))
    refuse(p, capsys, *needles)


MODEL_CASES = [
    ("missing-D", lambda a: _drop(a, "D"), ["missing key 'D'"]),
    ("missing-dt", lambda a: _drop(a, "dt"), ["missing key 'dt'"]),
    (
        "dt-negative",
        lambda a: {**a, "dt": np.array(-0.001)},
        ["key 'dt'", "expected 0.0", "got -0.001"],
    ),
    (
        "dt-vector",
        lambda a: {**a, "dt": np.array([0.0, 0.1])},
        ["key 'dt'", "expected a real scalar", "(2,)"],
    ),
    ("dt-nan", lambda a: {**a, "dt": np.array(np.nan)}, ["key 'dt'", "got nan"]),
    (
        "A-nonsquare",
        lambda a: {**a, "A": a["A"][:, :3]},
        ["key 'A'", "expected a square matrix", "(4, 3)"],
    ),
    ("A-1d", lambda a: {**a, "A": a["A"][0]}, ["key 'A'", "expected a 2-D matrix", "(4,)"]),
    ("A-complex", lambda a: {**a, "A": a["A"] + 1j}, ["key 'A'", "expected real"]),
    ("A-nan", lambda a: {**a, "A": np.full((4, 4), np.nan)}, ["key 'A'", "expected finite"]),
    ("B-rows", lambda a: {**a, "B": a["B"][:3]}, ["key 'B'", "expected 4 rows", "(3, 2)"]),
    ("C-cols", lambda a: {**a, "C": a["C"][:, :3]}, ["key 'C'", "expected 4 columns", "(3, 3)"]),
    (
        "D-shape",
        lambda a: {**a, "D": np.zeros((2, 3))},
        ["key 'D'", "expected shape (3, 2)", "(2, 3)"],
    ),
    (
        "names-count",
        lambda a: {**a, "output_names": np.array(["a"])},
        ["key 'output_names'", "expected 3 names", "got 1"],
    ),
    (
        "delay-vector",
        lambda a: {**a, "delay_s": np.array([1e-4, 2e-4])},
        ["key 'delay_s'", "expected a scalar input delay >= 0 s", "(2,)"],
    ),
    (
        "delay-negative",
        lambda a: {**a, "delay_s": np.array(-1e-4)},
        ["key 'delay_s'", "expected a scalar input delay >= 0 s", "-0.0001"],
    ),
]


@pytest.mark.parametrize(
    "build,needles", [c[1:] for c in MODEL_CASES], ids=[c[0] for c in MODEL_CASES]
)
def test_bad_model_file_is_refused(tmp_path, capsys, rng, build, needles):
    p = write(tmp_path, "bad_model.npz", build(model_arrays(rng)))
    refuse(p, capsys, *needles)


def test_model_not_matching_data_is_refused_by_compare(tmp_path, capsys, rng):
    data = write(tmp_path, "data.npz", frf_arrays(rng))  # 3 outputs x 2 inputs
    arrays = model_arrays(rng)
    arrays["B"] = np.ones((4, 1))  # 1 input
    arrays["D"] = np.zeros((3, 1))
    model = write(tmp_path, "model.npz", arrays)
    line = refuse(
        model,
        capsys,
        "expected a model with 2 inputs and 3 outputs",
        "got 1 inputs and 3 outputs",
        argv=["compare", "--model", str(model), "--data", str(data)],
    )
    assert str(data) in line


# ------------------------------------------------------------ bad containers
def test_missing_file_is_refused(tmp_path, capsys):
    refuse(tmp_path / "nothing_here.npz", capsys, "no such file")


def test_text_file_named_npz_is_refused(tmp_path, capsys):
    p = tmp_path / "notes.npz"
    p.write_text("kind = time\nfs = 1000\n")
    refuse(p, capsys, "expected an .npz archive")


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.99], ids=["half", "90pct", "99pct"])
def test_truncated_file_is_refused(tmp_path, capsys, rng, keep):
    full = write(tmp_path, "full.npz", time_arrays(rng)).read_bytes()
    p = tmp_path / "cut.npz"
    p.write_bytes(full[: int(keep * len(full))])
    refuse(p, capsys)


def test_corrupt_member_is_refused(tmp_path, capsys, rng):
    """Central directory intact, data bytes damaged: the zip CRC check catches it."""
    raw = bytearray(write(tmp_path, "ok.npz", time_arrays(rng)).read_bytes())
    i = raw.find(b"\x93NUMPY", raw.find(b"y.npy")) + 200  # inside the data of 'y'
    raw[i : i + 16] = b"\x00" * 16
    p = tmp_path / "corrupt.npz"
    p.write_bytes(bytes(raw))
    refuse(p, capsys, "corrupt")


def _npy_with_header(shape, dtype="<f8", payload=b"\x00" * 64) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": dtype, "fortran_order": False, "shape": shape}
    )
    return buf.getvalue() + payload


def test_absurd_header_is_refused(tmp_path, capsys, rng):
    """A header claiming 8 TB of data in a 64-byte member is not obeyed (no allocation)."""
    p = write(tmp_path, "absurd.npz", time_arrays(rng))
    with zipfile.ZipFile(p, "a") as zf:
        zf.writestr("y2.npy", _npy_with_header((10**6, 10**6)))
    refuse(p, capsys, "key 'y2'", "header claims", "truncated or corrupt")


def test_object_array_is_refused(tmp_path, capsys, rng):
    arrays = time_arrays(rng)
    arrays["u"] = np.array([{"evil": True}] * N, dtype=object)[:, None]
    p = tmp_path / "pickled.npz"
    np.savez(p, **arrays)  # numpy pickles object arrays on save
    refuse(p, capsys, "key 'u'", "object (pickled) array", "never loaded")


def test_refusal_through_subprocess_has_no_traceback(tmp_path, rng):
    arrays = time_arrays(rng)
    arrays["y"] = arrays["y"][:-3]
    p = write(tmp_path, "short.npz", arrays)
    proc = subprocess.run(
        [sys.executable, "-m", "workbench", "info", str(p)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert str(p) in lines[0] and "key 'y'" in lines[0]


# --------------------------------------------------------------- good files
def test_round_trip_time_and_model(tmp_path, rng):
    data = formats.measurement_from_arrays(time_arrays(rng))
    formats.save_measurement(tmp_path / "m.npz", data)
    back = formats.load_measurement(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.u, data.u)
    np.testing.assert_array_equal(back.r, data.r)
    assert back.loop == "closed" and back.fs == 1000.0
    assert not back.u.flags.writeable
    sys_ = formats.model_from_arrays(model_arrays(rng))
    formats.save_model(tmp_path / "s.npz", sys_, delay_s=np.array(1e-4))
    back_sys = formats.load_model(tmp_path / "s.npz")
    np.testing.assert_array_equal(back_sys.A, sys_.A)
    assert float(np.load(tmp_path / "s.npz")["delay_s"]) == 1e-4


CASES = ["example_stage_missing_frf", "example_stage_delay_time", "example_beam_none_frf"]


@pytest.mark.parametrize("case", CASES)
def test_shared_example_nominal_error_is_reproduced(case):
    """The examples come from code independent of the workbench: reading them and
    following the conventions (ZOH-compensated FRFs, time records from rest)
    must give answer.json's nominal_error to its 6 digits."""
    require_shared()
    folder = EXAMPLES / case
    answer = json.loads((folder / "answer.json").read_text())
    data = formats.load_measurement(folder / "measurement.npz")
    model = formats.load_model(folder / "nominal_model.npz")
    formats.check_model_matches(model, data)
    assert data.kind == answer["data_kind"]
    if data.kind == "frf":
        err = lti.relative_error_frf(data.G, lti.frf(model, data.freq))
    else:
        err = lti.relative_error_time(data.y, sim.simulate_zoh(model, data.u, data.fs))
    assert err == pytest.approx(answer["nominal_error"], rel=1e-4, abs=2e-6)


@pytest.mark.parametrize("case", CASES)
def test_shared_example_true_model_reaches_noise_floor(case):
    require_shared()
    folder = EXAMPLES / case
    answer = json.loads((folder / "answer.json").read_text())
    data = formats.load_measurement(folder / "measurement.npz")
    true = formats.load_model(folder / "answer_true_model.npz")
    delay_s = float(np.load(folder / "answer_true_model.npz")["delay_s"])
    if data.kind == "frf":
        err = lti.relative_error_frf(data.G, lti.frf(true, data.freq, delay_s=delay_s))
    else:
        err = lti.relative_error_time(
            data.y, sim.simulate_zoh(true, data.u, data.fs, delay_s=delay_s)
        )
    assert err == pytest.approx(answer["noise_floor_error"], rel=1e-3, abs=2e-6)


@pytest.mark.parametrize("case", CASES)
def test_info_reads_shared_examples(case, capsys):
    require_shared()
    for name in ["measurement.npz", "nominal_model.npz", "answer_true_model.npz"]:
        assert main(["info", str(EXAMPLES / case / name)]) == 0
        out = capsys.readouterr().out
        assert "file:" in out
