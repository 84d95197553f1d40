"""Plain numeric tables without a header: one row per sample, one column per channel.

The form of the identification databases (DaISy's ``.dat`` files, many loggers'
``.txt`` exports)::

    5.3100000e-02   -3.1300000e-02   4.9500000e-02   3.4200000e-02
    5.2600000e-02   -3.2800000e-02   5.2500000e-02   3.4200000e-02

Columns are separated by whitespace (spaces, tabs) or by one ``,`` or ``;``;
decimals are ``.``. Lines starting with ``#``, ``%`` or ``!`` are comments.
Nothing in such a file says which column is which, its sampling frequency or
its units, so the map says all three (nothing is guessed)::

    fs = 1.0                       # Hz (DaISy's CD player arm: no sample time given)
    input_names = ["u1", "u2"]     # optional; default u1.., y1..
    output_names = ["y1", "y2"]

    [variables]                    # columns by number, the first is 1
    u = [1, 2]
    y = [3, 4]
    # t = 1                        # or a time column, fs from it

    [units]
    u = "V"
    y = "V"

Columns the map does not name are left out (listed in a note). A time record
only: an FRF needs the element layout a CSV header spells out.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

from workbench.core.errors import InputError

from .build import Imported
from .csvfile import _DOT_NUMBER, _Column, _Table, _time, read_text
from .mapping import ImportMap

__all__ = ["read_table"]

_COMMENT = ("#", "%", "!")
_SPLIT = re.compile(r"[\s,;]+")


class _PlainTable(_Table):
    """The columns of a headerless table, named "1".."n" (what the map's numbers name)."""

    def __init__(self, path: Path):
        self.path = str(path)
        self.columns = _read_rows(path)
        self.by_name = {c.name: c for c in self.columns}
        self.delimiter = " "
        self.decimal_comma = False

    def unit(self, col: _Column, key: str, expect, m: ImportMap) -> float:
        """SI factor of the column's unit, which only the map can give."""
        if m.unit(col.name, key) is None:
            raise InputError(
                f"{self.path}: column {col.name} ({key}): a headerless table names no units: "
                f'expected the map\'s [units] {key} = "<unit>" (or "{col.name}" = ...), got none'
            )
        return super().unit(col, key, expect, m)


def _read_rows(path: Path) -> list[_Column]:
    text = read_text(path, "text table")
    rows: list[list[str]] = []
    lines: list[int] = []
    for i, raw in enumerate(text.splitlines()):
        s = raw.strip()
        if not s or s.startswith(_COMMENT):
            continue
        fields = [f for f in _SPLIT.split(s) if f]
        bad = next((f for f in fields if not _DOT_NUMBER.match(f)), None)
        if bad is not None:
            hint = (
                ": a header row? name the file .csv (columns named in its header)"
                if not rows
                else ""
            )
            raise InputError(f"{path}: line {i + 1}: expected numbers, got {bad!r}{hint}")
        if rows and len(fields) != len(rows[0]):
            raise InputError(
                f"{path}: line {i + 1}: expected {len(rows[0])} columns like line {lines[0]}, "
                f"got {len(fields)}"
            )
        rows.append(fields)
        lines.append(i + 1)
    if not rows:
        raise InputError(f"{path}: expected rows of numbers, got none")
    if len(rows[0]) < 2:
        raise InputError(
            f"{path}: expected at least 2 columns (an input and an output), got {len(rows[0])}"
        )
    return [
        _Column(str(k + 1), None, tuple(r[k] for r in rows), tuple(lines))
        for k in range(len(rows[0]))
    ]


def read_table(path: str | Path, m: ImportMap) -> Imported:
    """Read a headerless numeric table into a time record (spec 1a), as the map says."""
    src = str(path)
    m.refuse_variables(("fs", "freq", "G", "G_var", "input_names", "output_names"), "a table")
    if m.kind == "frf":
        raise InputError(
            f"{m.where('kind')}: expected 'time' for a headerless table (an FRF needs a CSV "
            "header naming its elements), got 'frf'"
        )
    missing = [k for k in ("u", "y") if k not in m.variables]
    if missing:
        raise InputError(
            f"{src}: a headerless table says nothing about its columns: expected the map's "
            f"[variables] {' and '.join(missing)} (column numbers, the first is 1), got none"
            + ("" if m.variables else " (no map?)")
        )
    table = _PlainTable(Path(path))
    n = len(table.columns)
    for key, sources in m.variables.items():
        for s in (sources,) if isinstance(sources, str) else sources:
            if s not in table.by_name:
                raise InputError(
                    f"{m.where('variables.' + key)}: expected a column number 1..{n} of "
                    f"{src}, got {s!r}"
                )
    tcol = table.by_name[m.variables["t"]] if "t" in m.variables else None
    if tcol is None and m.fs is None:
        raise InputError(
            f"{src}: a headerless table has no sample time: expected fs in the map (Hz), or "
            "a time column as [variables] t, got neither"
        )

    def count(key: str) -> int:
        v = m.variables.get(key, ())
        return 1 if isinstance(v, str) else len(v)

    named = replace(
        m,
        input_names=m.input_names or tuple(f"u{k + 1}" for k in range(count("u"))),
        output_names=m.output_names or tuple(f"y{k + 1}" for k in range(count("y"))),
    )
    got = _time(table, tcol, named)
    notes = tuple(t.replace("columns the map", "table columns the map") for t in got.notes)
    return Imported(got.data, notes, f"table, {got.data.n_samples} rows of {n} columns")
