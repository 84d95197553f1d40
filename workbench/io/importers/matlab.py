"""MATLAB .mat files: v4-v7 through ``scipy.io.loadmat``, v7.3 (HDF5) through h5py; export as v5.

Reading
-------
Without a map, variables named as the spec's keys import directly, in SI as
the spec says:

- time record: ``u``, ``y`` (N x channels, samples along the rows), ``fs``
  (Hz), optional ``r``, ``loop``, ``period``;
- FRF: ``freq`` (Hz), ``G`` (n_f x n_y x n_u; MATLAB drops trailing singleton
  dimensions, so an n_f x n_y matrix is one input and a vector one element),
  optional ``G_var``, ``fs``;
- optional ``kind`` (else told from the keys), ``input_names`` and
  ``output_names`` (a cell array of char, or a char matrix).

The keys may sit in a struct (``meas.u``, ``meas.y``, ...): a file whose top
level holds none of them and exactly one struct that does is read from that
struct; the map's ``struct`` picks one among several.

A map's ``[variables]`` names other variables, from the file's top level: a
variable, a struct field (``meas.force``), a column (``force(:,2)``, 1-based),
or, for ``u``, ``y``, ``r``, a list of one-channel vectors (named after
them). A variable taken under another name than the spec key needs its unit
in the map's ``[units]`` (``force = "N"``, ``w = "rad/s"``), except ``fs``
(Hz), ``period``, names, ``kind`` and ``loop``, which carry none. A time axis
``t`` may stand in for ``fs``; it must be uniform.

Vectors may be rows or columns. A channel matrix with more columns than rows
(channels as rows?) is refused: transpose it.

Writing
-------
A v5 .mat (``scipy.io.savemat``) with the spec keys: measurement keys (names
as cell arrays of char, vectors as columns), or a model's ``A``, ``B``,
``C``, ``D``, ``dt``, ``input_names``, ``output_names`` (and ``delay_s``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workbench.core.atomic import atomic_path
from workbench.core.errors import InputError

from . import units as U
from .axes import frequency_lines, rate_from_time_axis
from .build import Imported, frf_data, settle, time_data
from .mapping import ImportMap

__all__ = ["read_mat", "write_mat", "mat_arrays"]

_SPEC_KEYS = ("u", "y", "freq", "G")
_NUMERIC = {"double", "single", "logical", "char"} | {
    f"{s}int{b}" for s in ("", "u") for b in (8, 16, 32, 64)
}
_SOURCE = re.compile(
    r"^(?P<path>[A-Za-z]\w*(?:\.[A-Za-z]\w*)*)(?:\(\s*:\s*,\s*(?P<col>\d+)\s*\))?$"
)
_NO_UNIT = ("fs", "period", "input_names", "output_names", "kind", "loop")


@dataclass(frozen=True)
class _Text:
    """A MATLAB char array: its rows."""

    rows: tuple[str, ...]


@dataclass(frozen=True)
class _Unsupported:
    """A value the reader cannot use (an object, a struct array), kept to name it if asked for."""

    what: str


# --------------------------------------------------------------------- loading
def _from_v5(value):
    from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque

    if isinstance(value, MatlabObject):
        return _Unsupported(f"an object of class {value.classname}")
    if isinstance(value, MatlabOpaque | MatlabFunction):
        return _Unsupported("a MATLAB object (a string, a function handle or a class instance)")
    if not isinstance(value, np.ndarray):
        return _Unsupported(type(value).__name__)
    if value.dtype.names is not None:
        if value.size != 1:
            return _Unsupported(f"a struct array of size {'x'.join(map(str, value.shape))}")
        record = value.reshape(-1)[0]
        return {name: _from_v5(record[name]) for name in value.dtype.names}
    if value.dtype.kind == "O":
        return [_from_v5(v) for v in value.reshape(-1, order="F")]
    if value.dtype.kind == "U":
        return _Text(tuple(str(s) for s in value.reshape(-1)))
    if value.dtype.kind in "biufc":
        return value
    return _Unsupported(f"an array of dtype {value.dtype}")


def _load_v5(path: Path) -> dict:
    from scipy.io import loadmat

    try:
        raw = loadmat(str(path), squeeze_me=False, chars_as_strings=True, struct_as_record=True)
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError ... on bad files
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(
            f"{path}: expected a MATLAB .mat file, got an unreadable one ({msg})"
        ) from None
    return {k: _from_v5(v) for k, v in raw.items() if not k.startswith("__")}


def _h5_class(obj) -> str | None:
    cls = obj.attrs.get("MATLAB_class")
    return cls.decode() if isinstance(cls, bytes) else cls


def _from_h5(f, obj):
    import h5py

    cls = _h5_class(obj)
    if isinstance(obj, h5py.Group):
        if "MATLAB_sparse" in obj.attrs:
            return _Unsupported(f"a sparse {cls} matrix (save it with full())")
        if cls in (None, "struct"):
            return {k: _from_h5(f, obj[k]) for k in obj}
        return _Unsupported(f"a MATLAB {cls} object")
    if obj.attrs.get("MATLAB_empty", 0):
        return _Text(()) if cls == "char" else np.zeros((0, 0))
    value = obj[()]
    if cls == "cell" or (isinstance(value, np.ndarray) and h5py.check_dtype(ref=value.dtype)):
        # stored transposed: the stored array's C order is MATLAB's column order
        return [_from_h5(f, f[ref]) for ref in np.asarray(value).reshape(-1)]
    value = np.asarray(value)
    if cls == "char":
        codes = np.atleast_2d(value.T)
        return _Text(tuple("".join(chr(int(c)) for c in row) for row in codes))
    if value.dtype.names is not None and {"real", "imag"} <= set(value.dtype.names):
        value = value["real"] + 1j * value["imag"]
    if cls is not None and cls not in _NUMERIC:
        return _Unsupported(f"a MATLAB {cls}")
    if value.dtype.kind not in "biufc":
        return _Unsupported(f"an HDF5 dataset of dtype {value.dtype}")
    return value.T  # MATLAB's column-major dims, stored reversed


def _load_v73(path: Path) -> dict:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return {k: _from_h5(f, f[k]) for k in f if not k.startswith("#")}
    except (OSError, KeyError, ValueError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(
            f"{path}: expected a MATLAB v7.3 (HDF5) .mat file, got an unreadable one ({msg})"
        ) from None


def load_mat(path: str | Path) -> tuple[dict, str]:
    """A .mat file's variables as a tree (structs as dicts, cells as lists), and its version."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if h5py.is_hdf5(path):
        return _load_v73(path), "v7.3"
    return _load_v5(path), "v5"


# ------------------------------------------------------------------ resolving
def _listing(tree: dict, prefix: str = "") -> list[str]:
    out = []
    for name, value in tree.items():
        out.append(prefix + name)
        if isinstance(value, dict):
            out += _listing(value, prefix + name + ".")
    return out


def _what(value) -> str:
    if isinstance(value, _Unsupported):
        return value.what
    if isinstance(value, dict):
        return "a struct"
    if isinstance(value, list):
        return f"a cell array of {len(value)}"
    if isinstance(value, _Text):
        return f"text {value.rows[0]!r}" if len(value.rows) == 1 else "a char matrix"
    return f"a {'x'.join(map(str, value.shape))} {value.dtype} array"


def _resolve(tree: dict, source: str, path: Path, m: ImportMap, key: str):
    match = _SOURCE.match(source)
    if match is None:
        raise InputError(
            f"{m.where(key)}: expected a variable, a struct field (a.b) or a column (a(:,2)), "
            f"got {source!r}"
        )
    node, walked = tree, []
    for part in match["path"].split("."):
        walked.append(part)
        if not isinstance(node, dict) or part not in node:
            have = _listing(tree)
            listed = ", ".join(have[:20]) + (", ..." if len(have) > 20 else "")
            raise InputError(
                f"{m.where(key)}: variable {'.'.join(walked)!r} is not in {path} "
                f"(variables: {listed or 'none'})"
            )
        node = node[part]
    if match["col"] is None:
        return node
    a = _numeric(node, f"{path}: variable '{match['path']}'")
    col = int(match["col"])
    if a.ndim != 2 or not 1 <= col <= a.shape[1]:
        raise InputError(
            f"{m.where(key)}: expected a column 1..{a.shape[1] if a.ndim == 2 else 0} of "
            f"'{match['path']}', got {source!r} ({_what(a)})"
        )
    return a[:, col - 1 : col]


def _numeric(value, where: str) -> np.ndarray:
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "biufc":
        raise InputError(f"{where}: expected a numeric array, got {_what(value)}")
    return value.astype(float) if value.dtype.kind in "biu" else value


def _real(value, where: str) -> np.ndarray:
    a = _numeric(value, where)
    if np.iscomplexobj(a):
        raise InputError(f"{where}: expected real values, got {_what(a)}")
    return a


def _vector(value, where: str) -> np.ndarray:
    a = _numeric(value, where)
    if sum(n > 1 for n in a.shape) > 1:
        raise InputError(f"{where}: expected a vector, got {_what(a)}")
    return a.reshape(-1)


def _scalar(value, where: str) -> float:
    a = _real(value, where)
    if a.size != 1:
        raise InputError(f"{where}: expected a scalar, got {_what(a)}")
    return float(a.reshape(-1)[0])


def _channels(value, where: str) -> np.ndarray:
    a = _real(value, where)
    if a.ndim == 1 or (a.ndim == 2 and a.shape[0] == 1):
        return a.reshape(-1, 1)
    if a.ndim != 2:
        raise InputError(f"{where}: expected an N x channels matrix, got {_what(a)}")
    if a.shape[0] < a.shape[1]:
        raise InputError(
            f"{where}: expected samples along the rows (N x channels), got {a.shape[0]}x"
            f"{a.shape[1]}: transpose it"
        )
    return a


def _text(value, where: str) -> str:
    if not isinstance(value, _Text) or len(value.rows) != 1:
        raise InputError(f"{where}: expected text, got {_what(value)}")
    return value.rows[0]


def _names(value, where: str) -> tuple[str, ...]:
    if isinstance(value, _Text):
        return tuple(row.rstrip() for row in value.rows)  # a char matrix pads its rows
    if isinstance(value, list) and all(isinstance(v, _Text) and len(v.rows) <= 1 for v in value):
        return tuple(v.rows[0] if v.rows else "" for v in value)
    raise InputError(
        f"{where}: expected a cell array of char (or a char matrix), got {_what(value)}"
    )


class _Variables:
    """The spec keys of one .mat file: where each is (the map, a struct, the top level)."""

    def __init__(self, path: Path, tree: dict, m: ImportMap):
        self.path, self.tree, self.m = path, tree, m
        self.root, self.prefix = tree, ""
        if m.struct is not None:
            self.root = _resolve(tree, m.struct, path, m, "struct")
            if not isinstance(self.root, dict):
                raise InputError(f"{m.where('struct')}: expected a struct, got {_what(self.root)}")
            self.prefix = m.struct + "."
        elif not any(k in tree for k in _SPEC_KEYS):
            holders = [
                k
                for k, v in tree.items()
                if isinstance(v, dict) and any(s in v for s in _SPEC_KEYS)
            ]
            if len(holders) > 1:
                raise InputError(
                    f"{path}: expected one struct holding the spec keys, got {len(holders)} "
                    f"({', '.join(holders)}): name one with struct in the map"
                )
            if holders:
                self.root, self.prefix = tree[holders[0]], holders[0] + "."

    def get(self, key: str):
        """(label, value, mapped) of a spec key, or None; a list of sources gives lists."""
        source = self.m.variables.get(key)
        if isinstance(source, tuple):
            values = [_resolve(self.tree, s, self.path, self.m, f"variables.{key}") for s in source]
            return list(source), values, True
        if source is not None:
            return source, _resolve(self.tree, source, self.path, self.m, f"variables.{key}"), True
        if key in self.root:
            return self.prefix + key, self.root[key], False
        return None

    def where(self, label: str) -> str:
        return f"{self.path}: variable '{label}'"

    def factor(self, key: str, label: str, mapped: bool, expect) -> float:
        """SI factor of a variable: the map's [units], else 1 (spec-named), else refused."""
        by_map = self.m.unit(label, key)
        if by_map is not None:
            return U.si_factor(by_map[1], expect, self.m.where("units." + by_map[0]))
        plain = label.split("(")[0].split(".")[-1]
        if mapped and plain != key and key not in _NO_UNIT:
            raise InputError(
                f"{self.where(label)}: expected its unit in the map's [units] "
                f'(e.g. {key} = "{_EXAMPLE[expect]}" or "{label}" = "{_EXAMPLE[expect]}"), '
                "got none"
            )
        return 1.0

    def channels(self, key: str) -> tuple[np.ndarray, list[str]] | None:
        """(N, n) channels of u, y or r in SI, and the names a list of sources gives."""
        got = self.get(key)
        if got is None:
            return None
        label, value, mapped = got
        if not isinstance(label, list):
            return _channels(value, self.where(label)) * self.factor(
                key, label, mapped, U.CHANNEL
            ), []
        cols = [
            _vector(_real(v, self.where(s)), self.where(s)) * self.factor(key, s, mapped, U.CHANNEL)
            for s, v in zip(label, value)
        ]
        lengths = [c.size for c in cols]
        if min(lengths) != max(lengths):
            a, b = int(np.argmin(lengths)), int(np.argmax(lengths))
            raise InputError(
                f"{self.path}: channels of unequal length: variable '{label[a]}' has "
                f"{lengths[a]} samples, variable '{label[b]}' has {lengths[b]}"
            )
        return np.column_stack(cols), [s.split("(")[0].split(".")[-1] for s in label]


_EXAMPLE = {U.CHANNEL: "m", U.TIME: "s", U.FREQUENCY: "Hz", U.FRF: "m/N", U.FRF_VARIANCE: "(m/N)^2"}


def read_mat(path: str | Path, m: ImportMap) -> Imported:
    """Read a .mat file (v4-v7.3) into one measurement (spec 1a or 1b)."""
    path = Path(path)
    tree, version = load_mat(path)
    v = _Variables(path, tree, m)
    notes = (
        [f"read the fields of struct '{v.prefix[:-1]}'"] if v.prefix and m.struct is None else []
    )
    kind = None
    got = v.get("kind")
    if got is not None:
        kind = _text(got[1], v.where(got[0]))
        if kind not in ("time", "frf"):
            raise InputError(f"{v.where(got[0])}: expected 'time' or 'frf', got {kind!r}")
    kind = settle(kind, m.kind, m, "kind", str(path))
    if kind is None:
        is_time = v.get("u") is not None or v.get("y") is not None
        is_frf = v.get("G") is not None or v.get("freq") is not None
        if is_time and is_frf:
            raise InputError(
                f"{path}: expected a time record (u, y) or an FRF (freq, G), got both: say "
                "which with kind in the map"
            )
        if not is_time and not is_frf:
            have = ", ".join(_listing(tree)[:20]) or "none"
            raise InputError(
                f"{path}: expected variables u and y (a time record) or freq and G (an FRF), "
                f"or a map naming them, got variables: {have}"
            )
        kind = "time" if is_time else "frf"
    read = _read_time if kind == "time" else _read_frf
    data, more = read(v)
    return Imported(data, tuple(notes + more), f"MATLAB {version} .mat")


def _need(v: _Variables, key: str, what: str):
    got = v.get(key)
    if got is None:
        have = ", ".join(_listing(v.root)[:20]) or "none"
        raise InputError(
            f"{v.path}: missing variable '{v.prefix}{key}' ({what}); variables: {have}"
        )
    return got


def _names_of(v: _Variables, key: str, fallback: list[str]) -> list[str] | tuple[str, ...]:
    got = v.get(key)
    return fallback if got is None else _names(got[1], v.where(got[0]))


def _read_time(v: _Variables) -> tuple:
    path, m = v.path, v.m
    _need(v, "u", "(N, n_u) plant input")
    _need(v, "y", "(N, n_y) measured output")
    u, u_names = v.channels("u")
    y, y_names = v.channels("y")
    if y.shape[0] != u.shape[0]:
        raise InputError(
            f"{path}: channels of unequal length: u has {u.shape[0]} samples, y has {y.shape[0]}"
        )
    got_r = v.channels("r")
    r = None
    if got_r is not None:
        r = got_r[0]
        if r.shape != u.shape:
            raise InputError(
                f"{path}: variable 'r': expected {u.shape[0]}x{u.shape[1]} like u, got "
                f"{r.shape[0]}x{r.shape[1]}"
            )
    fs = None
    got = v.get("fs")
    if got is not None:
        fs = _scalar(got[1], v.where(got[0]))
        fs = settle(fs, m.fs, m, "fs", v.where(got[0]))
    got = v.get("t")
    if got is not None:
        t = _vector(_real(got[1], v.where(got[0])), v.where(got[0]))
        t = t * v.factor("t", got[0], got[2], U.TIME)
        if t.size != u.shape[0]:
            raise InputError(
                f"{v.where(got[0])}: expected {u.shape[0]} instants like u, got {t.size}"
            )
        stated = fs if fs is not None else m.fs
        by = "variable 'fs'" if fs is not None else f"the map's fs ({m.source})"
        fs = rate_from_time_axis(t, v.where(got[0]), stated=stated, stated_by=by)
    if fs is None:
        fs = m.fs
    if fs is None:
        raise InputError(
            f"{path}: missing variable '{v.prefix}fs' (sampling frequency, Hz) or a time axis "
            "t; or fs in the map"
        )
    loop = period = None
    got = v.get("loop")
    if got is not None:
        loop = _text(got[1], v.where(got[0]))
    got = v.get("period")
    if got is not None:
        p = _scalar(got[1], v.where(got[0]))
        if p != int(p):
            raise InputError(f"{v.where(got[0])}: expected an integer number of samples, got {p:g}")
        period = int(p)
    data = time_data(
        str(path),
        m,
        fs=fs,
        u=u,
        y=y,
        r=r,
        loop=loop,
        period=period,
        input_names=_names_of(v, "input_names", u_names),
        output_names=_names_of(v, "output_names", y_names),
    )
    return data, []


def _frf_array(value, where: str, n_f: int, real: bool) -> np.ndarray:
    a = _real(value, where) if real else _numeric(value, where)
    if a.ndim == 2 and a.shape[0] == 1 and a.shape[1] == n_f and n_f > 1:
        a = a.reshape(n_f)  # a row vector: one element
    if a.ndim == 1:
        a = a.reshape(-1, 1)
    if a.ndim == 2:
        a = a[:, :, None]  # MATLAB dropped the trailing singleton n_u = 1
    if a.ndim != 3 or a.shape[0] != n_f:
        raise InputError(
            f"{where}: expected {n_f} frequency lines along the first dimension (n_f x n_y x n_u) "
            f"like freq, got {_what(a)}"
        )
    return a


def _read_frf(v: _Variables) -> tuple:
    path, m = v.path, v.m
    label, value, mapped = _need(v, "freq", "(n_f,) frequency lines, Hz")
    f = _vector(_real(value, v.where(label)), v.where(label)) * v.factor(
        "freq", label, mapped, U.FREQUENCY
    )
    freq, dropped = frequency_lines(f, v.where(label))
    keep = slice(1, None) if dropped else slice(None)
    label, value, mapped = _need(v, "G", "(n_f, n_y, n_u) complex response")
    G = _frf_array(value, v.where(label), f.size, real=False)[keep] * v.factor(
        "G", label, mapped, U.FRF
    )
    G_var = None
    got = v.get("G_var")
    if got is not None:
        label, value, mapped = got
        G_var = _frf_array(value, v.where(label), f.size, real=True)[keep]
        G_var = G_var * v.factor("G_var", label, mapped, U.FRF_VARIANCE)
    fs = None
    got = v.get("fs")
    if got is not None:
        fs = _scalar(got[1], v.where(got[0]))
    data = frf_data(
        str(path),
        m,
        freq=freq,
        G=G,
        G_var=G_var,
        fs=fs,
        input_names=_names_of(v, "input_names", []),
        output_names=_names_of(v, "output_names", []),
    )
    return data, ["dropped the 0 Hz line (the spec's lines are > 0 Hz)"] if dropped else []


# --------------------------------------------------------------------- writing
def mat_arrays(arrays: dict[str, np.ndarray]) -> dict:
    """Spec arrays (``measurement_arrays``, a model file's arrays) as savemat takes them:
    names and other string lists as cell arrays of char, a string as char, numbers unchanged."""
    out = {}
    for key, a in arrays.items():
        a = np.asarray(a)
        if key in ("input_names", "output_names") or (a.dtype.kind in "US" and a.ndim):
            cell = np.empty(a.size, dtype=object)
            cell[:] = [str(s) for s in a.reshape(-1)]
            out[key] = cell
        elif a.dtype.kind in "US":
            out[key] = str(a)
        else:
            out[key] = a
    return out


def write_mat(path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    """Write spec arrays to a v5 .mat file, atomically (vectors as columns, compressed)."""
    from scipy.io import savemat

    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        savemat(fh, mat_arrays(arrays), format="5", oned_as="column", do_compression=True)
