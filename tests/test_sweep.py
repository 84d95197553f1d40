"""``workbench sweep``: the KEY=SPEC grammar, the plan, resume, failed runs, tables, Dask, CLI.

Most runs use a tiny scenario: the wafer stage (5 kHz) with a 200-sample closed-loop step
experiment under the experiment's default PID, ~0.2 s a run once imported; its figure is the
largest output rms of the experiment (``max(summary.json:experiment.y_rms.*)``), which moves
with the delay and the mode errors. Oracles: the grammar's definitions (linspace, the offset,
the distributions' supports), the row files on disk (their mtimes show what was not redone),
the Parquet table read back against the CSV, and the local pool's table against Dask's.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line

from workbench.cli.main import main
from workbench.core.errors import InputError
from workbench.io.scenario import load_scenario
from workbench.sweep import (
    apply_overrides,
    collect_figures,
    parse_figure,
    parse_vary,
    plan_sweep,
    run_sweep,
    sweep_settings,
)

TINY = """
[scenario]
name = "tiny"
seed = 7
results = "{results}"

[plant]
name = "wafer_stage"
[plant.effects]
delay_s = 2e-4
mode_freq_error = [0.0, 0.0]

[experiment]
kind = "step"
loop = "closed"
n_samples = 200

[sweep.collect]
y_rms_max = "max(summary.json:experiment.y_rms.*)"
"""
# two delays x two Monte-Carlo draws of both mode frequencies: 4 runs
VARY = ["plant.effects.delay_s=[1e-4, 3e-4]", "plant.effects.mode_freq_error=uniform(-0.05,0.05)"]


@pytest.fixture
def tiny(tmp_path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY.format(results=tmp_path / "results"))
    return path


def table_rows(out: Path) -> list[dict]:
    import pyarrow.parquet as pq

    return pq.read_table(out / "sweep_table.parquet").to_pylist()


def mtimes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in folder.glob("*.json")}


# ------------------------------------------------------------------ grammar
@pytest.mark.parametrize(
    ("spec", "values"),
    [
        ("0:1:3", (0.0, 0.5, 1.0)),  # numpy.linspace, both ends included
        ("5:5:1", (5.0,)),
        ("0:4e-4:3", (0.0, 2e-4, 4e-4)),
        ("[1, 2.5, true]", (1, 2.5, True)),
        ('["pid-notch", modal-sf]', ("pid-notch", "modal-sf")),  # bare words are strings
        ("[[0.01, 0.02], [0.0, 0.0]]", ([0.01, 0.02], [0.0, 0.0])),
    ],
    ids=["linspace", "one-point", "exponents", "toml-list", "words", "per-element"],
)
def test_grid_specs(spec, values):
    v = parse_vary(f"design.ms_max={spec}")
    assert v.is_grid
    assert v.values == pytest.approx(values) if isinstance(values[0], float) else v.values == values


@pytest.mark.parametrize(
    ("spec", "dist", "params", "offset"),
    [
        ("uniform(-0.05,0.05)", "uniform", (-0.05, 0.05), 0.0),
        ("loguniform(0.5, 2) - 1", "loguniform", (0.5, 2.0), -1.0),
        ("normal(0,1e-5)+2e-4", "normal", (0.0, 1e-5), 2e-4),
        ("choice(pid-notch, 2, [1, 2])", "choice", ("pid-notch", 2, [1, 2]), 0.0),
    ],
    ids=["uniform", "loguniform-offset", "normal-offset", "choice"],
)
def test_distribution_specs(spec, dist, params, offset):
    v = parse_vary(f"plant.effects.delay_s={spec}")
    assert (v.dist, v.params, v.offset) == (dist, params, offset)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("plant.effects.delay_s", "expected KEY=SPEC"),
        ("plant.effects.delay_s=unifrm(0,1)", "delay_s: expected SPEC as a:b:n"),
        ("plant.effects.delay_s=uniform(1)", "two numbers"),
        ("plant.effects.delay_s=uniform(2,1)", "lo <= hi"),
        ("plant.effects.delay_s=loguniform(0,1)", "0 < lo"),
        ("plant.effects.delay_s=normal(0,-1)", "sigma >= 0"),
        ("plant.effects.delay_s=0:1:x", "expected SPEC as"),
        ("plant.effects.delay_s=[1, 2", "expected SPEC as"),
        ("plant.effects.delay_s=[]", "non-empty list"),
        ("plant.effects.delay_s=choice()", "at least one value"),
        ("plant=1:2:3", "expected a dotted scenario key"),
        ("scenario.name=[a]", "only 'scenario.seed'"),
        ("sweep.runs=[3]", "key of a stage table"),
    ],
    ids=lambda x: x if len(x) < 30 else x[:30],
)
def test_malformed_vary_is_one_line_naming_the_key(text, match):
    with pytest.raises(InputError, match=match) as info:
        parse_vary(text)
    message = str(info.value)
    assert "\n" not in message and text.split("=")[0] in message


@pytest.mark.parametrize(
    ("varies", "runs", "match"),
    [
        (["evaluate.plots=[true]"], None, r"no \[evaluate\] table"),
        (["plant.effects.delay_s=uniform(0,1e-4)"], None, "needs --runs"),
        (["plant.effects.delay_s=[0, 1e-4]"], 3, "only with a distribution"),
        (["plant.name=[a]", "plant.name=[b]"], None, "given twice"),
        (["scenario.seed=[1.5]"], None, "expected integers >= 0"),
        (["plant.name.x=[1]"], None, "not a table"),
        ([], None, "nothing to vary"),
    ],
    ids=["no-table", "no-runs", "runs-without-dist", "twice", "seed", "into-a-value", "none"],
)
def test_plan_refusals(tiny, varies, runs, match):
    scenario = load_scenario(tiny)
    with pytest.raises(InputError, match=match):
        plan_sweep(scenario, [parse_vary(v) for v in varies], runs=runs)


# ------------------------------------------------------------------ plan
def test_grid_product_first_key_slowest_and_ids_stable(tiny):
    scenario = load_scenario(tiny)
    a, b = parse_vary("plant.effects.delay_s=0:4e-4:3"), parse_vary("scenario.seed=[1, 2]")
    plan = plan_sweep(scenario, [a, b])
    assert [dict(v.overrides) for v in plan] == [
        {"plant.effects.delay_s": d, "scenario.seed": s} for d in (0.0, 2e-4, 4e-4) for s in (1, 2)
    ]
    assert all(isinstance(dict(v.overrides)["scenario.seed"], int) for v in plan)
    assert len({v.run_id for v in plan}) == 6
    # the id is of the overrides, not of the order of the --vary options
    assert {v.run_id for v in plan_sweep(scenario, [b, a])} == {v.run_id for v in plan}
    # ... and of the base scenario: another seed is another sweep
    other = dataclasses.replace(scenario, seed=8)
    assert not {v.run_id for v in plan_sweep(other, [a, b])} & {v.run_id for v in plan}


def test_monte_carlo_is_reproducible_prefix_stable_and_per_element(tiny):
    scenario = load_scenario(tiny)
    freq = parse_vary("plant.effects.mode_freq_error=uniform(-0.05,0.05)")
    damp = parse_vary("plant.effects.delay_s=loguniform(0.5,2)-1")  # a scalar default
    plan = plan_sweep(scenario, [freq, damp], runs=50)
    again = plan_sweep(scenario, [freq, damp], runs=50)
    assert plan == again  # same command, same draws, same ids
    assert plan_sweep(scenario, [freq, damp], runs=20) == plan[:20]  # --runs 20 is a prefix
    # adding a key leaves the other key's draws alone
    alone = plan_sweep(scenario, [freq], runs=50)
    assert [v.overrides[0] for v in alone] == [v.overrides[0] for v in plan]
    f = np.array([dict(v.overrides)[freq.key] for v in plan])
    d = np.array([dict(v.overrides)[damp.key] for v in plan])
    # the scenario gives mode_freq_error as a 2-list: two independent draws per run
    assert f.shape == (50, 2) and np.all(np.abs(f) <= 0.05) and not np.allclose(f[:, 0], f[:, 1])
    # a factor 0.5 .. 2 minus one: the relative error -0.5 .. 1, log-uniform (median factor 1)
    assert d.shape == (50,) and np.all((d >= -0.5) & (d <= 1.0))
    assert np.mean(np.log(1 + d) < 0) == pytest.approx(0.5, abs=0.2)
    # another scenario seed, other draws
    other = dataclasses.replace(scenario, seed=8)
    assert plan_sweep(other, [freq], runs=5)[0].overrides != alone[0].overrides


def test_apply_overrides_sets_nested_keys_on_a_copy(tiny):
    scenario = load_scenario(tiny)
    sc = apply_overrides(
        scenario,
        [("plant.effects.delay_s", 3e-4), ("experiment.rms", 2.0), ("scenario.seed", 3)],
        results="/tmp/x",
    )
    assert sc.tables["plant"]["effects"]["delay_s"] == 3e-4 and sc.tables["experiment"]["rms"] == 2
    assert sc.seed == 3 and str(sc.results) == "/tmp/x"
    assert scenario.tables["plant"]["effects"]["delay_s"] == 2e-4 and scenario.seed == 7


def test_collect_figures_wildcards_reducers_and_non_finite(tmp_path):
    doc = {
        "designs": {
            "a": {"stable": True, "loops": [{"s": 1.5}, {"s": "inf"}], "r": None},
            "b": {"stable": False, "loops": [{"s": 2.0}, {"s": 1.0}], "r": 0.5},
        }
    }
    (tmp_path / "evaluation.json").write_text(json.dumps(doc))
    figures = [
        parse_figure("stable", "evaluation.json:designs.*.stable"),
        parse_figure("s_max", "max(evaluation.json:designs.*.loops.*.s)"),
        parse_figure("s_min", "min(evaluation.json:designs.*.loops.*.s)"),
        parse_figure("r", "evaluation.json:designs.*.r"),
        parse_figure("missing", "other.json:x"),
    ]
    got = collect_figures(tmp_path, figures)
    assert got == {
        "stable.a": True, "stable.b": False, "s_max.a": float("inf"), "s_max.b": 2.0,
        "s_min.a": 1.5, "s_min.b": 1.0, "r.a": None, "r.b": 0.5,
    }  # fmt: skip


# ------------------------------------------------------------------ running
def test_sweep_writes_rows_and_tables_and_resumes_without_redoing(tiny, tmp_path):
    scenario = load_scenario(tiny)
    out = tmp_path / "sweep"
    varies = [parse_vary(v) for v in VARY]
    first = run_sweep(scenario, varies=varies, runs=2, out=out, workers=0)
    assert (first.n_planned, first.n_run, first.n_resumed, first.n_failed) == (4, 4, 0, 0)
    rows = table_rows(out)
    assert [r["run_id"] for r in rows] == [v.run_id for v in plan_sweep(scenario, varies, runs=2)]
    assert [r["plant.effects.delay_s"] for r in rows] == [1e-4, 1e-4, 3e-4, 3e-4]
    assert all(r["status"] == "ok" and r["y_rms_max"] > 0 for r in rows)
    assert len({r["y_rms_max"] for r in rows}) == 4  # the varied plant moves the figure
    for r in rows:  # the run's own folder, and its figure read back from it
        summary = json.loads((out / "runs" / r["run_id"] / "summary.json").read_text())
        assert max(summary["experiment"]["y_rms"]) == r["y_rms_max"]
    before = mtimes(out / "rows")
    again = run_sweep(scenario, varies=varies, runs=2, out=out, workers=0)
    assert (again.n_run, again.n_resumed) == (0, 4)
    assert mtimes(out / "rows") == before
    # more draws: the first two are the same runs, found done
    more = run_sweep(scenario, varies=varies, runs=3, out=out, workers=0)
    assert (more.n_planned, more.n_run, more.n_resumed) == (6, 2, 4)
    assert {k: v for k, v in mtimes(out / "rows").items() if k in before} == before


def test_interrupted_sweep_keeps_finished_rows_and_resumes(tiny, tmp_path, monkeypatch):
    import workbench.sweep.runner as sweep

    scenario = load_scenario(tiny)
    out = tmp_path / "sweep"
    varies = [parse_vary("plant.effects.delay_s=0:4e-4:5")]
    real, calls = sweep.run_variation, []

    def interrupted_on_the_third(*args):
        calls.append(args[1])
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(sweep, "run_variation", interrupted_on_the_third)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(scenario, varies=varies, out=out, workers=0)
    assert len(list((out / "rows").glob("*.json"))) == 2
    assert len(table_rows(out)) == 2  # the table of what finished, written on the way out
    before = mtimes(out / "rows")
    monkeypatch.setattr(sweep, "run_variation", real)
    result = run_sweep(scenario, varies=varies, out=out, workers=0)
    assert (result.n_resumed, result.n_run) == (2, 3)
    assert {k: v for k, v in mtimes(out / "rows").items() if k in before} == before
    assert len(table_rows(out)) == 5


def test_failing_variation_is_a_row_with_its_error(tiny, tmp_path):
    scenario = load_scenario(tiny)
    out = tmp_path / "sweep"
    # Effects refuses a damping error below -1 (a negative damping ratio)
    varies = [parse_vary("plant.effects.mode_damping_error=[0.0, -2.0]")]
    result = run_sweep(scenario, varies=varies, out=out, workers=0)
    assert (result.n_run, result.n_failed) == (2, 1)
    ok, bad = table_rows(out)
    assert ok["status"] == "ok" and ok["y_rms_max"] > 0
    assert bad["status"].startswith("error: Effects.mode_damping_error: expected relative errors")
    assert bad["y_rms_max"] is None
    assert "failed x1: error: Effects.mode_damping_error" in result.text
    # a failed run is done too: not rerun unless asked
    assert run_sweep(scenario, varies=varies, out=out, workers=0).n_run == 0
    assert run_sweep(scenario, varies=varies, out=out, workers=0, redo_failed=True).n_run == 1


def test_csv_and_parquet_tables_agree(tiny, tmp_path):
    import pyarrow.csv as pv
    import pyarrow.parquet as pq

    scenario = load_scenario(tiny)
    out = tmp_path / "sweep"
    # 8 runs, the 4 with a damping error of -2 failed: empty (null) figure cells
    bad = parse_vary("plant.effects.mode_damping_error=[0.0, -2.0]")
    result = run_sweep(scenario, varies=[*map(parse_vary, VARY), bad], runs=2, out=out, workers=0)
    assert (result.n_run, result.n_failed) == (8, 4)
    parquet = pq.read_table(out / "sweep_table.parquet")
    csv = pv.read_csv(out / "sweep_table.csv", convert_options=pv.ConvertOptions(
        column_types=parquet.schema, strings_can_be_null=True))  # fmt: skip
    assert csv.column_names == parquet.column_names
    assert "plant.effects.mode_freq_error[1]" in csv.column_names  # one column per element
    assert csv.to_pylist() == parquet.to_pylist()  # floats by repr: exact


def test_local_pool_and_dask_cluster_give_the_same_table(tiny, tmp_path):
    from distributed import LocalCluster

    scenario = load_scenario(tiny)
    varies = [parse_vary(v) for v in VARY]
    local = run_sweep(scenario, varies=varies, runs=2, out=tmp_path / "local", workers=2)
    workers = {r["worker"].rsplit(":", 1)[1] for r in local.rows}
    assert local.n_failed == 0 and len(workers) <= 2 and str(os.getpid()) not in workers
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        dask = run_sweep(
            scenario,
            varies=varies,
            runs=2,
            out=tmp_path / "dask",
            scheduler=cluster.scheduler_address,
        )
    assert dask.n_run == 4 and dask.n_failed == 0
    a, b = table_rows(tmp_path / "local"), table_rows(tmp_path / "dask")
    for row in a + b:
        row.pop("seconds")  # wall time, the one column that may differ
    assert a == b


# ------------------------------------------------------------------ command line
def test_cli_sweep_writes_table_summary_and_plots(tiny, tmp_path, capsys):
    out = tmp_path / "cli"
    argv = ["sweep", str(tiny), "--vary", "plant.effects.delay_s=0:2e-4:2", "--out", str(out)]
    assert main([*argv, "--workers", "0", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "2 of 2 runs done, 2 ok, 0 failed" in printed
    for name in ("sweep_table.csv", "sweep_table.parquet", "sweep_summary.json",
                 "sweep_summary.txt", "sweep_worst.png", "sweep_scatter.png"):  # fmt: skip
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "sweep_summary.json").read_text())
    assert summary["n_ok"] == 2 and summary["columns"]["y_rms_max"]["worst_is"] == "max"
    assert not list(out.rglob(".*.tmp*"))  # atomic writers leave nothing behind


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--vary", "plant.effects.delay_s=uniform(0,1"], "plant.effects.delay_s: expected SPEC"),
        (["--vary", "plant.effects.delay_s=uniform(0,1e-4)"], "needs --runs N"),
        (["--vary", "evaluate.plots=[false]"], r"no \[evaluate\] table"),
        (
            ["--vary", "scenario.seed=[1]", "--workers", "2", "--scheduler", "tcp://x:1"],
            "--workers",
        ),
    ],
    ids=["bad-spec", "no-runs", "no-table", "workers-and-scheduler"],
)
def test_cli_bad_input_is_exit_2_and_one_line(tiny, tmp_path, capsys, extra, match):
    import re

    assert main(["sweep", str(tiny), "--out", str(tmp_path / "o"), *extra]) == 2
    assert re.search(match, one_line(capsys.readouterr().err))


# ------------------------------------------------------------------ [design] controllers
@pytest.fixture(scope="module")
def controller_file(tmp_path_factory) -> Path:
    """The experiment's default decentralized PID for the stage (100 Hz), as a spec-5 file."""
    import plants
    from workbench.experiments import default_controller
    from workbench.io.formats import save_controller

    path = tmp_path_factory.mktemp("k") / "results" / "controller_pid.npz"
    path.parent.mkdir()
    save_controller(path, default_controller(plants.wafer_stage(), crossover_hz=100.0))
    return path


def fixed_controller_scenario(folder: Path, controller: Path) -> Path:
    path = folder / "fixed.toml"
    path.write_text(
        f'[scenario]\nname = "fixed"\nresults = "{folder / "results_fixed"}"\n'
        '[plant]\nname = "wafer_stage"\n'
        f'[design]\ncontrollers = {{ pid = "{os.path.relpath(controller, folder)}" }}\n'
        '[evaluate]\nbaseline = "pid"\nscan = false\nplots = false\n'
    )
    return path


def test_design_reads_controller_files_and_evaluate_judges_them(tmp_path, controller_file):
    from controllers.protocol import StateSpaceController
    from workbench.testing import assert_stable

    path = fixed_controller_scenario(controller_file.parent.parent, controller_file)
    scenario = load_scenario(path)
    assert sweep_settings(scenario).figures[0].name == "stable"  # [evaluate]: per-design figures
    assert main(["run", str(path), "--results", str(tmp_path / "r"), "--quiet"]) == 0
    evaluation = json.loads((tmp_path / "r" / "evaluation.json").read_text())
    assert list(evaluation["designs"]) == ["pid"] and evaluation["scan"] is None
    assert evaluation["designs"]["pid"]["tracking"] is None
    # the figure is the controller file's on the nominal stage
    import plants

    stable = evaluation["designs"]["pid"]["analysis"]["stable"]
    assert stable is True
    assert_stable(plants.wafer_stage(), StateSpaceController.read(controller_file))
    assert not list((tmp_path / "r").glob("*.png"))  # plots = false


def test_missing_controller_file_names_the_run_that_writes_it(tmp_path, capsys, controller_file):
    folder = tmp_path / "scenarios"
    folder.mkdir()
    # a scenario beside it whose results folder is where the controller should be
    (folder / "maker.toml").write_text(
        f'[scenario]\nname = "maker"\nresults = "{tmp_path / "made"}"\n[design]\n'
    )
    path = fixed_controller_scenario(folder, tmp_path / "made" / "controller_pid.npz")
    assert main(["run", str(path), "--results", str(tmp_path / "r"), "--quiet"]) == 2
    line = one_line(capsys.readouterr().err)
    assert "controllers.pid" in line and "no such file" in line
    assert "workbench run" in line and "maker.toml" in line


def test_robustness_scenario_plans_the_motivating_sweep():
    """The robustness scenario: +-5 % mode frequencies, damping x0.5-2, delay 0-2 samples."""
    scenario = load_scenario(
        Path(__file__).resolve().parents[1] / "scenarios/wafer_stage_robustness.toml"
    )
    settings = sweep_settings(scenario)
    plan = plan_sweep(scenario, settings.varies, runs=settings.runs)
    values = [dict(v.overrides) for v in plan]
    f = np.array([v["plant.effects.mode_freq_error"] for v in values])
    z = np.array([v["plant.effects.mode_damping_error"] for v in values])
    d = np.array([v["plant.effects.delay_s"] for v in values])
    fs = 5000.0  # the stage's sample rate (plants.wafer_stage.StageConfig.fs)
    assert f.shape == z.shape == (len(plan), 2)
    assert np.all(np.abs(f) <= 0.05) and np.all((1 + z >= 0.5) & (1 + z <= 2.0))
    assert np.all((d >= 0) & (d <= 2 / fs))
    assert {f.name for f in settings.figures} >= {"stable", "s_peak_max"}


def test_docstring_examples():
    import doctest

    import workbench.sweep.figures
    import workbench.sweep.spec

    for module in (workbench.sweep.spec, workbench.sweep.figures):
        result = doctest.testmod(module)
        assert result.attempted > 0 and result.failed == 0, module.__name__


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (from /proc: each process's parent)."""
    parent = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            parent[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out += kids
        todo += kids
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_killed_worker_loses_no_finished_row_and_the_rerun_does_only_the_rest(tiny, tmp_path):
    """SIGKILL to one pool worker mid-sweep: exit 1, the finished rows stay (whole JSON files),
    and the same command afterwards runs only the variations without a row."""
    import signal
    import subprocess
    import sys
    import time

    # longer runs (4000-sample records, ~0.3 s) so the sweep is still going when a worker dies
    text = tiny.read_text().replace("n_samples = 200", "n_samples = 4000")
    tiny.write_text(text)
    out = tmp_path / "sweep"
    argv = [sys.executable, "-m", "workbench", "sweep", str(tiny), "--workers", "2", "--quiet",
            "--vary", "plant.effects.delay_s=0:4e-4:24", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rows = out / "rows"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list(rows.glob("*.json"))) < 2:
        time.sleep(0.05)
    assert proc.poll() is None, "the sweep ended before a worker could be killed"
    # the pool's workers: forked by the forkserver (they carry its command line), no children;
    # not multiprocessing's resource tracker, the other helper process below the sweep
    tree = _descendants(proc.pid)

    def cmdline(pid):
        try:
            return (Path("/proc") / str(pid) / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            return ""

    workers = [p for p in tree if not _descendants(p) and "forkserver" in cmdline(p)]
    assert workers, tree
    os.kill(workers[0], signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    assert "worker process died" in err and "Traceback" not in err
    kept = {p.name: p.stat().st_mtime_ns for p in rows.glob("*.json")}
    assert 2 <= len(kept) < 24
    for p in rows.glob("*.json"):  # whole files only: the parent writes rows atomically
        assert json.loads(p.read_text())["status"] == "ok"
    assert not list(rows.glob(".*"))  # no temporary file left behind
    again = subprocess.run(argv[:6] + ["0"] + argv[7:], capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert len(list(rows.glob("*.json"))) == 24
    assert {p.name: p.stat().st_mtime_ns for p in rows.glob("*.json") if p.name in kept} == kept
