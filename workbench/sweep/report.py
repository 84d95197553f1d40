"""A sweep's outputs, rebuilt from its rows: the table (CSV, Parquet), the summary (JSON,
text) and the plots (share false, worst values, figure vs varied key).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from workbench.core import atomic
from workbench.core.jsonutil import jsonable
from workbench.io.scenario import Scenario
from workbench.sweep.figures import Figure, Settings
from workbench.sweep.spec import Vary, _is_number

__all__ = ["write_outputs"]


def _table(varies: Sequence[Vary], rows: Sequence[dict]) -> tuple[list[str], list[list]]:
    """(columns, values per row): run_id, the varied keys, status, seconds, figures, warnings.

    A list-valued key gets a column per element, ``key[i]`` (a scalar on it fills each).
    """
    vary_cols: list[tuple[str, str, int | None]] = []
    for v in varies:
        n = max(
            (
                len(r["overrides"][v.key])
                for r in rows
                if isinstance(r["overrides"].get(v.key), list)
            ),
            default=0,
        )
        vary_cols += (
            [(f"{v.key}[{i}]", v.key, i) for i in range(n)] if n else [(v.key, v.key, None)]
        )
    fig_cols = list(dict.fromkeys(c for r in rows for c in r["figures"]))
    columns = ["run_id", *(c for c, _, _ in vary_cols), "status", "seconds", *fig_cols, "warnings"]
    values = []
    for r in rows:
        line = [r["run_id"]]
        for _c, key, i in vary_cols:
            x = r["overrides"].get(key)
            line.append(x[i] if isinstance(x, list) and i is not None and i < len(x) else x)
        line += [r["status"], r.get("seconds")]
        line += [r["figures"].get(c) for c in fig_cols]
        line.append(" | ".join(r.get("warnings", [])) or None)
        values.append(line)
    return columns, values


def _kind(values: Sequence) -> str:
    """bool, int, float or string: one type per column (None is missing)."""
    vals = [v for v in values if v is not None]
    if vals and all(isinstance(v, bool) for v in vals):
        return "bool"
    if vals and all(isinstance(v, int) and not isinstance(v, bool) for v in vals):
        return "int"
    if all(_is_number(v) for v in vals):
        return "float"
    return "string"


def _cell(v, kind: str):
    if v is None:
        return None
    if kind == "float":
        return float(v)
    if kind == "string" and not isinstance(v, str):
        return (
            json.dumps(v)
            if isinstance(v, list)
            else str(v).lower()
            if isinstance(v, bool)
            else str(v)
        )
    return v


def _write_tables(out: Path, columns: list[str], values: list[list]) -> list[str]:
    """sweep_table.csv and sweep_table.parquet (same columns, types and values), atomically.

    CSV: booleans ``true`` / ``false``, floats by ``repr`` (exact), missing cells empty.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    kinds = [_kind([line[j] for line in values]) for j in range(len(columns))]
    cols = [[_cell(line[j], kinds[j]) for line in values] for j in range(len(columns))]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for i in range(len(values)):
        writer.writerow(
            ""
            if c[i] is None
            else ("true" if c[i] else "false")
            if k == "bool"
            else repr(c[i])
            if k == "float"
            else c[i]
            for c, k in zip(cols, kinds, strict=True)
        )
    atomic.write_text(out / "sweep_table.csv", buf.getvalue())
    types = {"bool": pa.bool_(), "int": pa.int64(), "float": pa.float64(), "string": pa.string()}
    table = pa.table(
        {name: pa.array(c, type=types[k]) for name, c, k in zip(columns, cols, kinds, strict=True)}
    )
    with atomic.atomic_path(out / "sweep_table.parquet") as tmp:
        pq.write_table(table, tmp)
    return ["sweep_table.csv", "sweep_table.parquet"]


def _figure_of(column: str, figures: Sequence[Figure]) -> tuple[Figure | None, str]:
    """The figure a column comes from and its group (the part after the figure's name)."""
    best = None
    for f in figures:
        if f.name and (column == f.name or column.startswith(f.name + ".")):
            if best is None or len(f.name) > len(best.name):
                best = f
    if best is None:
        return None, ""
    return best, column[len(best.name) + 1 :]


def _summarize(rows: Sequence[dict], figures: Sequence[Figure], gate: str) -> dict[str, dict]:
    """Per figure column: its figure, group, kind and statistics over the ok runs."""
    ok = [r for r in rows if r["status"] == "ok"]
    columns = list(dict.fromkeys(c for r in ok for c in r["figures"]))
    stats: dict[str, dict] = {}
    for c in columns:
        fig, group = _figure_of(c, figures)
        name = fig.name if fig else c
        gate_col = f"{gate}.{group}" if group else gate
        gated = gate_col in columns and gate_col != c
        vals = [r["figures"].get(c) for r in ok if not gated or r["figures"].get(gate_col) is True]
        vals = [v for v in vals if v is not None]
        entry: dict[str, Any] = {"figure": name, "group": group, "n": len(vals)}
        if vals and all(isinstance(v, bool) for v in vals):
            n_false = sum(not v for v in vals)
            entry.update(kind="bool", n_false=n_false, share_false=n_false / len(vals))
        elif vals and all(_is_number(v) for v in vals):
            x = np.asarray(vals, float)
            how = fig.reduce if fig is not None and fig.reduce in ("max", "min") else None
            entry.update(
                kind="number", min=float(np.min(x)), median=float(np.median(x)),
                max=float(np.max(x)), worst=float(getattr(np, how)(x)) if how else None,
                worst_is=how, gated_by=gate_col if gated else None,
            )  # fmt: skip
        else:
            entry.update(kind="other")
        stats[c] = entry
    return stats


def _text(scenario: Scenario, plan, rows, stats: dict[str, dict], gate: str) -> str:
    """The summary table: one line per group (design), one cell per figure."""
    n_ok = sum(r["status"] == "ok" for r in rows)
    lines = [
        f"sweep {scenario.name}: {len(rows)} of {len(plan)} runs done, {n_ok} ok, "
        f"{len(rows) - n_ok} failed"
    ]
    names = list(dict.fromkeys(s["figure"] for s in stats.values() if s["kind"] != "other"))
    groups = list(dict.fromkeys(s["group"] for s in stats.values()))
    if names:
        heads = []
        for name in names:
            kinds = {s["kind"] for s in stats.values() if s["figure"] == name}
            worst = {s.get("worst_is") for s in stats.values() if s["figure"] == name}
            if kinds == {"bool"}:
                heads.append(f"{name} false")
            elif worst - {None}:
                heads.append(f"{name} worst ({'/'.join(sorted(worst - {None}))})")
            else:
                heads.append(f"{name} min..max")
        width = max(12, *(len(g) for g in groups))
        cw = [max(14, len(h)) for h in heads]
        lines.append(f"{'':{width}}" + "".join(f"  {h:>{w}}" for h, w in zip(heads, cw)))
        for g in groups:
            cells = []
            for name in names:
                s = stats.get(f"{name}.{g}" if g else name)
                if s is None or s["kind"] == "other" or s["n"] == 0:
                    cells.append("-")
                elif s["kind"] == "bool":
                    cells.append(f"{s['n_false']}/{s['n']} ({100 * s['share_false']:.1f} %)")
                elif s["worst"] is not None:
                    cells.append(f"{s['worst']:.4g}")
                else:
                    cells.append(f"{s['min']:.4g}..{s['max']:.4g}")
            lines.append(f"{g or '-':{width}}" + "".join(f"  {c:>{w}}" for c, w in zip(cells, cw)))
        notes = []
        if any(s["kind"] == "bool" for s in stats.values()):
            notes.append("false: share of the ok runs")
        if any(s.get("gated_by") for s in stats.values()):
            notes.append(f"worst / min..max: over the ok runs with {gate} = true")
        if notes:
            lines.append("; ".join(notes))
    failures: dict[str, int] = {}
    for r in rows:
        if r["status"] != "ok":
            failures[r["status"]] = failures.get(r["status"], 0) + 1
    for status, n in sorted(failures.items(), key=lambda t: -t[1])[:3]:
        lines.append(f"failed x{n}: {status}")
    return "\n".join(lines)


def write_outputs(
    out: Path, scenario: Scenario, plan, varies: Sequence[Vary], rows, settings: Settings
) -> tuple[tuple[str, ...], dict, str]:
    """Rebuild the table (CSV, Parquet), the summary (JSON, text) and the plots from ``rows``."""
    columns, values = _table(varies, rows)
    files = _write_tables(out, columns, values)
    stats = _summarize(rows, settings.figures, settings.gate)
    text = _text(scenario, plan, rows, stats, settings.gate)
    summary = {
        "scenario": scenario.name,
        "file": str(scenario.path) if scenario.path else None,
        "seed": scenario.seed,
        "varies": [{"key": v.key, "spec": v.spec} for v in varies],
        "n_planned": len(plan),
        "n_done": len(rows),
        "n_ok": sum(r["status"] == "ok" for r in rows),
        "gate": settings.gate,
        "collect": {f.name: f.source for f in settings.figures},
        "columns": stats,
    }
    atomic.write_text(out / "sweep_summary.json", json.dumps(jsonable(summary), indent=2) + "\n")
    atomic.write_text(out / "sweep_summary.txt", text + "\n")
    files += ["sweep_summary.json", "sweep_summary.txt"]
    files += _plots(out, varies, rows, stats, settings.gate)
    return tuple(files), summary, text


def _plots(out: Path, varies, rows, stats: dict[str, dict], gate: str) -> list[str]:
    """sweep_shares.png (boolean figures false), sweep_worst.png, sweep_scatter.png."""
    from workbench.plotting import lean_axes, new_figure, save_png

    ok = [r for r in rows if r["status"] == "ok"]
    written = []
    bools = [(c, s) for c, s in stats.items() if s["kind"] == "bool" and s["n"]]
    if bools:
        fig = new_figure(6, 0.35 * len(bools) + 1.4)
        ax = fig.add_subplot(1, 1, 1)
        ax.barh([c for c, _ in bools], [100 * s["share_false"] for _, s in bools], color="C3")
        for k, (_c, s) in enumerate(bools):
            ax.text(100 * s["share_false"], k, f" {s['n_false']}/{s['n']}", va="center", fontsize=7)
        ax.set_xlim(0, 110)
        ax.set_xlabel(f"share of the ok runs where the figure is false, % ({gate}: unstable)")
        ax.tick_params(labelsize=7)
        fig.subplots_adjust(left=0.3, bottom=0.25 if len(bools) < 4 else 0.12)
        save_png(fig, out / "sweep_shares.png")
        written.append("sweep_shares.png")
    numbers: dict[str, list[tuple[str, dict]]] = {}
    for c, s in stats.items():
        if s["kind"] == "number" and s["n"]:
            numbers.setdefault(s["figure"], []).append((c, s))
    if numbers:
        fig = new_figure(3.2 * min(len(numbers), 3) + 0.5, 2.8 * math.ceil(len(numbers) / 3) + 0.6)
        for k, (name, cols) in enumerate(numbers.items()):
            ax = fig.add_subplot(math.ceil(len(numbers) / 3), min(len(numbers), 3), k + 1)
            labels = [s["group"] or name for _, s in cols]
            for j, (_c, s) in enumerate(cols):
                ax.plot([j, j], [s["min"], s["max"]], color="0.6", lw=3)
                ax.plot(j, s["median"], "ko", ms=3)
                if s["worst"] is not None:
                    ax.plot(j, s["worst"], "r_", ms=14, mew=2)
                    ax.annotate(f"{s['worst']:.3g}", (j, s["worst"]), fontsize=7, xytext=(6, 0),
                                textcoords="offset points", va="center")  # fmt: skip
            ax.set_xticks(range(len(cols)), labels, fontsize=7, rotation=20)
            ax.set_xlim(-0.6, len(cols) - 0.4)
            worst = cols[0][1]["worst_is"]
            gated = " over stable runs" if cols[0][1]["gated_by"] else ""
            ax.set_title(
                f"{name}: range, median" + (f", worst ({worst}, red)" if worst else "") + gated,
                fontsize=7,
            )
            ax.tick_params(labelsize=7)
        fig.tight_layout()
        save_png(fig, out / "sweep_worst.png")
        written.append("sweep_worst.png")
    xs = _scatter_axes(varies, ok)
    ys = list(numbers)[:4]
    if xs and ys and ok:
        fig = new_figure(2.6 * len(xs) + 0.6, 2.2 * len(ys) + 0.6)
        for i, name in enumerate(ys):
            for j, (label, xv) in enumerate(xs):
                ax = fig.add_subplot(len(ys), len(xs), i * len(xs) + j + 1)
                for k, (c, s) in enumerate(numbers[name]):
                    y = np.array([_num(r["figures"].get(c)) for r in ok])
                    good = np.array([
                        s["gated_by"] is None or r["figures"].get(s["gated_by"]) is True for r in ok
                    ])  # fmt: skip
                    ax.plot(xv[good], y[good], ".", ms=3, color=f"C{k}", label=s["group"] or name)
                    ax.plot(xv[~good], y[~good], "x", ms=3, color=f"C{k}")
                if i == len(ys) - 1:
                    ax.set_xlabel(label, fontsize=7)
                if j == 0:
                    ax.set_ylabel(name, fontsize=7)
                ax.tick_params(labelsize=6)
                lean_axes(ax)
        fig.axes[0].legend(fontsize=6)
        fig.suptitle(f"figure vs varied key (x: {gate} false)", fontsize=8)
        fig.tight_layout()
        save_png(fig, out / "sweep_scatter.png")
        written.append("sweep_scatter.png")
    return written


def _num(v) -> float:
    return float(v) if _is_number(v) else math.nan


def _scatter_axes(varies, ok) -> list[tuple[str, np.ndarray]]:
    """Up to 5 numeric varied values as x axes (a list key: one axis per element)."""
    axes = []
    for v in varies:
        vals = [r["overrides"].get(v.key) for r in ok]
        n = max((len(x) for x in vals if isinstance(x, list)), default=0)
        for i in range(n) if n else [None]:
            x = [
                (x[i] if isinstance(x, list) and i < len(x) else x) if i is not None else x
                for x in vals
            ]
            if x and all(_is_number(e) for e in x):
                axes.append((v.key + (f"[{i}]" if i is not None else ""), np.array(x, float)))
    return axes[:5]
