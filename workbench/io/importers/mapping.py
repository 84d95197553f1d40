"""The import map: what a data file does not say (``--map MAP.toml``, read with tomllib).

Every key is optional; a key the file also states must agree with it (a
disagreement is refused, never settled silently)::

    kind = "time"            # "time" or "frf": picks one kind when a file holds both
    fs = 2000.0              # sampling frequency, Hz
    loop = "closed"          # "open" or "closed"
    period = 1000            # samples per period of a periodic excitation
    struct = "meas"          # .mat: the struct whose fields are the spec keys
    input_names = ["Fx", "Fy"]     # channel names, in the file's order
    output_names = ["x", "y"]

    [variables]              # spec key = where it is in the file
    u = ["force_x", "force_y"]     # .mat variables ("meas.F", "F(:,2)"), CSV columns,
    y = "meas.disp"                # UFF channels ("101+Z" or entity name), or a
                                   # headerless table's column numbers (u = [1, 2])
    t = "time"                     # time axis (.mat, CSV)
    freq = "w"                     # frequency axis (.mat, CSV)
    G = "H"                        # FRF array (.mat)

    [units]                  # source or spec key = unit (see workbench.io.importers.units)
    force_x = "N"
    y = "um"
    w = "rad/s"

``u``, ``y`` and ``r`` take a list of one-channel sources, stacked as columns
in that order, or one source holding all channels; the other keys one source.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from workbench.core.errors import InputError

__all__ = ["ImportMap", "read_map", "map_from_dict", "CHANNEL_KEYS", "VARIABLE_KEYS"]

CHANNEL_KEYS = ("u", "y", "r")
VARIABLE_KEYS = (
    *CHANNEL_KEYS,
    "t",
    "fs",
    "freq",
    "G",
    "G_var",
    "input_names",
    "output_names",
    "kind",
    "loop",
    "period",
)
_TOP_KEYS = (
    "kind",
    "fs",
    "loop",
    "period",
    "struct",
    "input_names",
    "output_names",
    "variables",
    "units",
)


@dataclass(frozen=True)
class ImportMap:
    """What a data file does not say, from a map file.

    Attributes
    ----------
    source : str
        The map file's name (for messages); ``"map"`` for a map built in code.
    kind : {"time", "frf"} or None
    fs : float or None
        Sampling frequency, Hz.
    loop : {"open", "closed"} or None
    period : int or None
        Samples per period.
    struct : str or None
        .mat files: the struct variable whose fields are the spec keys.
    input_names, output_names : tuple of str or None
        Channel names in the file's order.
    variables : dict
        Spec key -> source (str), or a tuple of sources for ``u``, ``y``, ``r``.
    units : dict
        Source or spec key -> unit string.
    """

    source: str = "map"
    kind: str | None = None
    fs: float | None = None
    loop: str | None = None
    period: int | None = None
    struct: str | None = None
    input_names: tuple[str, ...] | None = None
    output_names: tuple[str, ...] | None = None
    variables: dict[str, str | tuple[str, ...]] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)

    def where(self, key: str) -> str:
        """``"<map file>: key '<key>'"``, the start of a refusal about one key."""
        return f"{self.source}: key '{key}'"

    def unit(self, *labels: str) -> tuple[str, str] | None:
        """The first of ``labels`` that ``[units]`` names, as (label, unit), or None."""
        for label in labels:
            if label in self.units:
                return label, self.units[label]
        return None

    def refuse_variables(self, keys, fmt: str) -> None:
        """Refuse ``[variables]`` keys that do not apply to a file format ``fmt``."""
        for key in self.variables:
            if key in keys:
                raise InputError(
                    f"{self.where('variables.' + key)}: does not apply to {fmt}, "
                    "which says it itself"
                )


def _str(value, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{where}: expected a non-empty string, got {value!r}")
    return value.strip()


def _source(value, where: str) -> str:
    """A source's name, or a column number (a headerless table's, from 1) as its text."""
    if isinstance(value, int) and not isinstance(value, bool):
        if value < 1:
            raise InputError(f"{where}: expected a column number >= 1, got {value}")
        return str(value)
    return _str(value, where)


def _names(value, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not value:
        raise InputError(f"{where}: expected a list of channel names, got {value!r}")
    names = tuple(_str(v, where) for v in value)
    if len(set(names)) != len(names):
        raise InputError(f"{where}: expected distinct channel names, got {list(names)}")
    return names


def map_from_dict(raw: dict, source: str = "map") -> ImportMap:
    """Check a map's keys and values (a dict as tomllib reads it) and build the ImportMap."""

    def where(key: str) -> str:
        return f"{source}: key '{key}'"

    unknown = sorted(set(raw) - set(_TOP_KEYS))
    if unknown:
        raise InputError(f"{where(unknown[0])}: expected one of {', '.join(_TOP_KEYS)}")
    kind = raw.get("kind")
    if kind is not None and kind not in ("time", "frf"):
        raise InputError(f"{where('kind')}: expected 'time' or 'frf', got {kind!r}")
    loop = raw.get("loop")
    if loop is not None and loop not in ("open", "closed"):
        raise InputError(f"{where('loop')}: expected 'open' or 'closed', got {loop!r}")
    fs = raw.get("fs")
    if fs is not None:
        if isinstance(fs, bool) or not isinstance(fs, int | float) or not 0 < fs < float("inf"):
            raise InputError(f"{where('fs')}: expected a sampling frequency > 0 Hz, got {fs!r}")
        fs = float(fs)
    period = raw.get("period")
    if period is not None and (isinstance(period, bool) or not isinstance(period, int)):
        raise InputError(f"{where('period')}: expected an integer (samples), got {period!r}")
    struct = raw.get("struct")
    if struct is not None:
        struct = _str(struct, where("struct"))
    names = {
        key: None if raw.get(key) is None else _names(raw[key], where(key))
        for key in ("input_names", "output_names")
    }
    variables: dict[str, str | tuple[str, ...]] = {}
    table = raw.get("variables", {})
    if not isinstance(table, dict):
        raise InputError(f"{where('variables')}: expected a table [variables], got {table!r}")
    for key, value in table.items():
        w = where(f"variables.{key}")
        if key not in VARIABLE_KEYS:
            raise InputError(f"{w}: expected one of the spec keys {', '.join(VARIABLE_KEYS)}")
        if isinstance(value, list) and key in CHANNEL_KEYS:
            if not value:
                raise InputError(f"{w}: expected at least one source, got an empty list")
            variables[key] = tuple(_source(v, w) for v in value)
        else:
            variables[key] = _source(value, w)
    units = raw.get("units", {})
    if not isinstance(units, dict):
        raise InputError(f"{where('units')}: expected a table [units], got {units!r}")
    units = {str(k): _str(v, where(f"units.{k}")) for k, v in units.items()}
    return ImportMap(
        source=source,
        kind=kind,
        fs=fs,
        loop=loop,
        period=period,
        struct=struct,
        input_names=names["input_names"],
        output_names=names["output_names"],
        variables=variables,
        units=units,
    )


def read_map(path: str | os.PathLike) -> ImportMap:
    """Read a map file (TOML). Refused with one line: a missing file, bad TOML, bad keys."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with open(p, "rb") as fh:
            raw = tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: expected a TOML map file, got invalid TOML ({exc})") from None
    return map_from_dict(raw, source=str(path))
