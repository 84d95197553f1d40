"""CSV files with a header row: one column per channel, units in brackets.

Column names (the convention; a map can name other columns, see below)::

    time record:  t [s],  u_F1 [N],  u_F2 [N],  y_x [um],  y_y [um],  r_F1 [N],  r_F2 [N]
    FRF:          f [Hz], G_x_F1_re [m/N], G_x_F1_im [m/N], G_x_F2_mag [m/N], G_x_F2_phase [deg],
                  Gvar_x_F1 [(m/N)^2], ...

- The abscissa: a time column ``t`` or ``time`` (s, ms, us) for a time record,
  or a frequency column ``f``, ``freq`` or ``frequency`` (Hz, kHz, rad/s) for an
  FRF. The time axis must be uniform; ``fs`` is taken from it.
- Time channels ``<role>_<name>``: role ``u`` plant input, ``y`` measured
  output, ``r`` excitation added at the input (closed loop: one per input,
  named as that input). The name is what follows the first underscore.
- FRF elements ``G_<output>_<input>_<part>``: ``re`` and ``im`` (real and
  imaginary part), or ``mag`` and ``phase`` (phase in deg or rad); one pair per
  element, every output/input pair present. Optional ``Gvar_<output>_<input>``:
  the variance of that element (all elements or none). Output and input names
  hold no underscore here.
- Units: every column names its unit in brackets (``y_x [um]``); a column
  without one takes it from the map's ``[units]`` (by column name, or by spec
  key ``t``, ``freq``, ``u``, ``y``, ``r``, ``G``); a column with neither is
  refused. Values are converted to SI (:mod:`.units`).
- Delimiter: ``;`` if the header has one, else a tab, else ``,``. Decimal mark:
  ``.``; a ``;``- or tab-delimited file may use ``,`` instead (every number in
  the file then does: a file with both is refused). A ``,``-delimited file
  with a decimal comma has more fields in its rows than in its header and is
  refused: it is never misread. Lines starting with ``#`` are comments.

With a map, ``[variables]`` names the columns: ``t`` or ``freq`` one column,
``u``, ``y``, ``r`` a list of columns (the channel name is the column's);
columns the map does not name are then left out (listed in a note).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workbench.core.errors import InputError

from . import units as U
from .axes import frequency_lines, rate_from_time_axis
from .build import Imported, frf_data, time_data
from .mapping import ImportMap

__all__ = ["read_csv"]

_TIME_NAMES = ("t", "time")
_FREQ_NAMES = ("f", "freq", "frequency")
_HEADER = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<unit>[^\]]*)\])?$")
_ROLE = re.compile(r"^(?P<role>[uyr])_(?P<name>.+)$")
_G = re.compile(r"^G_(?P<out>[^_]+)_(?P<inp>[^_]+)_(?P<part>re|im|mag|phase)$")
_GVAR = re.compile(r"^Gvar_(?P<out>[^_]+)_(?P<inp>[^_]+)$")
_DOT_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_COMMA_NUMBER = re.compile(r"^[+-]?(\d+,?\d*|,\d+)([eE][+-]?\d+)?$")
_CONVENTION = (
    "t/time, f/freq/frequency, u_<name>, y_<name>, r_<name>, G_<out>_<in>_<part>, Gvar_<out>_<in>"
)


@dataclass(frozen=True)
class _Column:
    """One column: its header name and unit, its fields (text) and the line of each field."""

    name: str
    unit: str | None
    fields: tuple[str, ...]
    lines: tuple[int, ...]


class _Table:
    """The columns of a CSV file, numbers parsed with the file's decimal mark."""

    def __init__(self, path: Path):
        self.path = str(path)
        self.columns, self.delimiter = _read_columns(path)
        self.by_name = {c.name: c for c in self.columns}
        self.decimal_comma = self._decimal_mark()

    def _decimal_mark(self) -> bool:
        comma = dot = None
        for col in self.columns:
            for text, line in zip(col.fields, col.lines):
                if "," in text and comma is None:
                    comma = (col, text, line)
                if "." in text and dot is None:
                    dot = (col, text, line)
        if comma is None:
            return False
        col, text, line = comma
        if self.delimiter == ",":
            raise InputError(
                f"{self.path}: line {line}, column '{col.name}': expected '.' decimals in a "
                f"comma-separated file, got {text!r} (a quoted decimal comma): use ';' to separate"
            )
        if dot is not None:
            col, text, line = dot
            raise InputError(
                f"{self.path}: line {line}, column '{col.name}': expected the file's decimal "
                f"comma, got {text!r} (a file with both ',' and '.' in its numbers is ambiguous)"
            )
        return True

    def column(self, name: str, key: str, m: ImportMap) -> _Column:
        """The column ``name``, which the map names under ``key`` (refused when absent)."""
        if name not in self.by_name:
            have = ", ".join(c.name for c in self.columns)
            raise InputError(
                f"{m.where(key)}: column {name!r} is not in {self.path} (columns: {have})"
            )
        return self.by_name[name]

    def values(self, col: _Column) -> np.ndarray:
        """The column's numbers (as written, not scaled), shape (n,)."""
        pattern = _COMMA_NUMBER if self.decimal_comma else _DOT_NUMBER
        out = np.empty(len(col.fields))
        for k, (text, line) in enumerate(zip(col.fields, col.lines)):
            if not pattern.match(text):
                got = "an empty field" if not text else repr(text)
                raise InputError(
                    f"{self.path}: line {line}, column '{col.name}': expected a number, got {got}"
                )
            out[k] = float(text.replace(",", ".")) if self.decimal_comma else float(text)
        return out

    def resolution(self, col: _Column) -> np.ndarray:
        """The value of the last printed digit of each of the column's numbers, (N,).

        Per number, not the column's largest: a logger's "0" at the first instant (%g
        strips the zeros) would otherwise allow a whole second of jitter at every sample.
        """
        out = np.empty(len(col.fields))
        for k, text in enumerate(col.fields):
            mantissa, _, exponent = text.lower().partition("e")
            decimals = len(mantissa.replace(",", ".").partition(".")[2])
            out[k] = 10.0 ** (int(exponent or 0) - decimals)
        return out

    def unit(self, col: _Column, key: str, expect: frozenset[str], m: ImportMap) -> float:
        """SI factor of the column's unit: the header's, else the map's; refused when neither."""
        by_map = m.unit(col.name, key)
        if col.unit is not None:
            if by_map is not None and by_map[1] != col.unit:
                raise InputError(
                    f"{m.where('units.' + by_map[0])}: column '{col.name}' of {self.path} says "
                    f"{col.unit!r}, the map says {by_map[1]!r}"
                )
            return U.si_factor(col.unit, expect, f"{self.path}: column '{col.name}'")
        if by_map is None:
            raise InputError(
                f"{self.path}: column '{col.name}': expected a unit in the header "
                f"('{col.name} [unit]') or in the map's [units], got none"
            )
        return U.si_factor(by_map[1], expect, m.where("units." + by_map[0]))


def read_text(path: Path, what: str = "text file") -> str:
    """The file's text (UTF-8, a byte-order mark dropped); refused in one line otherwise."""
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: expected a UTF-8 {what}, got {exc.reason} at byte {exc.start}"
        ) from None


def _read_columns(path: Path) -> tuple[list[_Column], str]:
    lines = read_text(path).splitlines()
    start = next(
        (i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")), None
    )
    if start is None:
        raise InputError(f"{path}: expected a header row, got an empty file")
    header = lines[start]
    delimiter = ";" if ";" in header else "\t" if "\t" in header else ","
    head = [h.strip() for h in next(csv.reader([header], delimiter=delimiter))]
    names, units = [], []
    for cell in head:
        match = _HEADER.match(cell)
        name, unit = match["name"].strip(), match["unit"]
        if not name:
            raise InputError(
                f"{path}: line {start + 1}: expected a name for every column, got {cell!r}"
            )
        if name in names:
            raise InputError(
                f"{path}: line {start + 1}: expected distinct column names, got {name!r} twice"
            )
        names.append(name)
        units.append(None if unit is None or not unit.strip() else unit.strip())
    if len(names) < 2:
        raise InputError(
            f"{path}: line {start + 1}: expected at least 2 columns separated by ',', ';' or a "
            f"tab, got {header.strip()!r}"
        )
    fields: list[list[str]] = [[] for _ in names]
    rows: list[int] = []
    for i in range(start + 1, len(lines)):
        if not lines[i].strip() or lines[i].lstrip().startswith("#"):
            continue
        row = [c.strip() for c in next(csv.reader([lines[i]], delimiter=delimiter))]
        while len(row) > len(names) and row[-1] == "":
            row.pop()  # trailing delimiters
        if len(row) > len(names):
            hint = (
                ": a decimal comma in a comma-separated file? use '.' decimals or ';' to separate"
                if delimiter == ","
                else ""
            )
            raise InputError(
                f"{path}: line {i + 1}: expected {len(names)} fields like the header, got "
                f"{len(row)}{hint}"
            )
        row += [""] * (len(names) - len(row))
        for col, value in zip(fields, row):
            col.append(value)
        rows.append(i + 1)
    if not rows:
        raise InputError(f"{path}: expected data rows below the header, got none")
    columns = []
    for name, unit, col in zip(names, units, fields):
        n = len(col)
        while n and col[n - 1] == "":
            n -= 1
        columns.append(_Column(name, unit, tuple(col[:n]), tuple(rows[:n])))
    lengths = [len(c.fields) for c in columns]
    if min(lengths) != max(lengths):
        short = columns[int(np.argmin(lengths))]
        long = columns[int(np.argmax(lengths))]
        raise InputError(
            f"{path}: channels of unequal length: column '{short.name}' has {len(short.fields)} "
            f"values, column '{long.name}' has {len(long.fields)}"
        )
    return columns, delimiter


def _first(table: _Table, names: tuple[str, ...]) -> list[_Column]:
    return [c for c in table.columns if c.name.lower() in names]


def read_csv(path: str | Path, m: ImportMap) -> Imported:
    """Read a CSV time record or FRF (the module's column convention) into the spec form."""
    m.refuse_variables(
        ("fs", "G", "G_var", "input_names", "output_names", "kind", "loop", "period"), "a CSV file"
    )
    table = _Table(Path(path))
    src = str(path)
    time_cols = (
        [table.column(m.variables["t"], "variables.t", m)]
        if "t" in m.variables
        else _first(table, _TIME_NAMES)
    )
    freq_cols = (
        [table.column(m.variables["freq"], "variables.freq", m)]
        if "freq" in m.variables
        else _first(table, _FREQ_NAMES)
    )
    for cols, what in ((time_cols, "time"), (freq_cols, "frequency")):
        if len(cols) > 1:
            raise InputError(
                f"{src}: expected one {what} column, got {', '.join(repr(c.name) for c in cols)}"
            )
    kind = m.kind
    if kind is None:
        if time_cols and freq_cols:
            raise InputError(
                f"{src}: expected a time column or a frequency column, got both "
                f"('{time_cols[0].name}', '{freq_cols[0].name}'): say which with kind in the map"
            )
        if time_cols or any(k in m.variables for k in ("u", "y", "r")):
            kind = "time"
        elif freq_cols:
            kind = "frf"
        else:
            raise InputError(
                f"{src}: expected a time column (t, time) or a frequency column (f, freq, "
                f"frequency), got columns {', '.join(c.name for c in table.columns)}"
            )
    if kind == "time":
        return _time(table, time_cols[0] if time_cols else None, m)
    if not freq_cols:
        raise InputError(
            f"{src}: expected a frequency column (f, freq, frequency) for an FRF, got none"
        )
    return _frf(table, freq_cols[0], m)


def _time(table: _Table, tcol: _Column | None, m: ImportMap) -> Imported:
    src = table.path
    notes: list[str] = []
    roles: dict[str, list[tuple[str, _Column]]] = {"u": [], "y": [], "r": []}
    if any(k in m.variables for k in roles):
        for key in roles:
            sources = m.variables.get(key, ())
            sources = (sources,) if isinstance(sources, str) else sources
            roles[key] = [(s, table.column(s, f"variables.{key}", m)) for s in sources]
        used = {c.name for cols in roles.values() for _, c in cols} | (
            {tcol.name} if tcol else set()
        )
        left = [c.name for c in table.columns if c.name not in used]
        if left:
            notes.append(f"columns the map does not name, left out: {', '.join(left)}")
    else:
        for col in table.columns:
            if col is tcol:
                continue
            match = _ROLE.match(col.name)
            if match is None:
                raise InputError(
                    f"{src}: column '{col.name}': expected a channel column named u_<name>, "
                    "y_<name> or r_<name> (or a map naming the columns), got "
                    f"{col.name!r}"
                )
            roles[match["role"]].append((match["name"], col))
    for key, what in (("u", "input (u_<name>)"), ("y", "output (y_<name>)")):
        if not roles[key]:
            raise InputError(f"{src}: expected at least one {what} column, got none")
    if tcol is not None:
        factor = table.unit(tcol, "t", U.TIME, m)
        t = table.values(tcol) * factor
        fs = rate_from_time_axis(
            t,
            f"{src}: column '{tcol.name}'",
            resolution=table.resolution(tcol) * factor,
            stated=m.fs,
            stated_by=f"the map's fs ({m.source})",
        )
    elif m.fs is not None:
        fs = m.fs
    else:
        raise InputError(f"{src}: expected a time column (t, time) or fs in the map, got neither")

    def matrix(key: str) -> np.ndarray:
        cols = [table.values(c) * table.unit(c, key, U.CHANNEL, m) for _, c in roles[key]]
        return np.column_stack(cols)

    u, y = matrix("u"), matrix("y")
    in_names = [name for name, _ in roles["u"]]
    r = None
    if roles["r"]:
        r_names = [name for name, _ in roles["r"]]
        if "r" not in m.variables:
            if sorted(r_names) != sorted(in_names):
                raise InputError(
                    f"{src}: expected one r_<name> column per input ({', '.join(in_names)}), got "
                    f"r columns for {', '.join(r_names)}"
                )
            order = [r_names.index(name) for name in in_names]
            roles["r"] = [roles["r"][k] for k in order]
        elif len(r_names) != len(in_names):
            raise InputError(
                f"{m.where('variables.r')}: expected {len(in_names)} columns (one per input), "
                f"got {len(r_names)}"
            )
        r = matrix("r")
    data = time_data(
        src,
        m,
        fs=fs,
        u=u,
        y=y,
        r=r,
        input_names=in_names,
        output_names=[name for name, _ in roles["y"]],
    )
    return Imported(data, tuple(notes), f"CSV time record, {u.shape[0]} samples")


def _frf(table: _Table, fcol: _Column, m: ImportMap) -> Imported:
    src = table.path
    for key in ("u", "y", "r", "t"):
        if key in m.variables:
            raise InputError(f"{m.where('variables.' + key)}: does not apply to an FRF CSV file")
    elements: dict[tuple[str, str], dict[str, _Column]] = {}
    variances: dict[tuple[str, str], _Column] = {}
    outputs: list[str] = []
    inputs: list[str] = []
    for col in table.columns:
        if col is fcol:
            continue
        g, gv = _G.match(col.name), _GVAR.match(col.name)
        if g is None and gv is None:
            raise InputError(
                f"{src}: column '{col.name}': expected G_<output>_<input>_<part> (part re, im, mag "
                f"or phase) or Gvar_<output>_<input> in an FRF file, got {col.name!r} "
                f"(the convention: {_CONVENTION})"
            )
        match = g or gv
        pair = (match["out"], match["inp"])
        outputs += [] if pair[0] in outputs else [pair[0]]
        inputs += [] if pair[1] in inputs else [pair[1]]
        if g is not None:
            elements.setdefault(pair, {})[g["part"]] = col
        else:
            variances[pair] = col
    if not elements:
        raise InputError(f"{src}: expected FRF columns G_<output>_<input>_<part>, got none")
    factor = table.unit(fcol, "freq", U.FREQUENCY, m)
    freq, dropped = frequency_lines(table.values(fcol) * factor, f"{src}: column '{fcol.name}'")
    keep = slice(1, None) if dropped else slice(None)
    n_f = freq.size
    G = np.empty((n_f, len(outputs), len(inputs)), dtype=complex)
    G_var = np.empty(G.shape) if variances else None
    for j, out in enumerate(outputs):
        for i, inp in enumerate(inputs):
            parts = elements.get((out, inp), {})
            name = f"G_{out}_{inp}"
            if set(parts) == {"re", "im"}:
                re_, im_ = (
                    table.values(parts[p])[keep] * table.unit(parts[p], "G", U.FRF, m)
                    for p in ("re", "im")
                )
                G[:, j, i] = re_ + 1j * im_
            elif set(parts) == {"mag", "phase"}:
                mag = table.values(parts["mag"])[keep] * table.unit(parts["mag"], "G", U.FRF, m)
                phase = table.values(parts["phase"])[keep] * table.unit(
                    parts["phase"], "phase", U.ANGLE, m
                )
                G[:, j, i] = mag * np.exp(1j * phase)
            else:
                got = ", ".join(f"{name}_{p}" for p in parts) or "none"
                raise InputError(
                    f"{src}: expected columns {name}_re and {name}_im, or {name}_mag and "
                    f"{name}_phase (every output/input pair, {len(outputs)} x {len(inputs)}), "
                    f"got {got}"
                )
            if G_var is not None:
                if (out, inp) not in variances:
                    raise InputError(
                        f"{src}: expected a Gvar column for every element or none, got none for "
                        f"Gvar_{out}_{inp}"
                    )
                col = variances[(out, inp)]
                G_var[:, j, i] = table.values(col)[keep] * table.unit(
                    col, "G_var", U.FRF_VARIANCE, m
                )
    notes = ["dropped the 0 Hz line (the spec's lines are > 0 Hz)"] if dropped else []
    data = frf_data(src, m, freq=freq, G=G, G_var=G_var, input_names=inputs, output_names=outputs)
    return Imported(data, tuple(notes), f"CSV FRF, {n_f} lines")
