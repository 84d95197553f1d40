"""``workbench regress SCENARIO.toml --baseline DIR [--out DIR]``: rerun, compare every figure.

Reruns the scenario into ``--out`` (default: a new temporary folder, kept and
printed) and compares every numeric figure of every JSON file of the baseline
folder (an earlier results folder of the same scenario) with the rerun's.

A figure is a JSON leaf addressed as ``FILE:KEY``, KEY the dotted path with
list indices as numbers, e.g. ``evaluation.json:designs.pid-notch.tracking.ma_max.y``
or ``design.json:designs.pid-notch.on_model.loops.0.crossover_hz``. It passes when

    |now - baseline| <= abs + rel * |baseline|

with the defaults ``rel = 1e-6`` and ``abs = 1e-15`` (figures are in SI units:
1e-15 m is a millionth of a nanometre); non-finite figures (``"inf"``, ``"nan"``)
must match exactly, booleans must be equal, other strings (notes, paths) are not
figures and are skipped. A figure of the baseline missing from the rerun (or a
whole JSON file) is a regression; a new one is not. Timings
(``summary.json:scenario.stage_seconds.*``) are ignored.

The scenario's ``[regress]`` table overrides these::

    [regress]
    rel = 1e-6                  # default relative tolerance
    abs = 1e-15                 # default absolute tolerance
    ignore = ["modes.json:*"]   # more FILE:KEY patterns to skip (fnmatch)
    [regress.tolerances]        # per FILE:KEY pattern (fnmatch); the longest match wins
    "evaluation.json:designs.*.tracking.*" = { rel = 1e-3, abs = 1e-12 }

Exit status: 0 every figure within tolerance; 1 a regression (each one printed:
file, key, baseline and new value, tolerance); 2 bad input (no baseline folder,
no JSON figures in it, a bad [regress] table).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

from workbench.core.atomic import check_output
from workbench.core.errors import InputError

DEFAULT_REL = 1e-6
DEFAULT_ABS = 1e-15
#: figures that are not results of the scenario (wall-clock timings)
DEFAULT_IGNORE = ("summary.json:scenario.stage_seconds.*",)


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "regress",
        help="rerun a scenario and compare every figure with a stored baseline (exit 1 if moved)",
        description=(
            "Rerun SCENARIO and compare every numeric figure of the baseline folder's JSON files "
            f"with the rerun's within tolerances (default rel {DEFAULT_REL:g}, abs "
            f"{DEFAULT_ABS:g}; per FILE:KEY pattern in the scenario's [regress] table). Exit 1 "
            "naming each figure that moved, 0 when none did, 2 on bad input."
        ),
    )
    p.add_argument("scenario", help="scenario file (.toml)")
    p.add_argument("--baseline", required=True, metavar="DIR", help="earlier results folder")
    p.add_argument("--out", metavar="DIR", help="results folder of the rerun (default: temporary)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


@dataclass(frozen=True)
class Tolerances:
    """Default and per-pattern tolerances, and patterns of keys to skip."""

    rel: float = DEFAULT_REL
    abs: float = DEFAULT_ABS
    per_key: tuple[tuple[str, float, float], ...] = ()  # (pattern, rel, abs)
    ignore: tuple[str, ...] = DEFAULT_IGNORE

    def for_key(self, key: str) -> tuple[float, float] | None:
        """(rel, abs) of ``key``, None when it is ignored."""
        if any(fnmatch.fnmatchcase(key, pat) for pat in self.ignore):
            return None
        matches = [t for t in self.per_key if fnmatch.fnmatchcase(key, t[0])]
        if not matches:
            return self.rel, self.abs
        _pat, rel, abs_ = max(matches, key=lambda t: len(t[0]))
        return rel, abs_


def _tol_value(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise InputError(f"[regress] {where}: expected a number >= 0, got {value!r}")
    return float(value)


def tolerances_from_table(table: dict) -> Tolerances:
    """A :class:`Tolerances` from a scenario's ``[regress]`` table (unknown keys refused)."""
    table = dict(table)
    rel = _tol_value(table.pop("rel", DEFAULT_REL), "key 'rel'")
    abs_ = _tol_value(table.pop("abs", DEFAULT_ABS), "key 'abs'")
    ignore = table.pop("ignore", [])
    if not isinstance(ignore, list) or not all(isinstance(x, str) for x in ignore):
        raise InputError(
            f"[regress] key 'ignore': expected a list of FILE:KEY patterns, got {ignore!r}"
        )
    per = table.pop("tolerances", {})
    if not isinstance(per, dict):
        raise InputError(f"[regress] key 'tolerances': expected a table, got {per!r}")
    if table:
        raise InputError(f"[regress] has unknown key '{sorted(table)[0]}'")
    per_key = []
    for pattern, spec in per.items():
        if ":" not in pattern:
            raise InputError(
                f"[regress.tolerances] key {pattern!r}: expected FILE:KEY (e.g. "
                "'evaluation.json:designs.*.tracking.*')"
            )
        if not isinstance(spec, dict) or not spec or set(spec) - {"rel", "abs"}:
            raise InputError(
                f"[regress.tolerances] {pattern!r}: expected {{ rel = ..., abs = ... }}, "
                f"got {spec!r}"
            )
        per_key.append(
            (
                pattern,
                _tol_value(spec.get("rel", rel), f"tolerances {pattern!r} rel"),
                _tol_value(spec.get("abs", abs_), f"tolerances {pattern!r} abs"),
            )
        )
    return Tolerances(rel, abs_, tuple(per_key), DEFAULT_IGNORE + tuple(ignore))


def figures(node, prefix: str = "") -> dict[str, object]:
    """Every figure leaf of a JSON document: {dotted key: number, bool or non-finite string}."""
    out: dict[str, object] = {}
    if isinstance(node, dict):
        for k, v in node.items():
            out.update(figures(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.update(figures(v, f"{prefix}.{i}" if prefix else str(i)))
    elif isinstance(node, (bool, int, float)) or node is None:
        out[prefix] = node
    elif isinstance(node, str) and node.strip().lower() in ("inf", "-inf", "nan", "infinity"):
        out[prefix] = float(node)
    return out


def _same(old, new, rel: float, abs_: float) -> bool:
    if isinstance(old, bool) or isinstance(new, bool) or old is None or new is None:
        return old is new or (old == new and type(old) is type(new))
    old, new = float(old), float(new)
    if not (math.isfinite(old) and math.isfinite(new)):
        return (math.isnan(old) and math.isnan(new)) or old == new
    return abs(new - old) <= abs_ + rel * abs(old)


def compare_folders(baseline: Path, rerun: Path, tol: Tolerances) -> tuple[list[str], int]:
    """(one line per regression, number of figures compared) of rerun against baseline."""
    files = sorted(p.relative_to(baseline) for p in baseline.rglob("*.json"))
    if not files:
        raise InputError(
            f"--baseline {baseline}: expected a results folder with JSON figures, found none"
        )
    problems: list[str] = []
    n = 0
    for rel_path in files:
        name = rel_path.as_posix()
        try:
            old = figures(json.loads((baseline / rel_path).read_text()))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"--baseline {baseline / rel_path}: not a JSON file ({exc})") from None
        new_path = rerun / rel_path
        if not new_path.is_file():
            if any(tol.for_key(f"{name}:{k}") for k in old):
                problems.append(f"{name}: missing from the rerun")
            continue
        new = figures(json.loads(new_path.read_text()))
        for key, value in old.items():
            full = f"{name}:{key}"
            t = tol.for_key(full)
            if t is None:
                continue
            n += 1
            if key not in new:
                problems.append(f"{name}: {key}: baseline {value!r}, missing from the rerun")
            elif not _same(value, new[key], *t):
                problems.append(
                    f"{name}: {key}: baseline {value!r}, now {new[key]!r} "
                    f"(tolerance rel {t[0]:g}, abs {t[1]:g})"
                )
    return problems, n


def run(args) -> int:
    from workbench.cli.pipeline import run_scenario
    from workbench.io.scenario import load_scenario

    if args.out is not None:
        check_output(args.out, [args.scenario], folder=True, what="--out")
    baseline = Path(args.baseline)
    if not baseline.is_dir():
        raise InputError(
            f"--baseline: expected an earlier results folder, got {args.baseline!r} "
            "(no such folder)"
        )
    if not any(baseline.rglob("*.json")):
        raise InputError(
            f"--baseline {args.baseline}: expected a results folder with JSON figures, found none"
        )
    if args.out is None:
        out = Path(tempfile.mkdtemp(prefix="workbench-regress-"))
    else:
        out = Path(args.out)
        if out.resolve() == baseline.resolve():
            raise InputError(
                "--out: expected a folder other than the baseline (it would be overwritten)"
            )
    scenario = load_scenario(args.scenario, results=out)
    tol = tolerances_from_table(scenario.table("regress"))
    run_scenario(scenario, progress=not args.quiet)
    problems, n = compare_folders(baseline, out, tol)
    for line in problems:
        print(f"REGRESSION {line}")
    if problems:
        print(f"{len(problems)} regression(s) in {n} figures; rerun in {out}/")
        return 1
    print(f"no regression: {n} figures within tolerance; rerun in {out}/")
    return 0
