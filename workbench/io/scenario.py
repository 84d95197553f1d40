"""Scenario files: every result of the workbench can be regenerated from one.

A scenario is a TOML file with a ``[scenario]`` table (name, seed, results
folder) and one table per stage of the pipeline, run in this order when
present::

    [plant]        which true system, with which physical effects
    [experiment]   what experiment to run on it (workbench.experiments)
    [frf]          FRF estimation from the recorded data
    [identify]     subspace identification (workbench.ident)
    [modes]        modal analysis of the identified model
    [minimality]   minimality report
    [model]        a user's (nominal) model to check against the data
    [compare], [diagnose], [augment]   the model-versus-measurement loop
    [modalfit], [update], [predict]    modal fit, FE model updating, prediction at
                   sensors held out (seed 001)
    [design]       controllers designed on the identified modal model
    [evaluate]     every design on the true plant: loop figures, scan tracking
    [inferential]  the beam's unmeasured point: inferential vs conventional control

and ``[regress]`` (tolerances of ``workbench regress``) and ``[sweep]`` (default
variations of ``workbench sweep``, :mod:`workbench.sweep`), which run no stage.

Unknown tables and keys are refused with one line, so a typo never silently
changes an experiment.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workbench.core.errors import InputError

STAGES = (
    "plant",
    "experiment",
    "frf",
    "identify",
    "modes",
    "minimality",
    "model",
    "compare",
    "diagnose",
    "augment",
    "modalfit",
    "update",
    "predict",
    "design",
    "evaluate",
    "inferential",
)
#: tables that configure a command rather than run a stage (``[regress]``: workbench regress,
#: ``[sweep]``: workbench sweep)
SETTINGS_TABLES = ("regress", "sweep")


@dataclass(frozen=True)
class Scenario:
    """A parsed scenario file.

    Parameters
    ----------
    name : str
    seed : int
        Seed of the one ``np.random.Generator`` the whole run draws from.
    results : Path
        Folder the run writes its JSON figures and PNG plots to.
    tables : dict
        The stage tables present, keyed by stage name.
    path : Path
        Where the scenario came from (relative paths resolve against its folder).
    """

    name: str
    seed: int
    results: Path
    tables: dict[str, dict[str, Any]] = field(default_factory=dict)
    description: str = ""
    path: Path | None = None

    def has(self, stage: str) -> bool:
        return stage in self.tables

    def table(self, stage: str) -> dict[str, Any]:
        return dict(self.tables.get(stage, {}))

    def resolve(self, relative: str | os.PathLike) -> Path:
        """A path named in the scenario, relative to the scenario's folder."""
        p = Path(relative)
        if p.is_absolute() or self.path is None:
            return p
        return (self.path.parent / p).resolve()


def load_scenario(path: str | os.PathLike, *, results: str | os.PathLike | None = None) -> Scenario:
    """Read and check a scenario file."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{path}: no such scenario file")
    try:
        raw = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML file ({exc})") from None
    head = raw.pop("scenario", None)
    if not isinstance(head, dict):
        raise InputError(f"{path}: missing table [scenario] (name, seed, results)")
    unknown = sorted(set(raw) - set(STAGES) - set(SETTINGS_TABLES))
    if unknown:
        raise InputError(
            f"{path}: unknown table [{unknown[0]}]; expected some of: "
            f"{', '.join(STAGES + SETTINGS_TABLES)}"
        )
    extra = sorted(set(head) - {"name", "seed", "results", "description"})
    if extra:
        raise InputError(f"{path}: [scenario] has unknown key '{extra[0]}'")
    seed = head.get("seed", 0)
    if not isinstance(seed, int) or seed < 0:
        raise InputError(f"{path}: [scenario] key 'seed': expected an integer >= 0, got {seed!r}")
    name = str(head.get("name", p.stem))
    out = Path(results) if results is not None else Path(head.get("results", f"results/{name}"))
    for stage, table in raw.items():
        if not isinstance(table, dict):
            raise InputError(
                f"{path}: '{stage}' must be a table [{stage}], got {type(table).__name__}"
            )
    return Scenario(
        name=name,
        seed=seed,
        results=out,
        tables=raw,
        description=str(head.get("description", "")),
        path=p.resolve(),
    )


def take(table: dict[str, Any], key: str, default: Any, *, where: str, kind: type | tuple = object):
    """Pop ``key`` from a stage table with a type check (one-line error naming the table)."""
    value = table.pop(key, default)
    if value is not None and not isinstance(value, kind):
        raise InputError(f"[{where}] key '{key}': expected {kind}, got {value!r}")
    return value


def refuse_leftovers(table: dict[str, Any], *, where: str) -> None:
    """Unknown keys in a stage table are errors, not silently ignored settings."""
    if table:
        key = sorted(table)[0]
        raise InputError(f"[{where}] has unknown key '{key}'")
