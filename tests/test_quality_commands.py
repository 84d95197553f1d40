"""Every command that reads a measurement says the same data-quality warnings (issue 13).

A set of bad records (constant input, two identical inputs, a clipped sensor,
closed-loop data without r, an excitation gap; an FRF with noise-dominated
lines and one with a gap in its grid) goes through ``info`` and through every
command that reads a measurement (compare, diagnose, augment, identify, frf,
modalfit, update, predict). The warning lines must be those of ``info``, word
for word, and must come before the work: the heavy step of each command is
replaced by a stub that stops it (one line, exit 2), so the test is quick and
shows the warnings were said before any diagnosis was built on the data.
"""

from __future__ import annotations

import numpy as np
import pytest

from workbench.cli.main import main
from workbench.core.errors import InputError
from workbench.core.model import LTIModel
from workbench.io.formats import FrfData, TimeData, save_measurement

FS = 1000.0  # Hz
PERIOD = 500  # samples: 2 Hz line spacing
N_PER = 4


def _model() -> LTIModel:
    """Two masses (1 kg, 2 kg) on springs, coupled: modes near 20 and 50 Hz, stable."""
    m = np.diag([1.0, 2.0])
    k = np.array([[(2 * np.pi * 20) ** 2 + 2e4, -2e4], [-2e4, 2 * (2 * np.pi * 40) ** 2 + 2e4]])
    mi = np.linalg.inv(m)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-mi @ k, -0.02 * np.sqrt(k.diagonal()) * mi]])
    B = np.vstack([np.zeros((2, 2)), mi])
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    return LTIModel(
        A=A, B=B, C=C, D=np.zeros((2, 2)), input_names=("F1", "F2"), output_names=("x1", "x2")
    )


def _multisine(rng, lines_hz, n_u=2) -> np.ndarray:
    """One period per input, each input on its own lines (odd/even halves), random phases."""
    out = np.zeros((PERIOD, n_u))
    k = np.round(np.asarray(lines_hz) * PERIOD / FS).astype(int)
    for j in range(n_u):
        X = np.zeros(PERIOD // 2 + 1, complex)
        mine = k[j::n_u]
        X[mine] = np.exp(2j * np.pi * rng.random(mine.size))
        out[:, j] = np.fft.irfft(X, PERIOD)
    return np.tile(out / out.std(axis=0), (N_PER, 1))


def _time(u, *, loop="open", r=None, clip=False, rng) -> TimeData:
    from workbench import sim

    y = sim.simulate_zoh(_model().to_statespace(), u, FS)
    y = y + 1e-3 * y.std(axis=0) * rng.standard_normal(y.shape)
    if clip:
        y[:, 0] = np.minimum(y[:, 0], 0.6 * y[:, 0].max())
    return TimeData(
        fs=FS,
        u=u,
        y=y,
        r=r,
        loop=loop,
        period=PERIOD,
        input_names=("F1", "F2"),
        output_names=("x1", "x2"),
    )


LINES = np.arange(2.0, 200.0, 2.0)


def bad_time_records(rng) -> dict[str, tuple[TimeData, str]]:
    """name -> (record, a phrase its warning must hold)."""
    u = _multisine(rng, LINES)
    const = u.copy()
    const[:, 1] = 0.3
    same = u.copy()
    same[:, 1] = same[:, 0]
    gap = _multisine(rng, LINES[(LINES < 80) | (LINES > 120)])
    return {
        "constant-input": (_time(const, rng=rng), "is constant"),
        "identical-inputs": (_time(same, rng=rng), "are proportional"),
        "clipped-sensor": (_time(u, clip=True, rng=rng), "looks clipped"),
        "closed-without-r": (_time(u, loop="closed", rng=rng), "without the reference 'r'"),
        "excitation-gap": (_time(gap, rng=rng), "gap in the excited"),
    }


FE_INPUTS, FE_OUTPUTS = ("F1", "F2", "F3"), ("s1", "s2", "s5")


def bad_frf_records(fe_file) -> dict[str, tuple[FrfData, str]]:
    """FRFs of the beam FE prior (names as its file), with noise-dominated lines or a gap."""
    from workbench.fe import modal_terms, read_fe

    fe = read_fe(fe_file)
    freq = np.arange(1.0, 600.0, 0.5)
    G = modal_terms(fe, n_modes=fe.n_dof).frf(freq)[:, [0, 1, 4]]
    var = (0.01 * np.abs(G)) ** 2
    noisy = var.copy()
    band = (freq > 200) & (freq < 260)
    noisy[band] = 4 * np.abs(G[band]) ** 2  # SNR -6 dB over 60 Hz on every element
    keep = (freq < 300) | (freq > 400)
    return {
        "noise-dominated": (
            FrfData(freq, G, noisy, None, FE_INPUTS, FE_OUTPUTS),
            "SNR < 0 dB",
        ),
        "grid-gap": (
            FrfData(freq[keep], G[keep], var[keep], None, FE_INPUTS, FE_OUTPUTS),
            "no lines between",
        ),
    }


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from plants.beam import beam_fe_file, beam_prior_config
    from workbench.fe import save_fe
    from workbench.io.formats import save_model

    d = tmp_path_factory.mktemp("bad")
    rng = np.random.default_rng(13)
    save_model(d / "model.npz", _model())
    out = {"time": {}, "frf": {}, "dir": d}
    for name, (rec, phrase) in bad_time_records(rng).items():
        save_measurement(d / f"{name}.npz", rec)
        out["time"][name] = (d / f"{name}.npz", phrase)
    save_fe(d / "fe.npz", beam_fe_file(beam_prior_config(), damping=0.01))
    for name, (rec, phrase) in bad_frf_records(d / "fe.npz").items():
        save_measurement(d / f"{name}.npz", rec)
        out["frf"][name] = (d / f"{name}.npz", phrase)
    # a 3 x 3 model for compare / diagnose on the FRFs (stubbed: any model of that size)
    save_model(
        d / "fe_model.npz",
        LTIModel(
            A=-10.0 * np.eye(2),
            B=np.ones((2, 3)),
            C=np.ones((3, 2)),
            D=np.zeros((3, 3)),
            input_names=FE_INPUTS,
            output_names=FE_OUTPUTS,
        ),
    )
    return out


def _stop(*_a, **_k):
    raise InputError("stub: the work starts here")


@pytest.fixture
def stubs(monkeypatch):
    """Replace the heavy step of every command by a one-line refusal."""
    import workbench.diagnosis
    import workbench.diagnosis.augment
    import workbench.fe.predict
    import workbench.modal.fit
    import workbench.signals.frf
    from workbench.cli.commands import compare as compare_cmd
    from workbench.cli.commands import identify as identify_cmd

    monkeypatch.setattr(workbench.diagnosis, "diagnose", _stop)
    monkeypatch.setattr(workbench.diagnosis.augment, "augment", _stop)
    monkeypatch.setattr(compare_cmd, "compare", _stop)
    monkeypatch.setattr(identify_cmd, "identify_subspace", _stop)
    monkeypatch.setattr(workbench.signals.frf, "estimate_frf", _stop)
    monkeypatch.setattr(workbench.modal.fit, "fit_modal", _stop)
    monkeypatch.setattr(workbench.fe.predict, "predict_frf", _stop)


def _warnings(capsys, argv) -> tuple[int, list[str]]:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    return rc, [line for line in err.splitlines() if line.startswith("warning:")]


TIME_COMMANDS = {
    "compare": lambda d, f: ["compare", "--model", d / "model.npz", "--data", f],
    "diagnose": lambda d, f: ["diagnose", "--model", d / "model.npz", "--data", f],
    "augment": lambda d, f: [
        "augment",
        "--model",
        d / "model.npz",
        "--data",
        f,
        "--effect",
        "time_delay",
    ],
    "identify": lambda d, f: ["identify", f, "--method", "moesp", "--out", d / "id.npz"],
    "frf": lambda d, f: ["frf", f, "--out", d / "frf_out.npz"],
}


@pytest.mark.parametrize("record", list(bad_time_records(np.random.default_rng(0))))
@pytest.mark.parametrize("command", list(TIME_COMMANDS))
def test_time_record_warnings_same_in_every_command(files, stubs, capsys, record, command):
    path, phrase = files["time"][record]
    rc_info, info_lines = _warnings(capsys, ["info", path])
    assert rc_info == 0
    assert any(phrase in w for w in info_lines), (record, info_lines)
    rc, lines = _warnings(capsys, TIME_COMMANDS[command](files["dir"], path))
    assert rc == 2  # stopped by the stub: the warnings came before the work
    assert set(info_lines) <= set(lines), (command, record, lines)


def test_open_loop_method_on_closed_loop_record_warns(files, stubs, capsys):
    path, _ = files["time"]["closed-without-r"]
    d = files["dir"]
    _, lines = _warnings(capsys, ["identify", path, "--method", "moesp", "--out", d / "m.npz"])
    assert any("open-loop method 'moesp' on closed-loop data" in w for w in lines), lines
    _, lines = _warnings(capsys, ["info", path])
    assert not any("open-loop method" in w for w in lines)  # said where a method is run


FRF_COMMANDS = {
    "modalfit": lambda d, f: ["modalfit", f, "--out", d / "modal.npz"],
    "update": lambda d, f: ["update", "--fe", d / "fe.npz", "--data", f, "--out", d / "up.npz"],
    "predict": lambda d, f: ["predict", "--fe", d / "fe.npz", "--data", f, "--out", d / "p.npz"],
    "compare": lambda d, f: ["compare", "--model", d / "fe_model.npz", "--data", f],
    "diagnose": lambda d, f: ["diagnose", "--model", d / "fe_model.npz", "--data", f],
}


@pytest.mark.parametrize("record", ["noise-dominated", "grid-gap"])
@pytest.mark.parametrize("command", list(FRF_COMMANDS))
def test_frf_warnings_same_in_every_command(files, stubs, capsys, record, command):
    path, phrase = files["frf"][record]
    _, info_lines = _warnings(capsys, ["info", path])
    assert any(phrase in w for w in info_lines), (record, info_lines)
    rc, lines = _warnings(capsys, FRF_COMMANDS[command](files["dir"], path))
    assert rc == 2
    assert set(info_lines) <= set(lines), (command, record, lines)


def test_good_record_gives_no_warning(files, stubs, capsys, tmp_path):
    rng = np.random.default_rng(2)
    save_measurement(tmp_path / "good.npz", _time(_multisine(rng, LINES), rng=rng))
    rc, lines = _warnings(
        capsys, ["compare", "--model", files["dir"] / "model.npz", "--data", tmp_path / "good.npz"]
    )
    assert lines == []


# ------------------------------------------------------------------ unstable poles
def test_unstable_model_warned_in_one_line_rigid_body_not(tmp_path, capsys, files):
    from workbench.io.formats import save_model

    path, _ = files["time"]["clipped-sensor"]
    # a rigid-body double integrator (poles at 0) and a mode at 30 Hz: no warning
    w = 2 * np.pi * 30
    A = np.array([[0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1], [0, 0, -(w**2), 0.02 * w]])
    for growth, expect in ((-0.02 * w, False), (0.02 * w, True)):
        A[3, 3] = growth  # + : the 30 Hz pair grows
        m = LTIModel(
            A=A,
            B=np.array([[0, 0], [1, 0], [0, 0], [0, 1.0]]),
            C=np.array([[1.0, 0, 0, 0], [0, 0, 1, 0]]),
            D=np.zeros((2, 2)),
        )
        save_model(tmp_path / "m.npz", m)
        rc = main(["info", str(tmp_path / "m.npz")])
        err = capsys.readouterr().err
        assert rc == 0
        lines = [x for x in err.splitlines() if "unstable pole" in x]
        assert len(lines) == (1 if expect else 0), err
        if expect:
            assert "30 Hz" in lines[0] and "rigid-body" in lines[0]


def test_compare_warns_unstable_model(tmp_path, capsys, files):
    from workbench.io.formats import save_model

    path, _ = files["time"]["clipped-sensor"]
    m = _model()
    A = np.array(m.A)
    A[2:, 2:] = -A[2:, 2:]  # negative damping: both modes grow
    save_model(tmp_path / "bad.npz", m.replace(A=A))
    rc = main(["compare", "--model", str(tmp_path / "bad.npz"), "--data", str(path)])
    err = capsys.readouterr().err
    assert rc == 0
    assert sum("unstable pole" in x for x in err.splitlines()) == 1
