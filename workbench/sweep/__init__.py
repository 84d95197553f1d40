"""Sweeps: one scenario run over a grid or a Monte-Carlo set of overridden keys.

Data flow::

    scenario.toml ([sweep] vary / runs / collect)  +  --vary KEY=SPEC ... --runs N
        ─► plan_sweep: grid product x Monte-Carlo draws ─► Variation(run_id, overrides)
        ─► every variation without a row (rows/<run_id>.json) runs, in a worker
           (local process pool, or a Dask cluster):
               run_scenario(scenario with the overrides) ─► runs/<run_id>/ (its own folder)
               collect_figures(runs/<run_id>/*.json) ─► row: status, seconds, figures
        ─► the PARENT writes rows/<run_id>.json atomically as each run completes
        ─► sweep_table.csv, sweep_table.parquet, sweep_summary.json / .txt and the
           sweep_*.png plots, rebuilt from the rows, atomically

**Keys.** ``KEY`` is a dotted scenario key: ``TABLE.key[.key ...]`` (``plant.effects.delay_s``,
``design.ms_max``, ``evaluate.scan.velocity``) or ``scenario.seed``. The table must be in the
scenario; a missing key is added (its type is checked by the stage when the run starts, so a
typo fails every run with the stage's one-line refusal as its status).

**SPEC.** A grid: ``a:b:n`` (n points from a to b, both included, ``numpy.linspace``) or a list
``[v1, v2, ...]`` (TOML values; bare words are strings). Several grid keys make a full product,
the first ``--vary`` the slowest. A distribution (Monte Carlo, ``--runs N`` draws):
``uniform(lo,hi)``, ``loguniform(lo,hi)`` (0 < lo: log-uniform, for scale factors),
``normal(mu,sigma)``, ``choice(a,b,...)``, optionally followed by ``+c`` or ``-c`` (an offset
added to every draw: ``loguniform(0.5,2)-1`` draws a damping *factor* 0.5 .. 2 and stores the
relative error ``factor - 1`` that ``Effects.mode_damping_error`` takes). With grids and
distributions together every grid point gets the same N draws.

**Draws.** Reproducible: the draws of a key come from
``np.random.default_rng([scenario seed, crc32(KEY)])`` through uniform doubles (normal by the
inverse CDF, choice by ``floor(u k)``), so the same command gives the same table, adding a
``--vary`` does not change another key's draws, and ``--runs 200`` keeps the first 100 runs of
``--runs 100`` (resumed, not redone). When the scenario gives the key a list (a per-mode tuple
such as ``mode_freq_error = [0.0, 0.0]``), every element is drawn independently; a scalar
default (or none) gets one value (which ``Effects`` applies to every mode). A grid value is
set as given (a scalar on a list key: the same value for every element).

**Runs and rows.** ``run_id`` = the first 12 hex digits of the SHA-256 of the base scenario
(tables and seed, without ``[sweep]`` / ``[regress]``) and the overrides: stable across
reruns and the order of ``--vary``. A run that fails is a row with ``status = "error: <the
one-line error>"``, never a crash of the sweep. The parent writes each row as its run
completes, so a killed worker or an interrupted sweep loses only the runs in flight; a rerun
of the same command skips every run_id whose row exists (``redo_failed`` reruns the failed
ones).

**Workers.** ``workers = 0``: in this process. Otherwise a ``ProcessPoolExecutor`` started by
``forkserver``: a fresh server process (started by exec, not a fork of this process and its
threads) imports the pipeline once, and every worker forks from it, so no worker imports
numpy, python-control, numba ... again; each worker runs at one BLAS thread (threadpoolctl), so
N workers use N cores. As with any spawn / forkserver pool, a script that calls
:func:`run_sweep` with workers needs the ``if __name__ == "__main__":`` guard (the command line
has it). ``scheduler = ADDRESS``: a Dask ``distributed`` cluster; rows come back to this
process, so the workers need not share its filesystem (their ``runs/`` folders then stay on
their machines). Dask reschedules the runs of a worker that dies; a run that kills its
workers repeatedly becomes a row with Dask's error.

Package layout::

    spec.py     KEY=SPEC -> Vary; plan_sweep -> Variation (run_id, overrides); apply_overrides
    figures.py  FILE:KEY -> Figure; collect_figures of a run folder; the [sweep] table
    runner.py   run_variation (in a worker), the executors, run_sweep
    report.py   the table (CSV, Parquet), the summary (JSON, text), the plots

**Figures.** ``[sweep.collect]`` maps a column name to ``FILE:KEY`` (the syntax of
``workbench regress``: a JSON file of the run's folder and a dotted key, list indices as
numbers, ``*`` any key or index), optionally inside ``max(...)``, ``min(...)`` or
``mean(...)``, which reduce over the LAST ``*``; every other ``*`` makes one column per match,
named ``name.<match>``. ``FILE:**`` takes every number / boolean leaf of the file (the
``scenario`` part of ``summary.json``, timings, skipped). Default: with an ``[evaluate]``
stage, per design (:data:`EVALUATE_FIGURES`) ``stable``, ``s_peak_max`` (worst |S_ii|inf over
the DOFs), ``sigma_s_max``, ``crossover_min_hz``, ``pole_radius_max``; otherwise
``summary.json:**``.

**Summary.** Per column group (the part after the figure's name, e.g. the design): boolean
figures give the share of runs where they are false (``stable``: the share unstable), numeric
ones min / median / max and the *worst* value (the max of a ``max(...)`` figure, the min of a
``min(...)`` one), taken over the runs where the group's gate figure (``[sweep] gate``,
default ``stable``) is true: an unstable loop's |S|inf is infinite, not its sampled peak.
"""

from workbench.sweep.figures import (
    EVALUATE_FIGURES,
    Figure,
    Settings,
    collect_figures,
    parse_figure,
    sweep_settings,
)
from workbench.sweep.runner import SweepResult, SweepStopped, run_sweep, run_variation
from workbench.sweep.spec import Variation, Vary, apply_overrides, parse_vary, plan_sweep

__all__ = [
    "EVALUATE_FIGURES",
    "Figure",
    "Settings",
    "SweepResult",
    "SweepStopped",
    "Variation",
    "Vary",
    "apply_overrides",
    "collect_figures",
    "parse_figure",
    "parse_vary",
    "plan_sweep",
    "run_sweep",
    "run_variation",
    "sweep_settings",
]
