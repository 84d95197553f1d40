"""The sweep's grammar and plan: ``KEY=SPEC`` -> :class:`Vary`; varies -> :class:`Variation` s.

See :mod:`workbench.sweep` for the grammar, the draws and the run ids.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
import math
import os
import re
import tomllib
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from workbench.core.errors import InputError
from workbench.io.scenario import SETTINGS_TABLES, STAGES, Scenario

__all__ = ["Variation", "Vary", "apply_overrides", "parse_vary", "plan_sweep"]

DISTRIBUTIONS = ("uniform", "loguniform", "normal", "choice")
SPEC_HELP = (
    "a:b:n, [v1, v2, ...], uniform(lo,hi), loguniform(lo,hi), normal(mu,sigma) or "
    "choice(a,b,...), a distribution optionally followed by +c or -c"
)
#: the figures collected from a scenario with an [evaluate] stage, one column per design
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf"
_KEY = re.compile(r"[A-Za-z_][\w-]*(?:\.[\w-]+)+")


# ------------------------------------------------------------------ the grammar
@dataclass(frozen=True)
class Vary:
    """One ``--vary KEY=SPEC``: a grid (``values``) or a distribution (``dist``, ``params``).

    Parameters
    ----------
    key : str
        Dotted scenario key (``plant.effects.delay_s``, ``scenario.seed``).
    spec : str
        The SPEC as given (for messages and the summary).
    values : tuple
        Grid points (a grid); empty for a distribution.
    dist : str or None
        ``uniform``, ``loguniform``, ``normal`` or ``choice``; None for a grid.
    params : tuple
        (lo, hi), (mu, sigma) or the choices.
    offset : float
        Added to every draw (``-1`` of ``loguniform(0.5,2)-1``).
    """

    key: str
    spec: str
    values: tuple = ()
    dist: str | None = None
    params: tuple = ()
    offset: float = 0.0

    @property
    def is_grid(self) -> bool:
        return self.dist is None

    def transform(self, u: np.ndarray) -> list:
        """Draws from uniform doubles ``u`` in [0, 1), any shape: a nested list of values."""
        if self.dist == "choice":
            k = np.minimum((u * len(self.params)).astype(int), len(self.params) - 1)
            out = np.empty(u.shape, dtype=object)
            for idx, j in np.ndenumerate(k):
                c = self.params[j]
                out[idx] = c + self.offset if self.offset and _is_number(c) else c
            return out.tolist()
        a, b = self.params
        if self.dist == "uniform":
            x = a + (b - a) * u
        elif self.dist == "loguniform":
            x = np.exp(np.log(a) + (np.log(b) - np.log(a)) * u)
        else:  # normal: the inverse CDF of the uniform draw (one double per value)
            from scipy.special import ndtri

            x = a + b * ndtri(np.clip(u, 2.0**-53, 1.0 - 2.0**-53))
        return (x + self.offset).tolist()


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _split_top(text: str) -> list[str]:
    """Split on commas outside brackets and quotes."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(text):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts]


def _value(text: str, where: str):
    """A TOML value (number, "string", true, [list]); a bare word is a string."""
    text = text.strip()
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        pass
    if re.fullmatch(_NUMBER, text):
        return float(text)
    if text.startswith("[") and text.endswith("]"):
        inner = text[1:-1].strip()
        return [_value(p, where) for p in _split_top(inner)] if inner else []
    if re.fullmatch(r"[A-Za-z_][\w.+-]*", text):
        return text
    raise InputError(f"{where}: expected a number, a string or a [list], got {text!r}")


def parse_vary(text: str, *, where: str = "--vary") -> Vary:
    """Parse ``KEY=SPEC`` (see the module docstring for the grammar).

    Raises
    ------
    InputError
        One line naming the key and what was expected.

    Examples
    --------
    >>> parse_vary("design.ms_max=1.5:2.5:3").values
    (1.5, 2.0, 2.5)
    >>> v = parse_vary("plant.effects.mode_damping_error=loguniform(0.5,2)-1")
    >>> v.dist, v.params, v.offset
    ('loguniform', (0.5, 2.0), -1.0)
    """
    if "=" not in text:
        raise InputError(
            f"{where} {text!r}: expected KEY=SPEC, e.g. plant.effects.delay_s=0:4e-4:3"
        )
    key, spec = (s.strip() for s in text.split("=", 1))
    where = f"{where} {key}"
    if not _KEY.fullmatch(key):
        raise InputError(
            f"{where}: expected a dotted scenario key TABLE.key (e.g. plant.effects.delay_s, "
            f"scenario.seed), got {key!r}"
        )
    head = key.split(".")[0]
    if head == "scenario":
        if key != "scenario.seed":
            raise InputError(f"{where}: of [scenario] only 'scenario.seed' can vary, got {key!r}")
    elif head not in STAGES:
        raise InputError(
            f"{where}: expected a key of a stage table ({', '.join(STAGES)}) or scenario.seed, "
            f"got table [{head}]"
        )
    return Vary(key=key, spec=spec, **_parse_spec(spec, where))


def _parse_spec(spec: str, where: str) -> dict:
    bad = InputError(f"{where}: expected SPEC as {SPEC_HELP}, got {spec!r}")
    m = re.fullmatch(rf"\s*({_NUMBER})\s*:\s*({_NUMBER})\s*:\s*(\d+)\s*", spec)
    if m:
        a, b, n = float(m[1]), float(m[2]), int(m[3])
        if n < 1 or not (math.isfinite(a) and math.isfinite(b)):
            raise InputError(f"{where}: a:b:n needs finite a, b and n >= 1 points, got {spec!r}")
        return {"values": tuple(float(x) for x in np.linspace(a, b, n))}
    if spec.startswith("["):
        if not spec.endswith("]"):
            raise bad
        values = _value(spec, where)
        if not isinstance(values, list) or not values:
            raise InputError(f"{where}: expected a non-empty list [v1, v2, ...], got {spec!r}")
        return {"values": tuple(values)}
    m = re.fullmatch(rf"\s*(\w+)\((.*)\)\s*(?:([-+])\s*({_NUMBER}))?\s*", spec)
    if not m or m[1] not in DISTRIBUTIONS:
        raise bad
    dist, args = m[1], _split_top(m[2]) if m[2].strip() else []
    offset = float(m[4]) * (-1.0 if m[3] == "-" else 1.0) if m[3] else 0.0
    if dist == "choice":
        if not args:
            raise InputError(f"{where}: choice(a,b,...) needs at least one value, got {spec!r}")
        return {"dist": dist, "params": tuple(_value(a, where) for a in args), "offset": offset}
    try:
        lo, hi = (float(a) for a in args)
    except ValueError:
        raise InputError(f"{where}: {dist}(a,b) needs two numbers, got {spec!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise InputError(f"{where}: {dist}(a,b) needs finite numbers, got {spec!r}")
    if dist == "uniform" and not lo <= hi:
        raise InputError(f"{where}: uniform(lo,hi) needs lo <= hi, got {spec!r}")
    if dist == "loguniform" and not 0 < lo <= hi:
        raise InputError(f"{where}: loguniform(lo,hi) needs 0 < lo <= hi, got {spec!r}")
    if dist == "normal" and not hi >= 0:
        raise InputError(f"{where}: normal(mu,sigma) needs sigma >= 0, got {spec!r}")
    return {"dist": dist, "params": (lo, hi), "offset": offset}


@dataclass(frozen=True)
class Variation:
    """One run of a sweep: its id and the (key, value) overrides, in the order of the varies."""

    run_id: str
    overrides: tuple[tuple[str, Any], ...]


def _digest(obj) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _current(scenario: Scenario, key: str):
    """The scenario's value at ``key`` (None when it does not set it)."""
    head, *rest = key.split(".")
    if head == "scenario":
        return scenario.seed
    node: Any = scenario.tables.get(head)
    for part in rest:
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _typed(value, default):
    """An integral float where the scenario has an int becomes an int (``scenario.seed``)."""
    if isinstance(default, int) and not isinstance(default, bool) and isinstance(value, float):
        if value.is_integer():
            return int(value)
    return value


def plan_sweep(
    scenario: Scenario, varies: Sequence[Vary], *, runs: int | None = None
) -> tuple[Variation, ...]:
    """Every variation of the sweep, in order: the grid product, each point with the N draws.

    Raises
    ------
    InputError
        No varies, a key twice, a key whose table the scenario lacks, distributions without
        ``runs`` (or ``runs`` without a distribution), a seed that is not an integer >= 0.
    """
    if not varies:
        raise InputError(
            "sweep: nothing to vary; give --vary KEY=SPEC (or [sweep] vary in the scenario)"
        )
    keys = [v.key for v in varies]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise InputError(f"--vary {twice[0]}: given twice; expected each key once")
    for v in varies:
        head, *rest = v.key.split(".")
        if head != "scenario" and head not in scenario.tables:
            raise InputError(f"--vary {v.key}: the scenario has no [{head}] table to set it in")
        node: Any = scenario.tables.get(head)
        for part in rest[:-1]:
            node = node.get(part) if isinstance(node, dict) else None
            if node is not None and not isinstance(node, dict):
                raise InputError(
                    f"--vary {v.key}: '{part}' is a value in the scenario ({node!r}), not a table"
                )
    dists = [v for v in varies if not v.is_grid]
    if dists and runs is None:
        raise InputError(
            f"--vary {dists[0].key}={dists[0].spec}: a distribution needs --runs N "
            "(or [sweep] runs)"
        )
    if runs is not None and not dists:
        raise InputError(
            "--runs: only with a distribution --vary (uniform, loguniform, normal, choice); "
            "grids give their own points"
        )
    if runs is not None and runs < 1:
        raise InputError(f"--runs: expected an integer >= 1, got {runs}")
    n_draw = runs if dists else 1
    draws = {}
    for v in dists:
        default = _current(scenario, v.key)
        n_el = len(default) if isinstance(default, list) and default else 0
        rng = np.random.default_rng([scenario.seed, zlib.crc32(v.key.encode())])
        draws[v.key] = v.transform(rng.random((n_draw, max(n_el, 1)) if n_el else n_draw))
    base = _digest(
        {
            "seed": scenario.seed,
            "tables": {k: t for k, t in scenario.tables.items() if k not in SETTINGS_TABLES},
        }
    )
    out = []
    for point in itertools.product(*[v.values for v in varies if v.is_grid]):
        grid = dict(zip([v.key for v in varies if v.is_grid], point, strict=True))
        for i in range(n_draw):
            overrides = []
            for v in varies:
                value = grid[v.key] if v.is_grid else draws[v.key][i]
                default = _current(scenario, v.key)
                if isinstance(value, list):
                    el = default[0] if isinstance(default, list) and default else None
                    value = [_typed(x, el) for x in value]
                else:
                    value = _typed(value, default)
                if v.key == "scenario.seed" and not (
                    isinstance(value, int) and not isinstance(value, bool) and value >= 0
                ):
                    raise InputError(
                        f"--vary scenario.seed={v.spec}: expected integers >= 0, got {value!r}"
                    )
                overrides.append((v.key, value))
            run_id = _digest({"base": base, "overrides": sorted(overrides)})[:12]
            out.append(Variation(run_id, tuple(overrides)))
    return tuple(out)


def apply_overrides(
    scenario: Scenario, overrides: Sequence[tuple[str, Any]], *, results: str | os.PathLike
) -> Scenario:
    """The scenario with every (dotted key, value) set, writing into ``results``."""
    tables = copy.deepcopy(dict(scenario.tables))
    seed = scenario.seed
    for key, value in overrides:
        head, *rest = key.split(".")
        if head == "scenario":
            seed = value
            continue
        node = tables[head]
        for part in rest[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise InputError(f"--vary {key}: '{part}' is a value in the scenario, not a table")
        node[rest[-1]] = copy.deepcopy(value)
    return dataclasses.replace(scenario, seed=seed, tables=tables, results=Path(results))
