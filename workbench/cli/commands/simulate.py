"""``workbench simulate PLANT_OR_SCENARIO --out FILE``: record a simulated experiment.

The first argument is a plant name (``plants.get_plant(name)``, e.g.
``wafer_stage``) or a scenario ``.toml`` file whose ``[plant]`` table
(``name`` plus effect fields) and ``[experiment]`` table
(:class:`workbench.experiments.ExperimentConfig`) are used. The record is
written atomically in the spec's time format (TimeData: ``u``, ``y``, and
``r``, ``loop``, ``period`` as the experiment has them).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from workbench.core.atomic import check_not_input
from workbench.core.errors import InputError
from workbench.io.formats import save_measurement

_KIND_NAMES = {
    "closed-loop-multisine": "closed_loop_multisine",
    "open-loop-multisine": "open_loop_multisine",
    "noise": "noise",
    "step": "step",
}


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "simulate",
        help="simulate an experiment on a plant and write the measurement file",
        description=(
            "Simulate an open- or closed-loop experiment (multisine, noise, step) on a plant "
            "named by plants.get_plant, or as a scenario .toml's [plant] and [experiment] "
            "tables describe it, and write the record (spec 1a) atomically. Default for a "
            "plant name: the closed-loop multisine record (10,000 samples at 5 kHz on the "
            "wafer stage, period 2000)."
        ),
    )
    p.add_argument("source", metavar="PLANT_OR_SCENARIO", help="plant name or scenario .toml")
    p.add_argument("--out", required=True, help="output measurement .npz")
    p.add_argument("--seed", type=int, default=None, help="seed (default: scenario seed, or 0)")
    g = p.add_argument_group("experiment (with a plant name; a scenario's [experiment] wins)")
    g.add_argument("--experiment", choices=sorted(_KIND_NAMES), default="closed-loop-multisine")
    g.add_argument("--n-samples", type=int, default=None, help="record length, samples")
    g.add_argument("--period", type=int, default=None, help="multisine period, samples")
    g.add_argument("--periods", type=int, default=5, help="periods per block (first = transient)")
    g.add_argument("--n-exp", type=int, default=None, help="multisine experiments")
    g.add_argument("--realizations", type=int, default=1, help="multisine realizations")
    g.add_argument("--band-hz", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"))
    g.add_argument("--rms", type=float, default=None, help="excitation rms (N), all inputs")
    g.add_argument("--lines", choices=("random_odd", "odd", "full"), default="random_odd")
    g.add_argument("--design", choices=("independent", "orthogonal"), default="independent")
    g.add_argument("--loop", choices=("open", "closed"), default=None, help="noise/step loop")
    g.add_argument("--crossover-hz", type=float, default=None, help="controller crossover, Hz")
    return p


def _get_plant(name: str, config: dict):
    from plants import get_plant

    try:
        return get_plant(name, **config)
    except TypeError as exc:
        raise InputError(f"[plant] '{name}': {exc}") from None


def run(args) -> int:
    from workbench.experiments import ExperimentConfig, run_experiment

    source = args.source
    check_not_input(args.out, [source] if source.endswith(".toml") else [])
    if source.endswith(".toml"):
        from workbench.io.scenario import load_scenario

        scenario = load_scenario(source)
        check_not_input(args.out, [source])
        plant_table = scenario.table("plant")
        if "name" not in plant_table:
            raise InputError(f"{source}: [plant] needs a key 'name' (e.g. \"wafer_stage\")")
        name = plant_table.pop("name")
        plant = _get_plant(str(name), plant_table)
        if not scenario.has("experiment"):
            raise InputError(f"{source}: missing table [experiment] (kind, ...)")
        config = ExperimentConfig.from_table(scenario.table("experiment"))
        seed = scenario.seed if args.seed is None else args.seed
    else:
        if Path(source).suffix:
            raise InputError(f"{source}: expected a plant name or a scenario .toml file")
        plant = _get_plant(source, {})
        config = ExperimentConfig(
            kind=_KIND_NAMES[args.experiment],
            n_samples=args.n_samples,
            period=args.period,
            periods=args.periods,
            band_hz=None if args.band_hz is None else tuple(args.band_hz),
            rms=args.rms,
            lines=args.lines,
            design=args.design,
            n_exp=args.n_exp,
            n_realizations=args.realizations,
            loop=args.loop,
            crossover_hz=args.crossover_hz,
        )
        seed = 0 if args.seed is None else args.seed
    data = run_experiment(plant, config, rng=np.random.default_rng(seed))
    save_measurement(args.out, data)
    period = f", period {data.period}" if data.period else ""
    print(
        f"wrote {args.out}: {data.loop}-loop {config.kind}, {data.n_samples} samples at "
        f"{data.fs:g} Hz, {data.n_u} inputs, {data.n_y} outputs{period}"
    )
    return 0
