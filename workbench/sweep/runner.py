"""Running a sweep: one variation in a worker (:func:`run_variation`), the executors (this
process, a local process pool, a Dask cluster) and :func:`run_sweep`, which writes each row as
its run completes and rebuilds the outputs (:mod:`workbench.sweep.report`) at the end.
"""

from __future__ import annotations

import json
import os
import sys
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from workbench.core import atomic
from workbench.core.errors import InputError
from workbench.core.jsonutil import jsonable
from workbench.io.scenario import Scenario
from workbench.sweep.figures import Figure, collect_figures, sweep_settings
from workbench.sweep.report import write_outputs
from workbench.sweep.spec import Variation, Vary, apply_overrides, plan_sweep

__all__ = ["SweepResult", "SweepStopped", "run_sweep", "run_variation"]


class SweepStopped(RuntimeError):
    """A worker process of the local pool died (killed, out of memory): the sweep stopped.

    Not an input error (the CLI exits 1 with this one line): the rows of the finished runs are
    kept and the same command resumes. (A RuntimeError, not a workbench.core.errors class: those
    are the refusals of user input and data.)
    """


_PRELOAD = [
    "workbench.sweep",
    "workbench.cli.pipeline",
    "workbench.cli.design_stages",
    "workbench.loop",
    "workbench.sim",
    "workbench.compiled",
    "workbench._kernels",  # numba itself (0.5 s); each kernel still loads its cache on first call
    "workbench.experiments",
    "workbench.scan",
    "workbench.io.formats",
    "plants",
    "controllers.protocol",
    "control",
    "matplotlib.figure",
    "matplotlib.backends.backend_agg",
]


# ------------------------------------------------------------------ one run (in a worker)
def run_variation(
    scenario: Scenario,
    overrides: tuple[tuple[str, Any], ...],
    run_dir: str,
    figures: tuple[Figure, ...],
) -> dict[str, Any]:
    """Run one variation into ``run_dir``; its row (status, seconds, figures, warnings).

    Never raises for a failing run: the failure is the row's ``status``
    (``"error: <one line>"``; an internal error keeps its traceback in ``traceback``).
    """
    import traceback

    from workbench.cli.pipeline import run_scenario

    t0, c0 = time.perf_counter(), time.process_time()
    row: dict[str, Any] = {"status": "ok", "figures": {}}
    # the run's warnings belong to its row (a worker's stderr is nobody's terminal)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            run_scenario(apply_overrides(scenario, overrides, results=run_dir), progress=False)
            row["figures"] = collect_figures(run_dir, figures)
        except InputError as exc:
            row["status"] = f"error: {exc}"
        except Exception as exc:  # a failing variation is a result, not a crash of the sweep
            row["status"] = f"error: {type(exc).__name__}: {' '.join(str(exc).split())}"
            row["traceback"] = traceback.format_exc()
    row["seconds"] = time.perf_counter() - t0
    row["cpu_seconds"] = time.process_time() - c0  # without the waits for a busy core
    lines = dict.fromkeys(
        f"{w.category.__name__}: {' '.join(str(w.message).split())}" for w in caught
    )
    row["warnings"] = list(lines)[:5]
    row["worker"] = f"{os.uname().nodename}:{os.getpid()}"
    return row


# ------------------------------------------------------------------ executors
def _limit_blas() -> None:
    """One BLAS thread in this process: N workers use N cores, not N x cores threads."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def _init_worker() -> None:
    import signal

    # Ctrl-C goes to the whole process group: the parent decides (keeps the finished rows,
    # stops the pool); a worker must not die mid-write on its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _limit_blas()


def _in_process(tasks) -> Iterator[tuple[Variation, Any]]:
    for v, args in tasks:
        yield v, run_variation(*args)


def _local_pool(tasks, workers: int) -> Iterator[tuple[Variation, Any]]:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if ctx.get_start_method() == "forkserver":
        ctx.set_forkserver_preload(_PRELOAD)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker)
    finished = False
    try:
        futures = {pool.submit(run_variation, *args): v for v, args in tasks}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()  # BrokenProcessPool: a worker died
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:  # interrupted or broken: drop the queue, stop the runs in flight
            processes = list((getattr(pool, "_processes", None) or {}).values())  # no public handle
            pool.shutdown(wait=False, cancel_futures=True)
            for p in processes:
                if p.is_alive():
                    p.terminate()
            for p in processes:
                p.join(timeout=10)
            pool.shutdown(wait=True)  # the pool's own thread and queues, now that no run is left


def _dask(tasks, scheduler: str) -> Iterator[tuple[Variation, Any]]:
    try:
        from distributed import Client, as_completed
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise InputError(f"--scheduler: needs the 'distributed' package ({exc})") from None
    try:
        client = Client(scheduler, set_as_default=False, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(
            f"--scheduler {scheduler}: cannot connect to a Dask scheduler there ({exc})"
        ) from None
    futures: dict = {}
    try:
        client.run(_limit_blas)
        for v, args in tasks:
            futures[client.submit(run_variation, *args, pure=False)] = v
        for fut in as_completed(list(futures), loop=client.loop):
            try:
                result = fut.result()
            except Exception as exc:  # KilledWorker after Dask's retries: that run's result
                result = {
                    "status": f"error: {type(exc).__name__}: {' '.join(str(exc).split())}",
                    "figures": {},
                    "seconds": float("nan"),
                    "warnings": [],
                }
            yield futures[fut], result
    finally:
        client.cancel([f for f in futures if not f.done()])
        client.close()


# ------------------------------------------------------------------ the sweep
@dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` did and wrote.

    Attributes
    ----------
    out : Path
        The sweep's folder.
    rows : tuple of dict
        The finished runs' rows, in plan order.
    n_planned, n_resumed, n_run, n_failed : int
        Runs of the plan; found done (rows kept); run now; rows with an error status.
    wall_s : float
        Wall time of this call, s.
    summary : dict
        ``sweep_summary.json``.
    text : str
        ``sweep_summary.txt``: the per-group table.
    files : tuple of str
        Files written in ``out`` (besides rows/ and runs/).
    """

    out: Path
    rows: tuple[dict, ...]
    n_planned: int
    n_resumed: int
    n_run: int
    n_failed: int
    wall_s: float
    summary: dict
    text: str
    files: tuple[str, ...]


def run_sweep(
    scenario: Scenario,
    *,
    varies: Sequence[Vary] | None = None,
    runs: int | None = None,
    out: str | os.PathLike | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    redo_failed: bool = False,
    progress: bool = False,
) -> SweepResult:
    """Run every variation of a sweep not yet done; rebuild the table, summary and plots.

    Parameters
    ----------
    scenario : Scenario
        The base scenario (its ``[sweep]`` table gives defaults).
    varies : sequence of Vary, optional
        Replace the ``[sweep] vary`` list.
    runs : int, optional
        Monte-Carlo draws (replaces ``[sweep] runs``).
    out : path, optional
        The sweep's folder; default ``<scenario results>/sweep``.
    workers : int, optional
        Local worker processes; 0 = in this process; default every core.
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``): run there instead.
    redo_failed : bool
        Rerun the variations whose row has an error status.
    progress : bool
        A tqdm bar on stderr (shown only when stderr is a terminal).

    Returns
    -------
    SweepResult
    """
    settings = sweep_settings(scenario)
    varies = tuple(varies) if varies else settings.varies
    if runs is None and any(not v.is_grid for v in varies):
        runs = settings.runs  # [sweep] runs: the draws of whichever distributions are varied
    plan = plan_sweep(scenario, varies, runs=runs)
    if scheduler is not None and workers is not None:
        raise InputError("--workers: not with --scheduler (the Dask cluster has its own workers)")
    if workers is not None and workers < 0:
        raise InputError(f"--workers: expected an integer >= 0, got {workers}")
    if workers is None:
        workers = _cores()
    out = Path(out) if out is not None else Path(scenario.results) / "sweep"
    rows_dir, runs_dir = out / "rows", out / "runs"
    rows_dir.mkdir(parents=True, exist_ok=True)
    done: dict[str, dict] = {}
    for v in plan:
        row = _read_row(rows_dir / f"{v.run_id}.json")
        if row is not None and not (redo_failed and row["status"] != "ok"):
            done[v.run_id] = row
    n_resumed = len(done)
    todo = [v for v in plan if v.run_id not in done]
    tasks = [
        (v, (scenario, v.overrides, str((runs_dir / v.run_id).resolve()), settings.figures))
        for v in todo
    ]
    t0 = time.perf_counter()
    if scheduler is not None:
        results = _dask(tasks, scheduler)
    elif workers == 0 or len(tasks) <= 1:
        results = _in_process(tasks)
    else:
        results = _local_pool(tasks, min(workers, len(tasks)))
    from tqdm import tqdm

    bar = tqdm(
        total=len(plan), initial=n_resumed, unit="run", file=sys.stderr,
        disable=not (progress and sys.stderr.isatty()), desc=f"sweep {scenario.name}",
    )  # fmt: skip
    n_failed = sum(r["status"] != "ok" for r in done.values())
    broken = None
    try:
        for v, result in results:
            row = {"run_id": v.run_id, "overrides": dict(v.overrides), **result}
            text = json.dumps(jsonable(row))
            atomic.write_text(rows_dir / f"{v.run_id}.json", text + "\n")
            done[v.run_id] = json.loads(text)  # the row as a resumed sweep reads it back
            n_failed += row["status"] != "ok"
            bar.update(1)
            bar.set_postfix(failed=n_failed, refresh=False)
    except Exception as exc:
        from concurrent.futures.process import BrokenProcessPool

        if not isinstance(exc, BrokenProcessPool):
            raise
        broken = exc
    finally:
        bar.close()
        results.close()
        rows = tuple(done[v.run_id] for v in plan if v.run_id in done)
        files, summary, text = write_outputs(out, scenario, plan, varies, rows, settings)
    if broken is not None:
        raise SweepStopped(
            f"sweep stopped: a worker process died ({len(rows)} of {len(plan)} runs done, their "
            f"rows kept in {rows_dir}); run the same command again to resume"
        ) from broken
    return SweepResult(
        out=out, rows=rows, n_planned=len(plan), n_resumed=n_resumed,
        n_run=len(rows) - n_resumed, n_failed=sum(r["status"] != "ok" for r in rows),
        wall_s=time.perf_counter() - t0, summary=summary, text=text, files=files,
    )  # fmt: skip


def _cores() -> int:
    """Cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _read_row(path: Path) -> dict | None:
    """A finished run's row, or None (absent or unreadable: the run is not done)."""
    try:
        row = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return row if isinstance(row, dict) and "status" in row else None
