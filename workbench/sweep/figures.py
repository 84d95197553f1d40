"""What a sweep collects from each run (:class:`Figure`) and the ``[sweep]`` table.

See :mod:`workbench.sweep` for the ``FILE:KEY`` syntax, the reducers and the defaults.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from workbench.core.errors import InputError
from workbench.io.scenario import Scenario, refuse_leftovers, take
from workbench.sweep.spec import Vary, parse_vary

__all__ = [
    "EVALUATE_FIGURES",
    "Figure",
    "Settings",
    "collect_figures",
    "parse_figure",
    "sweep_settings",
]

EVALUATE_FIGURES = {
    "stable": "evaluation.json:designs.*.analysis.stable",
    "s_peak_max": "max(evaluation.json:designs.*.analysis.loops.*.s_peak)",
    "sigma_s_max": "evaluation.json:designs.*.analysis.sigma_max_S_inf",
    "scaled_sigma_s_max": "evaluation.json:designs.*.analysis.scaled_sigma_max_S_inf",
    "crossover_min_hz": "min(evaluation.json:designs.*.analysis.loops.*.crossover_hz)",
    "pole_radius_max": "evaluation.json:designs.*.analysis.max_pole_radius",
}
#: modules the forkserver imports once, so that no worker imports them per process


# ------------------------------------------------------------------ figures
@dataclass(frozen=True)
class Figure:
    """A collected figure: column ``name`` from ``FILE:KEY`` of each run's folder.

    ``path`` is KEY split on dots (``*`` any key or list index, ``**`` every scalar leaf);
    ``reduce`` (``max``, ``min``, ``mean`` or None) reduces over the last ``*``.
    """

    name: str
    source: str
    file: str
    path: tuple[str, ...]
    reduce: str | None = None


def parse_figure(name: str, text: str) -> Figure:
    """``[sweep.collect] name = "[max(]FILE:KEY[)]"`` as a :class:`Figure`.

    Examples
    --------
    >>> f = parse_figure("s_peak_max", "max(evaluation.json:designs.*.analysis.loops.*.s_peak)")
    >>> f.file, f.path[:2], f.reduce
    ('evaluation.json', ('designs', '*'), 'max')
    """
    where = f"[sweep.collect] key '{name}'"
    if not isinstance(text, str):
        raise InputError(f'{where}: expected "FILE:KEY" or "max(FILE:KEY)", got {text!r}')
    m = re.fullmatch(r"\s*(?:(max|min|mean)\((.*)\)|(.*?))\s*", text)
    reduce, inner = (m[1], m[2]) if m[1] else (None, m[3])
    file, sep, key = inner.partition(":")
    if not sep or not file.endswith(".json") or not key or "" in key.split("."):
        raise InputError(
            f"{where}: expected FILE:KEY (a JSON file of the run's folder and a dotted key, "
            f"e.g. evaluation.json:designs.*.analysis.stable), optionally in max(), min() or "
            f"mean(), got {text!r}"
        )
    path = tuple(key.split("."))
    if "**" in path and (path != ("**",) or reduce):
        raise InputError(f"{where}: '**' stands alone (FILE:**), without a reducer; got {text!r}")
    if not re.fullmatch(r"[\w-]*", name):
        raise InputError(f"{where}: expected a column name of letters, digits, _ and -")
    return Figure(name=name, source=text, file=file, path=path, reduce=reduce)


def _walk(node, path: tuple[str, ...], matched: tuple[str, ...] = ()):
    """(wildcard matches, value) of every leaf of ``node`` that ``path`` addresses."""
    if not path:
        yield matched, node
        return
    part, rest = path[0], path[1:]
    if isinstance(node, dict):
        items = node.items() if part == "*" else ((part, node[part]),) if part in node else ()
    elif isinstance(node, list):
        if part == "*":
            items = ((str(i), v) for i, v in enumerate(node))
        elif part.isdigit() and int(part) < len(node):
            items = ((part, node[int(part)]),)
        else:
            items = ()
    else:
        items = ()
    for k, v in items:
        yield from _walk(v, rest, matched + (k,) if part == "*" else matched)


def _leaves(node, prefix: tuple[str, ...] = ()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _leaves(v, prefix + (str(k),))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _leaves(v, prefix + (str(i),))
    elif isinstance(node, bool | int | float):
        yield prefix, node


def _scalar(v):
    """A figure value: bool, int or float; non-finite strings as floats; else None."""
    if isinstance(v, bool | int):
        return v
    if isinstance(v, float):
        return v if not math.isnan(v) else None
    if isinstance(v, str) and v.strip().lower() in ("inf", "+inf", "-inf", "infinity"):
        return float(v.strip().lower().replace("infinity", "inf"))
    return None


def _reduce(how: str, values: list):
    values = [v for v in (_scalar(x) for x in values) if v is not None]
    if not values:
        return None
    if how == "mean":
        return float(np.mean([float(v) for v in values]))
    return max(values) if how == "max" else min(values)


def collect_figures(run_dir: str | os.PathLike, figures: Sequence[Figure]) -> dict[str, Any]:
    """The figures of one finished run, {column: bool / int / float / None}."""
    run_dir = Path(run_dir)
    docs: dict[str, Any] = {}
    out: dict[str, Any] = {}
    for fig in figures:
        if fig.file not in docs:
            p = run_dir / fig.file
            docs[fig.file] = json.loads(p.read_text()) if p.is_file() else None
        doc = docs[fig.file]
        if doc is None:
            continue
        prefix = [fig.name] if fig.name else []
        if fig.path == ("**",):
            for parts, v in _leaves(doc):
                if fig.file == "summary.json" and parts[0] == "scenario":
                    continue  # the run's name, seed and timings: not figures
                out[".".join(prefix + list(parts))] = _scalar(v)
            continue
        found = list(_walk(doc, fig.path))
        if fig.reduce is None:
            for parts, v in found:
                out[".".join(prefix + list(parts))] = _scalar(v)
            continue
        groups: dict[tuple, list] = {}
        for parts, v in found:
            group = parts[:-1] if "*" in fig.path else parts
            groups.setdefault(group, []).extend(v if isinstance(v, list) else [v])
        for group, values in groups.items():
            out[".".join(prefix + list(group))] = _reduce(fig.reduce, values)
    return out


# ------------------------------------------------------------------ settings and plan
@dataclass(frozen=True)
class Settings:
    """A scenario's ``[sweep]`` table: default variations, runs, figures, gate."""

    varies: tuple[Vary, ...]
    runs: int | None
    figures: tuple[Figure, ...]
    gate: str


def sweep_settings(scenario: Scenario) -> Settings:
    """Parse the scenario's ``[sweep]`` table (unknown keys refused).

    ``vary`` a list of ``"KEY=SPEC"``; ``runs`` the Monte-Carlo draws; ``[sweep.collect]``
    {column: FILE:KEY} (default :data:`EVALUATE_FIGURES` with an ``[evaluate]`` stage, else
    ``summary.json:**``); ``gate`` the boolean figure that gates the worst values
    (default ``stable``).
    """
    table = dict(scenario.tables.get("sweep", {}))
    vary = take(table, "vary", [], where="sweep", kind=list)
    runs = take(table, "runs", None, where="sweep", kind=int)
    collect = take(table, "collect", None, where="sweep", kind=dict)
    gate = take(table, "gate", "stable", where="sweep", kind=str)
    refuse_leftovers(table, where="sweep")
    if not all(isinstance(v, str) for v in vary):
        raise InputError(
            f"[sweep] key 'vary': expected a list of \"KEY=SPEC\" strings, got {vary!r}"
        )
    if runs is not None and runs < 1:
        raise InputError(f"[sweep] key 'runs': expected an integer >= 1, got {runs}")
    if collect is None:
        collect = EVALUATE_FIGURES if scenario.has("evaluate") else {"": "summary.json:**"}
    if not collect:
        raise InputError('[sweep.collect]: expected at least one column = "FILE:KEY"')
    return Settings(
        varies=tuple(parse_vary(v, where="[sweep] vary") for v in vary),
        runs=runs,
        figures=tuple(parse_figure(k, v) for k, v in collect.items()),
        gate=gate,
    )
