"""Data from modal-test systems, MATLAB and spreadsheets into the spec's files, and back.

| format | suffix | import | export |
|---|---|---|---|
| universal file 58 (:mod:`.uff`) | ``.uff``, ``.unv`` | FRFs, time records | the same, exact |
| MATLAB (:mod:`.matlab`) | ``.mat`` | v4-v7, v7.3 (HDF5) | v5: measurements, models |
| CSV with a header (:mod:`.csvfile`) | ``.csv``, ``.tsv`` | FRFs, time records | |
| numeric table, no header (:mod:`.table`) | ``.dat``, ``.txt``, ``.asc`` | time records | |

Every import ends in a :class:`~workbench.io.formats.TimeData` or
:class:`~workbench.io.formats.FrfData` in SI units, written by
:func:`~workbench.io.formats.save_measurement`. What a file does not say (which
variable or column is which channel, ``fs``, units) comes from a map file
(:mod:`.mapping`). A malformed or ambiguous file is refused with one
:class:`~workbench.core.errors.InputError` line naming the file, the field and
what was expected; nothing is guessed.
"""

from __future__ import annotations

import os
from pathlib import Path

from workbench.core.errors import InputError
from workbench.io.formats import Measurement, load_any, measurement_arrays, read_npz

from .build import Imported
from .mapping import ImportMap, map_from_dict, read_map

__all__ = [
    "Imported",
    "ImportMap",
    "read_map",
    "import_file",
    "read_data_file",
    "export_file",
    "export_format",
    "IMPORT_SUFFIXES",
    "EXPORT_SUFFIXES",
]

IMPORT_SUFFIXES = {
    ".uff": "uff",
    ".unv": "uff",
    ".mat": "mat",
    ".csv": "csv",
    ".tsv": "csv",
    ".dat": "table",
    ".txt": "table",
    ".asc": "table",
}
EXPORT_SUFFIXES = {".uff": "uff", ".unv": "uff", ".mat": "mat"}


def _as_map(map) -> ImportMap:
    if map is None:
        return ImportMap()
    if isinstance(map, ImportMap):
        return map
    if isinstance(map, dict):
        return map_from_dict(map)
    return read_map(map)


def read_data_file(path: str | os.PathLike, map=None) -> Imported:
    """Read a UFF, .mat, CSV or headerless table into a measurement, with notes.

    Parameters
    ----------
    path : path
        The data file; its suffix names the format (``.uff``/``.unv``, ``.mat``,
        ``.csv``/``.tsv``, ``.dat``/``.txt``/``.asc``: a table without a header).
    map : ImportMap, dict, path or None
        What the file does not say (:mod:`.mapping`): a map file's path, its
        contents as a dict, or an ImportMap.
    """
    fmt = IMPORT_SUFFIXES.get(Path(path).suffix.lower())
    if fmt is None:
        raise InputError(
            f"{path}: expected a file ending in .uff or .unv (universal file), .mat (MATLAB), "
            f".csv/.tsv or .dat/.txt/.asc (a table without a header), got "
            f"{Path(path).suffix or 'no suffix'!r}"
        )
    m = _as_map(map)
    if fmt == "uff":
        from .uff import read_uff

        return read_uff(path, m)
    if fmt == "mat":
        from .matlab import read_mat

        return read_mat(path, m)
    if not Path(path).is_file():
        raise InputError(f"{path}: no such file")
    if fmt == "table":
        from .table import read_table

        return read_table(path, m)
    from .csvfile import read_csv

    return read_csv(path, m)


def import_file(path: str | os.PathLike, map=None) -> Measurement:
    """The measurement (TimeData or FrfData, SI) in a UFF, .mat, CSV or table file."""
    return read_data_file(path, map).data


def export_format(out: str | os.PathLike) -> str:
    """``"uff"`` or ``"mat"`` from an output's suffix; refused for any other."""
    fmt = EXPORT_SUFFIXES.get(Path(out).suffix.lower())
    if fmt is None:
        raise InputError(
            f"{out}: expected an output ending in .uff or .unv (universal file) or .mat "
            f"(MATLAB), got {Path(out).suffix or 'no suffix'!r}"
        )
    return fmt


def export_file(src: str | os.PathLike, out: str | os.PathLike) -> tuple[str, ...]:
    """Write a measurement or model file (spec 1 or 2) as UFF58 or .mat; return notes.

    FRFs and time records go to either; a model (A, B, C, D, dt, names and any
    further keys of its file, e.g. a controller's ``role``) to .mat only.
    """
    from workbench.core.model import LTIModel

    from .matlab import write_mat
    from .uff import write_uff

    fmt = export_format(out)
    obj = load_any(src)
    if isinstance(obj, LTIModel):
        if fmt == "uff":
            raise InputError(
                f"{out}: expected .mat for a model: a universal file's dataset 58 holds "
                "functions (FRFs, time records), not state-space matrices"
            )
        write_mat(out, read_npz(src))
        return ()
    if fmt == "uff":
        return write_uff(out, obj)
    write_mat(out, measurement_arrays(obj))
    return ()
