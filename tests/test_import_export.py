"""``workbench import`` / ``workbench export``: UFF58, MATLAB .mat (v5, v7.3) and CSV.

Every input file is made here, in tmp_path: spec files by ``save_measurement``,
universal files by pyuff (our exporter, or pyuff's own writer as a modal-test
system's file), .mat files by scipy and, for v7.3, by h5py in MATLAB's layout
(column-major dims, MATLAB_class attributes, cells as references). Oracles:
round trips are bit-exact; imports of foreign files are compared with the
arrays they were written from, converted by hand (units, accelerance).
Refusals exit 2 with one line naming the file and the field, and leave no
output file.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from conftest import one_line

from workbench.cli.main import main
from workbench.core.errors import InputError
from workbench.core.model import LTIModel
from workbench.io.formats import (
    FrfData,
    TimeData,
    load_measurement,
    measurement_arrays,
    save_measurement,
    save_model,
)
from workbench.io.importers import import_file, read_data_file

FS_ODD = 1.0 / 3e-4  # 3333.3333333333335 Hz: no short decimal, so only the exact tag restores it


def frf_example(G_var: bool = True) -> FrfData:
    rng = np.random.default_rng(1)
    freq = np.cumsum(rng.uniform(0.3, 2.0, 40)) + 1.0 / 3.0  # uneven lines, no short decimals
    G = rng.standard_normal((40, 3, 2)) + 1j * rng.standard_normal((40, 3, 2))
    return FrfData(
        freq=freq,
        G=G * 1e-6,
        G_var=rng.uniform(0, 1e-14, G.shape) if G_var else None,
        fs=FS_ODD,
        input_names=("F1", "F2"),
        output_names=("x", "y", "rz"),
    )


def time_example() -> TimeData:
    rng = np.random.default_rng(2)
    r = rng.standard_normal((200, 2))
    return TimeData(
        fs=FS_ODD,
        u=r + 0.1 * rng.standard_normal((200, 2)),
        y=1e-6 * rng.standard_normal((200, 3)),
        r=r,
        loop="closed",
        period=50,
        input_names=("F1", "F2"),
        output_names=("x", "y", "rz"),
    )


def assert_same(a, b) -> None:
    """Every spec array of two measurements equal, bit for bit."""
    ka, kb = measurement_arrays(a), measurement_arrays(b)
    assert sorted(ka) == sorted(kb)
    for key in ka:
        assert np.array_equal(ka[key], kb[key]), key
        assert np.asarray(ka[key]).dtype.kind == np.asarray(kb[key]).dtype.kind, key


def num(x) -> str:
    """A number as CSV text that reads back to the same double."""
    return repr(float(x))


def refused(argv, capsys, *words) -> str:
    """Run the CLI, expect exit 2 with one line holding every word; return the line."""
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2
    line = one_line(capsys.readouterr().err)
    for word in words:
        assert word in line, (word, line)
    return line


def leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# ------------------------------------------------------------------ round trips
def test_frf_round_trip_through_uff_is_exact(tmp_path, capsys):
    data = frf_example()
    src, uff, back = tmp_path / "frf.npz", tmp_path / "frf.uff", tmp_path / "back.npz"
    save_measurement(src, data)
    assert main(["export", str(src), "--out", str(uff)]) == 0
    out = capsys.readouterr().out
    assert "G_var not written" in out
    assert main(["import", str(uff), "--out", str(back)]) == 0
    out = capsys.readouterr().out
    assert "frf, 3 outputs x 2 inputs, 40 lines" in out and "6 FRF records" in out
    got = load_measurement(back)
    assert got.G_var is None
    assert_same(got, FrfData(data.freq, data.G, None, data.fs, data.input_names, data.output_names))
    # several records per file: one per output/input pair, and the 58b headers count their bytes
    raw = uff.read_bytes()
    headers = [line for line in raw.split(b"\n") if line.startswith(b"    58b")]
    assert len(headers) == 6
    assert all(int(h[31:43]) == 3 * 40 * 8 for h in headers)


def test_time_round_trip_through_uff_is_exact(tmp_path, capsys):
    data = time_example()
    src, uff, back = tmp_path / "t.npz", tmp_path / "t.unv", tmp_path / "back.npz"
    save_measurement(src, data)
    assert main(["export", str(src), "--out", str(uff)]) == 0
    assert main(["import", str(uff), "--out", str(back)]) == 0
    assert "closed loop, with r" in capsys.readouterr().out
    assert_same(load_measurement(back), data)


@pytest.mark.parametrize("example", [frf_example, time_example])
def test_round_trip_through_mat_is_exact(tmp_path, example):
    data = example()
    src, mat, back = tmp_path / "d.npz", tmp_path / "d.mat", tmp_path / "back.npz"
    save_measurement(src, data)
    assert main(["export", str(src), "--out", str(mat)]) == 0
    raw = scipy.io.loadmat(mat)
    assert str(raw["kind"][0]) == data.kind  # what MATLAB users see: the spec keys
    assert main(["import", str(mat), "--out", str(back)]) == 0
    assert_same(load_measurement(back), data)


def test_model_exports_to_mat_not_to_uff(tmp_path, capsys):
    A = np.array([[0.0, 1.0], [-4e4, -8.0]])
    model = LTIModel(
        A,
        [[0.0], [1.0]],
        [[1.0, 0.0]],
        [[0.0]],
        dt=0.0,
        delay_s=2e-4,
        input_names=("F",),
        output_names=("x",),
    )
    src, mat = tmp_path / "model.npz", tmp_path / "model.mat"
    save_model(src, model)
    assert main(["export", str(src), "--out", str(mat)]) == 0
    raw = scipy.io.loadmat(mat)
    assert np.array_equal(raw["A"], A) and raw["dt"].item() == 0.0
    assert raw["delay_s"].item() == 2e-4 and str(raw["input_names"][0, 0][0]) == "F"
    refused(["export", src, "--out", tmp_path / "model.uff"], capsys, "model.uff", ".mat")
    assert not (tmp_path / "model.uff").exists()


# ------------------------------------------------------------------ MATLAB files
def write_v73(path, variables: dict) -> None:
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 with a 512-byte header block, dims
    reversed (column-major), MATLAB_class attributes, complex as (real, imag) compounds,
    char as uint16, cells as references into #refs#, structs as groups."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w", userblock_size=512) as f:
        refs = f.create_group("#refs#")

        def put(group, name, value):
            if isinstance(value, dict):
                g = group.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("struct")
                for k, v in value.items():
                    put(g, k, v)
                return
            if isinstance(value, str):
                d = group.create_dataset(name, data=np.array([[ord(c)] for c in value], np.uint16))
                d.attrs["MATLAB_class"] = np.bytes_("char")
                return
            if isinstance(value, list):  # a 1 x n cell
                items = []
                for k, item in enumerate(value):
                    put(refs, f"{name}{k}", item)
                    items.append(refs[f"{name}{k}"].ref)
                d = group.create_dataset(name, data=np.array(items, dtype=h5py.ref_dtype)[:, None])
                d.attrs["MATLAB_class"] = np.bytes_("cell")
                return
            a = np.asarray(value, dtype=complex if np.iscomplexobj(value) else float)
            a = a.reshape(1, 1) if a.ndim == 0 else a
            if np.iscomplexobj(a):
                c = np.empty(a.T.shape, dtype=[("real", "<f8"), ("imag", "<f8")])
                c["real"], c["imag"] = a.real.T, a.imag.T
                d = group.create_dataset(name, data=c)
            else:
                d = group.create_dataset(name, data=a.T)
            d.attrs["MATLAB_class"] = np.bytes_("double")

        for name, value in variables.items():
            put(f, name, value)
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5"
    with open(path, "r+b") as fh:
        fh.write(text.ljust(116) + bytes(8) + b"\x00\x02IM")


def test_mat_v73_time_record_in_a_struct(tmp_path):
    data = time_example()
    mat = tmp_path / "v73.mat"
    write_v73(
        mat,
        {
            "meas": {
                "u": data.u,
                "y": data.y,
                "r": data.r,
                "fs": data.fs,
                "loop": "closed",
                "period": 50.0,
                "input_names": list(data.input_names),
                "output_names": list(data.output_names),
            }
        },
    )
    got = read_data_file(mat)
    assert "read the fields of struct 'meas'" in got.notes
    assert got.description == "MATLAB v7.3 .mat"
    assert_same(got.data, data)


def test_mat_v73_frf_one_input_dropped_singleton(tmp_path):
    data = frf_example(G_var=False)
    mat = tmp_path / "v73.mat"
    # MATLAB drops the trailing singleton dimension of an n_f x n_y x 1 array
    write_v73(mat, {"freq": data.freq, "G": data.G[:, :, 0], "output_names": ["x", "y", "rz"]})
    got = import_file(mat)
    assert np.array_equal(got.G, data.G[:, :, :1]) and np.array_equal(got.freq, data.freq)
    assert got.output_names == ("x", "y", "rz") and got.input_names == ("u0",)


def test_mat_structs_read_refused_when_ambiguous_picked_by_map(tmp_path, capsys):
    data = time_example()
    fields = {"u": data.u, "y": data.y, "fs": data.fs}
    one, two = tmp_path / "one.mat", tmp_path / "two.mat"
    scipy.io.savemat(one, {"meas": fields})
    scipy.io.savemat(two, {"a": fields, "b": {**fields, "y": 2 * data.y}})
    assert np.array_equal(import_file(one).y, data.y)
    refused(["import", two, "--out", tmp_path / "x.npz"], capsys, "two.mat", "2 (a, b)", "struct")
    got = import_file(two, {"struct": "b"})
    assert np.array_equal(got.y, 2 * data.y)


def test_mat_map_names_channels_and_units(tmp_path, capsys):
    rng = np.random.default_rng(3)
    Fx, Fy, disp = rng.standard_normal(300), rng.standard_normal(300), rng.standard_normal((300, 2))
    mat = tmp_path / "rig.mat"
    scipy.io.savemat(mat, {"Fx": Fx, "Fy": Fy, "rig": {"disp": disp, "Fs": 2048.0}})
    toml = tmp_path / "map.toml"
    toml.write_text(
        '[variables]\nu = ["Fx", "Fy"]\ny = "rig.disp"\nfs = "rig.Fs"\n'
        '[units]\nu = "N"\n"rig.disp" = "um"\n'
    )
    out = tmp_path / "rig.npz"
    assert main(["import", str(mat), "--out", str(out), "--map", str(toml)]) == 0
    got = load_measurement(out)
    assert got.fs == 2048.0 and got.input_names == ("Fx", "Fy")
    assert np.array_equal(got.u, np.column_stack([Fx, Fy])) and np.allclose(got.y, disp * 1e-6)
    # a column of a matrix, MATLAB style, and a unit the map does not give
    toml.write_text(
        '[variables]\nu = "Fx"\ny = "rig.disp(:,2)"\nfs = "rig.Fs"\n[units]\nFx = "N"\n'
    )
    refused(
        ["import", mat, "--out", out, "--map", toml], capsys, "rig.mat", "rig.disp(:,2)", "unit"
    )
    # a map naming a variable that is not in the file
    toml.write_text('[variables]\nu = "force"\ny = "rig.disp"\n')
    refused(["import", mat, "--out", out, "--map", toml], capsys, "map.toml", "'force'", "not in")


def test_mat_unequal_channels_and_transposed_refused(tmp_path, capsys):
    mat = tmp_path / "bad.mat"
    scipy.io.savemat(mat, {"a": np.ones(100), "b": np.ones(90), "y": np.ones((100, 1)), "fs": 1e3})
    toml = tmp_path / "map.toml"
    toml.write_text('[variables]\nu = ["a", "b"]\n[units]\nu = "N"\n')
    refused(
        ["import", mat, "--out", tmp_path / "o.npz", "--map", toml],
        capsys,
        "bad.mat",
        "unequal length",
        "'a' has 100",
        "'b' has 90",
    )
    scipy.io.savemat(mat, {"u": np.ones((2, 500)), "y": np.ones((500, 1)), "fs": 1e3})
    refused(["import", mat, "--out", tmp_path / "o.npz"], capsys, "'u'", "2x500", "transpose")


# ------------------------------------------------------------------- CSV files
def test_csv_time_record_fs_from_printed_time(tmp_path):
    rng = np.random.default_rng(4)
    u, y = rng.standard_normal((90, 1)), rng.standard_normal((90, 2))
    rows = ["# logged by the rig", "t [s],u_F1 [N],y_x [um],y_y [mm]"]
    rows += [f"{k / 3000:.6f},{num(u[k, 0])},{num(y[k, 0])},{num(y[k, 1])}" for k in range(90)]
    csv = tmp_path / "rec.csv"
    csv.write_text("\n".join(rows) + "\n")
    got = import_file(csv)
    assert got.fs == 3000.0  # not 1 / 0.000333 s: the printed instants fit 3000 Hz best
    assert got.input_names == ("F1",) and got.output_names == ("x", "y")
    assert np.array_equal(got.u, u)
    assert np.allclose(got.y, y * [1e-6, 1e-3], rtol=1e-15, atol=0)


def test_csv_frf_re_im_and_mag_phase(tmp_path):
    data = frf_example()
    G, freq = data.G[:, :2, :1], data.freq
    head = "freq [Hz],G_x_F1_re [m/N],G_x_F1_im [m/N],G_y_F1_mag [um/N],G_y_F1_phase [deg]"
    rows = [head + ",Gvar_x_F1 [(m/N)^2],Gvar_y_F1 [(m/N)^2]"]
    rows.append("0.0,1.0,0.0,1.0,0.0,0.0,0.0")  # a DC line, dropped
    for k, f in enumerate(freq):
        a, b = G[k, 0, 0], G[k, 1, 0]
        rows.append(
            f"{num(f)},{num(a.real)},{num(a.imag)},{num(abs(b) * 1e6)},"
            f"{num(np.degrees(np.angle(b)))},{num(data.G_var[k, 0, 0])},{num(data.G_var[k, 1, 0])}"
        )
    csv = tmp_path / "frf.csv"
    csv.write_text("\n".join(rows) + "\n")
    got = read_data_file(csv)
    assert "dropped the 0 Hz line" in got.notes[0]
    assert got.data.output_names == ("x", "y") and got.data.input_names == ("F1",)
    assert np.array_equal(got.data.freq, freq) and np.array_equal(got.data.G[:, 0], G[:, 0])
    assert np.allclose(got.data.G[:, 1], G[:, 1], rtol=1e-13, atol=0)
    assert np.array_equal(got.data.G_var[:, :, 0], data.G_var[:, :2, 0])


def test_csv_semicolon_with_decimal_comma_is_read_right(tmp_path):
    dot, comma = tmp_path / "dot.csv", tmp_path / "comma.csv"
    rows = [(k / 1000, np.sin(k / 7), 1e-3 * np.cos(k / 5)) for k in range(50)]
    dot.write_text("t [s],u_F [N],y_x [m]\n" + "".join(f"{a},{b},{c}\n" for a, b, c in rows))
    comma.write_text(
        "t [s];u_F [N];y_x [m]\n" + "".join(f"{a};{b};{c}\n".replace(".", ",") for a, b, c in rows)
    )
    assert_same(import_file(comma), import_file(dot))


def test_csv_decimal_comma_in_comma_separated_file_refused(tmp_path, capsys):
    csv = tmp_path / "de.csv"
    csv.write_text("t [s],u_F [N],y_x [m]\n0,0,0,5,0,25\n0,001,1,5,2,25\n")
    out = tmp_path / "o.npz"
    refused(["import", csv, "--out", out], capsys, "de.csv", "line 2", "decimal comma")
    assert not out.exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize(
    "text, words",
    [
        ("t [s],u_F [N],y_x\n0,1,2\n0.001,1,2\n", ["column 'y_x'", "unit"]),
        ("t [s],u_F [N],y_x [m]\n0,1,2\n0.001,1,2\n0.002,1\n", ["unequal length", "'y_x' has 2"]),
        (
            "t [s],u_F [N],y_x [m]\n" + "".join(f"{t},1,2\n" for t in (0, 0.001, 0.002, 0.004)),
            ["column 't'", "uniform time axis"],
        ),
        (
            # a 0.2 ms slip at one sample: within the 25 % step check, but off the grid by
            # more than that number's printed digit (the first "0" must not set the bound)
            "t [s],u_F [N],y_x [m]\n"
            + "".join(f"{t},1,2\n" for t in (0, 0.001, 0.002, 0.0032, 0.004, 0.005)),
            ["column 't'", "uniform time axis"],
        ),
        (
            "f [Hz],G_x_F_re [m/N],G_x_F_im [m/N]\n1,1,0\n2,1,0\n2,1,0\n",
            ["column 'f'", "2 Hz twice"],
        ),
        (
            "t [s];u_F [N];y_x [m]\n0;1,5;2.5\n0,001;1,5;2,5\n",
            ["column 'y_x'", "2.5", "decimal comma"],
        ),
        ("t [s],force [N],y_x [m]\n0,1,2\n0.001,1,2\n", ["column 'force'", "u_<name>"]),
        ("f [Hz],G_x_F_re [m/N]\n1,1\n2,1\n", ["G_x_F_re and G_x_F_im"]),
        ("t [ms],u_F [N],y_x [furlong]\n0,1,2\n1,1,2\n", ["column 'y_x'", "'furlong'"]),
    ],
    ids=[
        "units",
        "unequal",
        "nonuniform",
        "jitter",
        "duplicate-lines",
        "mixed-marks",
        "no-role",
        "half-pair",
        "bad-unit",
    ],
)
def test_csv_refusals(tmp_path, capsys, text, words):
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    refused(["import", csv, "--out", tmp_path / "o.npz"], capsys, "bad.csv", *words)
    assert not (tmp_path / "o.npz").exists()


def test_csv_map_names_columns_and_units(tmp_path, capsys):
    csv = tmp_path / "log.csv"
    csv.write_text(
        "Time,Force,Disp,Temp\n" + "".join(f"{k},{k % 3},{k % 5},20\n" for k in range(20))
    )
    toml = tmp_path / "map.toml"
    toml.write_text(
        '[variables]\nt = "Time"\nu = ["Force"]\ny = ["Disp"]\n'
        '[units]\nTime = "ms"\nForce = "N"\nDisp = "nm"\n'
    )
    got = read_data_file(csv, toml)
    assert got.data.fs == 1000.0 and np.allclose(got.data.y[:, 0], (np.arange(20) % 5) * 1e-9)
    assert "left out: Temp" in got.notes[0]
    toml.write_text('[variables]\nt = "Time"\nu = ["Force"]\ny = ["Displacement"]\n')
    refused(
        ["import", csv, "--out", tmp_path / "o.npz", "--map", toml],
        capsys,
        "map.toml",
        "'Displacement'",
        "not in",
    )


# ------------------------------------------------------------ headerless tables
CD_MAP = '[variables]\nu = [1, 2]\ny = [3, 4]\n[units]\nu = "V"\ny = "V"\n'


def test_daisy_table_read_as_numpy_reads_it(tmp_path, capsys):
    """DaISy's CD player arm (../shared/realdata): four columns, no header, no sample time;
    the map names the columns by number and fs, and the record is the file's numbers."""
    from conftest import SHARED_REALDATA, require_shared

    dat = require_shared(SHARED_REALDATA / "CD_player_arm.dat")
    toml = tmp_path / "cd.toml"
    toml.write_text("fs = 1.0\n" + CD_MAP)
    out = tmp_path / "cd.npz"
    assert main(["import", str(dat), "--out", str(out), "--map", str(toml)]) == 0
    assert "2048 samples at 1 Hz" in capsys.readouterr().out
    data = load_measurement(out)
    d = np.loadtxt(dat)
    np.testing.assert_array_equal(data.u, d[:, :2])
    np.testing.assert_array_equal(data.y, d[:, 2:])
    assert data.input_names == ("u1", "u2") and data.output_names == ("y1", "y2")
    assert data.fs == 1.0 and data.loop == "open"


def test_table_with_comments_a_time_column_units_and_a_column_left_out(tmp_path):
    dat = tmp_path / "log.txt"
    rows = "".join(f"{0.5 * k:g}\t{k % 3}\t{k % 5}  20.5\n" for k in range(40))
    dat.write_text("% logger export\n# t[ms] F[mN] x[um] temp\n" + rows)
    toml = tmp_path / "map.toml"
    toml.write_text(
        'output_names = ["x"]\n[variables]\nt = 1\nu = [2]\ny = [3]\n'
        '[units]\nt = "ms"\nu = "mN"\ny = "um"\n'
    )
    got = read_data_file(dat, toml)
    assert got.data.fs == pytest.approx(2000.0)
    np.testing.assert_allclose(got.data.u[:, 0], (np.arange(40) % 3) * 1e-3)
    np.testing.assert_allclose(got.data.y[:, 0], (np.arange(40) % 5) * 1e-6)
    assert got.data.input_names == ("u1",) and got.data.output_names == ("x",)
    assert "left out: 4" in got.notes[0]


@pytest.mark.parametrize(
    "text, map_text, words",
    [
        ("1 2\n3 4\n", None, ["says nothing about its columns", "[variables] u and y"]),
        ("1 2\n3 4\n", CD_MAP.replace("3, 4", "2").replace("1, 2", "1"), ["fs in the map"]),
        ("u y\n1 2\n", "fs = 1.0\n" + CD_MAP, ["line 1", "'u'", "header row", ".csv"]),
        ("1 2 3 4\n1 2 3\n", "fs = 1.0\n" + CD_MAP, ["line 2", "expected 4 columns", "got 3"]),
        ("1 2 3\n4 5 6\n", "fs = 1.0\n" + CD_MAP, ["variables.y", "1..3", "'4'"]),
        ("1 2\n3 4\n", "fs = 1.0\n[variables]\nu = [0]\ny = [2]\n", ["number >= 1", "0"]),
        ("1 2\n3 4\n", 'kind = "frf"\nfs = 1.0\n' + CD_MAP, ["kind", "'frf'"]),
        (
            "1 2 3 4\n5 6 7 8\n",
            "fs = 1.0\n[variables]\nu = [1, 2]\ny = [3, 4]\n",
            ["column 1", "names no units", "[units] u"],
        ),
    ],
    ids=["no-map", "no-fs", "header", "ragged", "no-such-column", "column-0", "frf", "no-units"],
)
def test_table_refusals(tmp_path, capsys, text, map_text, words):
    dat = tmp_path / "bad.dat"
    dat.write_text(text)
    argv = ["import", dat, "--out", tmp_path / "o.npz"]
    if map_text is not None:
        (tmp_path / "m.toml").write_text(map_text)
        argv += ["--map", tmp_path / "m.toml"]
    refused(argv, capsys, *words)
    assert not (tmp_path / "o.npz").exists()


# -------------------------------------------------------------- universal files
def uff_record(pyuff, **fields):
    """A dataset 58 as a modal-test system writes it: ASCII, even abscissa, node + direction."""
    base = dict(binary=0, rsp_dir=3, ref_dir=3, ref_node=1, orddenom_spec_data_type=0)
    return pyuff.prepare_58(**{**base, **fields})


def write_uff(path, sets) -> None:
    pyuff = pytest.importorskip("pyuff")
    pyuff.UFF(str(path)).write_sets(sets, mode="add")


MM_UNITS = {
    "type": 164,
    "units_code": 5,
    "units_description": "mm (milli newton)",
    "temp_mode": 2,
    "length": 1000.0,
    "force": 1000.0,
    "temp": 1.0,
    "temp_offset": 273.15,
}


def test_uff_accelerance_in_mm_from_a_test_system(tmp_path, capsys):
    pyuff = pytest.importorskip("pyuff")
    f = np.arange(0, 101) * 2.5  # even lines from a 0 Hz (DC) line
    rng = np.random.default_rng(5)
    acc = {n: rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size) for n in (101, 102)}
    sets = [MM_UNITS] + [
        uff_record(
            pyuff,
            func_type=4,
            rsp_node=n,
            data=acc[n],
            x=f,
            abscissa_spacing=1,
            abscissa_spec_data_type=18,
            ordinate_spec_data_type=12,
            orddenom_spec_data_type=13,
        )
        for n in (101, 102)
    ]
    path = tmp_path / "hammer.uff"
    write_uff(path, sets)
    out = tmp_path / "h.npz"
    assert main(["import", str(path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "acceleration per force converted" in text and "dropped the 0 Hz line" in text
    got = load_measurement(out)
    assert got.output_names == ("101+Z", "102+Z") and got.input_names == ("1+Z",)
    assert np.allclose(got.freq, f[1:], rtol=1e-5)
    w = 2 * np.pi * got.freq
    # (mm/s^2)/mN = (1e-3 m/s^2) / (1e-3 N): accelerance to receptance, / -(2 pi f)^2
    expected = np.column_stack([acc[101][1:], acc[102][1:]]) / -(w**2)[:, None]
    assert np.allclose(got.G[:, :, 0], expected, rtol=1e-10)
    # without the units dataset the units are missing; the map can give them
    write_uff(tmp_path / "nounits.uff", sets[1:])
    refused(
        ["import", tmp_path / "nounits.uff", "--out", out],
        capsys,
        "nounits.uff",
        "record 1 (101+Z/1+Z)",
        "'units'",
        "164",
    )
    toml = tmp_path / "map.toml"
    toml.write_text('[units]\nG = "mm/mN"\n')
    got = import_file(tmp_path / "nounits.uff", toml)
    assert np.allclose(got.G[:, :, 0], expected, rtol=1e-10)


def test_uff_time_records_fs_from_six_digit_increment(tmp_path):
    pyuff = pytest.importorskip("pyuff")
    t = np.arange(300) / 3000.0  # the header prints the increment 3.33333E-04
    rng = np.random.default_rng(6)
    force, disp = rng.standard_normal(300), rng.standard_normal(300)
    path = tmp_path / "run.uff"
    write_uff(
        path,
        [
            {**MM_UNITS, "length": 1.0, "force": 1.0},
            uff_record(
                pyuff,
                func_type=1,
                rsp_node=1,
                data=force,
                x=t,
                abscissa_spacing=1,
                ordinate_spec_data_type=13,
                rsp_ent_name="shaker",
            ),
            uff_record(
                pyuff,
                func_type=1,
                rsp_node=7,
                rsp_dir=-5,
                data=disp,
                x=t,
                abscissa_spacing=1,
                ordinate_spec_data_type=8,
            ),
        ],
    )
    got = import_file(path)
    assert got.fs == 3000.0 and got.loop == "open"
    assert got.input_names == ("shaker",) and got.output_names == ("7-RY",)
    assert np.allclose(got.u[:, 0], force, rtol=1e-11) and np.allclose(
        got.y[:, 0], disp, rtol=1e-11
    )


def test_uff_mixed_record_types_refused_unless_the_map_picks(tmp_path, capsys):
    pyuff = pytest.importorskip("pyuff")
    f = np.arange(1, 51) * 1.0
    frf = [
        uff_record(
            pyuff,
            func_type=4,
            rsp_node=n,
            data=np.ones(50) * (1 + 1j),
            x=f,
            abscissa_spacing=1,
            ordinate_spec_data_type=8,
            orddenom_spec_data_type=13,
        )
        for n in (2, 3)
    ]
    coh = uff_record(pyuff, func_type=6, rsp_node=2, data=np.ones(50), x=f, abscissa_spacing=1)
    rec = uff_record(
        pyuff,
        func_type=1,
        rsp_node=2,
        data=np.ones(50),
        x=f / 1e3,
        abscissa_spacing=1,
        ordinate_spec_data_type=8,
    )
    path = tmp_path / "mixed.uff"
    write_uff(path, [{**MM_UNITS, "length": 1.0, "force": 1.0}, *frf, coh, rec])
    refused(
        ["import", path, "--out", tmp_path / "o.npz"],
        capsys,
        "mixed.uff",
        "function type",
        "2 FRF (4)",
        "1 coherence (6)",
        "1 time response (1)",
        "kind",
    )
    got = read_data_file(path, {"kind": "frf"})
    assert got.data.G.shape == (50, 2, 1) and "left out records" in got.notes[0]
    only_coh = tmp_path / "coh.uff"
    write_uff(only_coh, [coh])
    refused(["import", only_coh, "--out", tmp_path / "o.npz"], capsys, "coh.uff", "coherence")


def test_uff_malformed_records_refused(tmp_path, capsys):
    pyuff = pytest.importorskip("pyuff")
    si = {**MM_UNITS, "length": 1.0, "force": 1.0}
    t = np.arange(100) / 1000.0

    def rec(node, n, data_type=8):
        return uff_record(
            pyuff,
            func_type=1,
            rsp_node=node,
            data=np.ones(n),
            x=t[:n],
            abscissa_spacing=1,
            ordinate_spec_data_type=data_type,
        )

    cases = {
        "unequal.uff": ([si, rec(1, 100, 13), rec(2, 90)], ["unequal length", "90 samples"]),
        "accel.uff": ([si, rec(1, 100, 13), rec(2, 100, 12)], ["record 3 (2+Z)", "acceleration"]),
        "norole.uff": ([si, rec(1, 100, 13), rec(2, 100, 0)], ["record 3", "[variables]"]),
    }
    f = np.array([1.0, 2.0, 2.0, 3.0])
    dup = uff_record(
        pyuff,
        func_type=4,
        rsp_node=2,
        data=np.ones(4) + 0j,
        x=f,
        abscissa_spacing=0,
        ordinate_spec_data_type=8,
        orddenom_spec_data_type=13,
    )
    cases["dup.uff"] = ([si, dup], ["record 2", "abscissa", "2 Hz twice"])
    for name, (sets, words) in cases.items():
        write_uff(tmp_path / name, sets)
        refused(["import", tmp_path / name, "--out", tmp_path / "o.npz"], capsys, name, *words)
    toml = tmp_path / "map.toml"
    toml.write_text('[variables]\nu = ["1+Z"]\ny = ["9+Z"]\n')
    refused(
        ["import", tmp_path / "norole.uff", "--out", tmp_path / "o.npz", "--map", toml],
        capsys,
        "map.toml",
        "'9+Z'",
        "not in",
    )
    toml.write_text('[variables]\nu = ["1+Z"]\ny = ["2+Z"]\n')
    refused(
        ["import", tmp_path / "norole.uff", "--out", tmp_path / "o.npz", "--map", toml],
        capsys,
        "record 3 (2+Z)",
        "'units'",
        "data types 0 (unknown)",
    )
    toml.write_text('[variables]\nu = ["1+Z"]\ny = ["2+Z"]\n[units]\n"2+Z" = "um"\n')
    assert import_file(tmp_path / "norole.uff", toml).y.shape == (100, 1)
    (tmp_path / "text.uff").write_text("not a universal file\n")
    refused(["import", tmp_path / "text.uff", "--out", tmp_path / "o.npz"], capsys, "text.uff")
    assert not (tmp_path / "o.npz").exists()


# --------------------------------------------------------------- CLI boundaries
def test_cli_refuses_bad_paths_maps_and_suffixes(tmp_path, capsys):
    data = tmp_path / "d.npz"
    save_measurement(data, frf_example())
    refused(["export", data, "--out", data], capsys, "d.npz", "'.npz'")
    refused(["export", data, "--out", tmp_path / "d.csv"], capsys, "d.csv", ".uff", ".mat")
    refused(["import", tmp_path / "d.xlsx", "--out", tmp_path / "o.npz"], capsys, "'.xlsx'")
    mat = tmp_path / "d.mat"
    assert main(["export", str(data), "--out", str(mat)]) == 0
    refused(["import", mat, "--out", mat], capsys, "d.mat", "input")
    toml = tmp_path / "map.toml"
    toml.write_text("kind = time\n")
    refused(["import", mat, "--out", tmp_path / "o.npz", "--map", toml], capsys, "map.toml", "TOML")
    toml.write_text('knd = "time"\n')
    refused(["import", mat, "--out", tmp_path / "o.npz", "--map", toml], capsys, "'knd'")
    toml.write_text("fs = 1000.0\n")  # the file says 3333.33... Hz
    refused(["import", mat, "--out", tmp_path / "o.npz", "--map", toml], capsys, "'fs'", "1000.0")
    with pytest.raises(InputError, match="not a MATLAB|unreadable"):
        (tmp_path / "junk.mat").write_bytes(b"\x00" * 300)
        import_file(tmp_path / "junk.mat")
    assert not (tmp_path / "o.npz").exists() and leftovers(tmp_path) == []
