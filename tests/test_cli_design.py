"""``workbench design`` and ``workbench loop`` on a small model file.

The plant: a mass 1/(m s^2) plus one flexible mode at 300 Hz (one force, one
position), 5 kHz, one sample of loop delay. Oracles: the design functions
called directly with the same settings (the written controller must be theirs,
bit for bit) and :func:`workbench.loop.analyze_loop` of the model with the
controller read back (the printed and JSON figures must be its figures).
"""

from __future__ import annotations

import json

import control
import numpy as np
import pytest
from conftest import one_line

from controllers.protocol import StateSpaceController
from workbench.cli.main import main
from workbench.core.model import LTIModel
from workbench.io.formats import read_model, read_npz
from workbench.loop import analyze_loop

FS = 5000.0
M, F_FLEX, Z_FLEX = 2.0, 300.0, 0.01


def mass_flex() -> LTIModel:
    w = 2 * np.pi * F_FLEX
    g = control.tf([1.0], [M, 0, 0]) + control.tf([1.0], [1, 2 * Z_FLEX * w, w * w])
    return LTIModel.from_statespace(control.ss(g), input_names=("F",), output_names=("x",))


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("design") / "model.npz"
    mass_flex().write(path)
    return path


@pytest.fixture(scope="module")
def designs(model_file, tmp_path_factory):
    """Both designs run once for the module: (controller file, report, printed text)."""
    tmp = tmp_path_factory.mktemp("out")
    got = {}
    for method in ("pid-notch", "modal-sf"):
        out, rep = tmp / f"K_{method}.npz", tmp / f"{method}.json"
        argv = ["design", "--model", str(model_file), "--method", method, "--fs", str(FS)]
        argv += ["--loop-delay-samples", "1", "--out", str(out), "--json", str(rep)]
        assert main(argv) == 0
        got[method] = (out, json.loads(rep.read_text()))
    return got


def reference_controller(method: str, report: dict):
    """The controller the design function gives when called directly with the same settings."""
    model = mass_flex()
    if method == "pid-notch":
        from controllers.pid_notch import tune_pid_notch

        return tune_pid_notch(model, FS, ms_max=2.0, loop_delay_samples=1)[0].controller
    from controllers.modal_sf import tune_modal_sf

    d = tune_modal_sf(model, ms_max=2.0, loop_delay_samples=1, fs=FS)
    assert report["settings"] == d.report.settings  # the CLI reports what the tuner kept
    return d.controller


@pytest.mark.parametrize("method", ["pid-notch", "modal-sf"])
def test_design_writes_the_designed_controller_as_a_spec5_file(designs, method):
    path, report = designs[method]
    arrays = read_npz(path)
    assert str(arrays["role"]) == "controller" and int(arrays["delay_samples"]) == 1
    assert "delay_s" not in arrays  # the loop delay is not in the controller's matrices
    back = StateSpaceController.read(path)
    assert back.input_names == ("x",) and back.output_names == ("F",)
    assert back.fs == FS and back.delay_samples == 1
    ref = reference_controller(method, report).statespace()
    got = back.statespace()
    for k in "ABCD":
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k))
    # the report's figures are analyze_loop's on the model, and meet the bound
    a = analyze_loop(read_model(report["model"]), back, loop_delay_samples=1)
    loop = report["analysis"]["loops"][0]
    assert loop["crossover_hz"] == pytest.approx(a.loops[0].crossover_hz, rel=1e-12)
    assert loop["s_peak"] == pytest.approx(a.loops[0].s_peak, rel=1e-12)
    assert a.stable and a.loops[0].s_peak <= 2.0 * (1 + 1e-6)
    assert a.loops[0].crossover_hz > 30.0  # a working design, not a token one


def test_loop_prints_and_writes_analyze_loops_figures(designs, model_file, tmp_path, capsys):
    path, _ = designs["modal-sf"]
    out = tmp_path / "loop.json"
    plots = tmp_path / "plots"
    argv = ["loop", "--plant", str(model_file), "--controller", str(path)]
    assert main(argv + ["--json", str(out), "--plots", str(plots)]) == 0
    text = capsys.readouterr().out
    # default loop delay: the one the controller's design assumed (1 sample)
    a = analyze_loop(read_model(model_file), StateSpaceController.read(path), loop_delay_samples=1)
    lp = a.loops[0]
    row = next(r for r in text.splitlines() if r.split()[:1] == [lp.name])
    assert row.split()[1:4] == [
        f"{lp.crossover_hz:.1f}",
        f"{lp.bandwidth_hz:.1f}",
        f"{lp.s_peak:.3f}",
    ]
    got = json.loads(out.read_text())
    assert got["loop_delay_samples"] == 1
    assert got["loops"][0]["crossover_hz"] == pytest.approx(lp.crossover_hz, rel=1e-12)
    assert got["loops"][0]["s_peak"] == pytest.approx(lp.s_peak, rel=1e-12)
    assert sorted(p.name for p in plots.iterdir()) == [
        "loop_bode.png", "loop_nyquist.png", "loop_sensitivity.png",
    ]  # fmt: skip
    # an explicit loop delay overrides the controller's: two samples cost phase
    assert main(argv + ["--loop-delay-samples", "2"]) == 0
    a2 = analyze_loop(read_model(model_file), StateSpaceController.read(path), loop_delay_samples=2)
    assert a2.loops[0].phase_margin_deg < lp.phase_margin_deg
    assert f"{a2.loops[0].s_peak:.3f}" in capsys.readouterr().out


def test_refusals_are_one_line_exit_2(designs, model_file, tmp_path, capsys, monkeypatch):
    # a non-square model: two forces, one sensor
    wide = tmp_path / "wide.npz"
    LTIModel(np.zeros((2, 2)), np.ones((2, 2)), np.ones((1, 2)), np.zeros((1, 2))).write(wide)
    base = ["design", "--method", "pid-notch", "--fs", str(FS)]
    out = tmp_path / "K.npz"
    assert main(base + ["--model", str(wide), "--out", str(out)]) == 2
    assert "2 inputs and 1 outputs" in one_line(capsys.readouterr().err)
    # modal-sf on a mode the actuator cannot move (b = 0): Lemma 1, named, nothing written
    from workbench.modal.model import ModalModel, Mode

    lemma = tmp_path / "lemma.npz"
    modes = (
        Mode("rigid", 0.0, 0.0, b=[0.5], c=[1.0]),
        Mode("flexible", F_FLEX, Z_FLEX, b=[0.0], c=[1.0]),
    )
    LTIModel.from_statespace(ModalModel(modes=modes, D=np.zeros((1, 1))).to_statespace()).write(
        lemma
    )
    argv = ["design", "--model", str(lemma), "--method", "modal-sf", "--fs", str(FS)]
    assert main(argv + ["--out", str(out)]) == 2
    assert "mode 2" in (line := one_line(capsys.readouterr().err)) and "Lemma 1" in line
    assert not out.exists()
    # an |S| bound no design meets: refused, nothing written
    assert main(base + ["--model", str(model_file), "--ms-max", "1.05", "--out", str(out)]) == 2
    one_line(capsys.readouterr().err)
    assert not out.exists() and not list(tmp_path.glob(".K.*"))

    # an unwritable --out is refused before the design runs
    def no_design(*_a, **_k):
        raise AssertionError("the design ran before the output was checked")

    monkeypatch.setattr("controllers.pid_notch.tune_pid_notch", no_design)
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for bad in (blocker / "K.npz", tmp_path):  # under a file; a directory
        assert main(base + ["--model", str(model_file), "--out", str(bad)]) == 2
        assert str(bad) in one_line(capsys.readouterr().err)
    # the output over the input
    assert main(base + ["--model", str(model_file), "--out", str(model_file)]) == 2
    assert "over an input" in one_line(capsys.readouterr().err)
    # a measured FRF is for youla's robust design only
    assert main(base + ["--model", str(model_file), "--frf", str(model_file)]) == 2
    assert "youla only" in one_line(capsys.readouterr().err)
    # loop: a 1x1 controller on a plant with other channel counts
    path, _ = designs["pid-notch"]
    assert main(["loop", "--plant", "beam", "--controller", str(path)]) == 2
    assert "5 inputs (errors) and 3 outputs" in one_line(capsys.readouterr().err)
    assert main(["loop", "--plant", "no_such_plant", "--controller", str(path)]) == 2
    assert "wafer_stage" in one_line(capsys.readouterr().err)


# ------------------------------------------------------------------ hinf
F_HIGH, B_HIGH = 1500.0, 0.05  # a stage-like mode: above the crossover, weakly coupled


@pytest.fixture(scope="module")
def stage_like_file(tmp_path_factory):
    """The 2 kg mass with one flexible mode at 1500 Hz (residue 0.05 against the rigid 0.5)."""
    w = 2 * np.pi * F_HIGH
    g = control.tf([1.0], [M, 0, 0]) + control.tf([B_HIGH], [1, 2 * Z_FLEX * w, w * w])
    path = tmp_path_factory.mktemp("hinf") / "model.npz"
    model = LTIModel.from_statespace(control.ss(g), input_names=("F",), output_names=("x",))
    model.write(path)
    return path


def test_hinf_design_round_trip_meets_the_bound(stage_like_file, tmp_path, capsys):
    """--method hinf: spec-5 file, report = analyze_loop of the file on the model, |S| <= 2."""
    model_file = stage_like_file
    out, rep = tmp_path / "K_hinf.npz", tmp_path / "hinf.json"
    argv = ["design", "--model", str(model_file), "--method", "hinf", "--fs", str(FS)]
    argv += ["--loop-delay-samples", "1", "--out", str(out), "--json", str(rep)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    arrays = read_npz(out)
    assert str(arrays["role"]) == "controller" and int(arrays["delay_samples"]) == 1
    back = StateSpaceController.read(out)
    assert back.input_names == ("x",) and back.output_names == ("F",) and back.fs == FS
    report = json.loads(rep.read_text())
    assert report["method"] == "hinf" and len(report["settings"]["gamma"]) == 1
    a = analyze_loop(read_model(model_file), back, loop_delay_samples=1)
    assert a.stable and a.loops[0].s_peak <= 2.0 * (1 + 1e-6)
    loop = report["analysis"]["loops"][0]
    assert loop["crossover_hz"] == pytest.approx(a.loops[0].crossover_hz, rel=1e-12)
    row = next(r for r in text.splitlines() if r.split()[:1] == ["x"])
    assert row.split()[1] == f"{a.loops[0].crossover_hz:.1f}"
    assert a.loops[0].crossover_hz > 30.0  # a working loop, not a token one


def test_hinf_infeasible_bound_refused_in_one_line(stage_like_file, tmp_path, capsys):
    # |S| <= 1.01 at every frequency: no loop with a delay meets it (Bode's integral)
    out = tmp_path / "K.npz"
    argv = ["design", "--model", str(stage_like_file), "--method", "hinf", "--fs", str(FS)]
    assert main(argv + ["--ms-max", "1.01", "--out", str(out)]) == 2
    line = one_line(capsys.readouterr().err)
    assert "hinf" in line and "1.01" in line
    assert not out.exists() and not list(tmp_path.glob(".K.*"))


# ------------------------------------------------------------------ youla
def test_youla_design_round_trip_beats_the_baseline(model_file, designs, tmp_path):
    """--method youla: the written controller is tune_youla's, stable, |S| <= 2 on the
    model, and its crossover above the pid-notch design it starts from."""
    from controllers.youla import tune_youla

    out, rep = tmp_path / "K_youla.npz", tmp_path / "youla.json"
    argv = ["design", "--model", str(model_file), "--method", "youla", "--fs", str(FS)]
    argv += ["--loop-delay-samples", "1", "--out", str(out), "--json", str(rep)]
    assert main(argv) == 0
    report = json.loads(rep.read_text())
    K = StateSpaceController.read(out)
    ref = tune_youla(mass_flex(), ms_max=2.0, loop_delay_samples=1, fs=FS).controller
    assert np.array_equal(K.A, ref.A) and np.array_equal(K.D, ref.D)
    a = analyze_loop(read_model(model_file), K, loop_delay_samples=1)
    assert a.stable and a.loops[0].s_peak <= 2.0
    pid = designs["pid-notch"][1]
    assert a.loops[0].crossover_hz > 1.2 * pid["analysis"]["loops"][0]["crossover_hz"]
    assert report["settings"]["template_hz"][0] > 0
