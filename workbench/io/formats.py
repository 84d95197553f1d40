"""Exchange formats: measurement files, model files (``shared/spec/data-format.md``).

Readers validate at the boundary and refuse bad files with a one-line
:class:`~workbench.core.errors.InputError` naming the file, the key, what was
expected and what came. Nothing is ever unpickled: ``allow_pickle`` stays
False, and every array header is checked against the archive before a byte of
data is read, so a truncated file or an absurd header is refused, not obeyed.

The in-memory types are frozen dataclasses holding read-only copies:
:class:`TimeData` (``kind = "time"``) and :class:`FrfData` (``kind = "frf"``).
Models are :class:`~workbench.core.model.LTIModel` (:func:`read_model`, with the
exact delay of the ``delay_s`` key); :func:`load_model` gives the rational part
as a python-control ``StateSpace`` with the channel names as its labels.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from workbench.core.arrays import readonly
from workbench.core.atomic import save_npz
from workbench.core.errors import InputError, describe

__all__ = [
    "TimeData",
    "FrfData",
    "load_measurement",
    "save_measurement",
    "load_model",
    "read_model",
    "save_model",
    "save_controller",
    "lti_model_from_arrays",
    "load_any",
    "model_names",
    "check_model_matches",
    "read_npz",
]


# --------------------------------------------------------------------- helpers
def _names(
    names, n: int, default: str, src: str = "channel names", key: str = ""
) -> tuple[str, ...]:
    if names is None or len(names) == 0:
        return tuple(f"{default}{i}" for i in range(n))
    names = tuple(str(s) for s in names)
    if len(names) != n:
        where = f"{src}: key '{key}'" if key else src
        raise InputError(f"{where}: expected {n} names, got {len(names)}")
    return names


def _store_channel_names(obj, n_u: int, n_y: int, src: str) -> None:
    """Check and store a measurement's ``input_names`` (n_u, default u0, u1, ...) and
    ``output_names`` (n_y, default y0, ...) on the frozen ``obj``."""
    for key, n, default in (("input_names", n_u, "u"), ("output_names", n_y, "y")):
        object.__setattr__(obj, key, _names(getattr(obj, key), n, default, src, key))


@dataclass(frozen=True)
class TimeData:
    """A time-domain experiment (spec 1a).

    Parameters
    ----------
    fs : float
        Sampling frequency, Hz.
    u : (N, n_u) array
        Plant input as applied (N), zero-order hold.
    y : (N, n_y) array
        Measured plant output (m), sampled at the same instants as ``u``.
    r : (N, n_u) array or None
        Exogenous excitation at the plant input (closed-loop data).
    loop : {"open", "closed"}
    period : int or None
        Samples per period of a periodic excitation.
    """

    fs: float
    u: np.ndarray
    y: np.ndarray
    r: np.ndarray | None = None
    loop: str = "open"
    period: int | None = None
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        src = "time data"
        u = _real_2d(self.u, src, "u")
        y = _real_2d(self.y, src, "y")
        if u.shape[0] < 2:
            raise InputError(
                f"{src}: key 'u': expected a record of at least 2 samples, got {u.shape[0]}"
            )
        if y.shape[0] != u.shape[0]:
            raise InputError(
                f"{src}: key 'y': expected {u.shape[0]} samples like 'u', got {y.shape[0]}"
            )
        r = None
        if self.r is not None:
            r = _real_2d(self.r, src, "r")
            if r.shape != u.shape:
                raise InputError(
                    f"{src}: key 'r': expected shape {u.shape} like 'u', got {r.shape}"
                )
        fs = _positive_scalar(self.fs, src, "fs")
        if self.loop not in ("open", "closed"):
            raise InputError(f"{src}: key 'loop': expected 'open' or 'closed', got {self.loop!r}")
        period = self.period
        if period is not None:
            period = int(period)
            if period < 1 or u.shape[0] % period:
                raise InputError(
                    f"{src}: key 'period': expected a positive divisor of N={u.shape[0]}, "
                    f"got {self.period}"
                )
        object.__setattr__(self, "u", readonly(u))
        object.__setattr__(self, "y", readonly(y))
        object.__setattr__(self, "r", None if r is None else readonly(r))
        object.__setattr__(self, "fs", fs)
        object.__setattr__(self, "period", period)
        _store_channel_names(self, u.shape[1], y.shape[1], src)

    @property
    def n_samples(self) -> int:
        return self.u.shape[0]

    @property
    def n_u(self) -> int:
        return self.u.shape[1]

    @property
    def n_y(self) -> int:
        return self.y.shape[1]

    @property
    def dt(self) -> float:
        return 1.0 / self.fs

    @property
    def t(self) -> np.ndarray:
        """Sample instants, s, shape (N,)."""
        return np.arange(self.n_samples) / self.fs

    @property
    def kind(self) -> str:
        return "time"


@dataclass(frozen=True)
class FrfData:
    """A measured frequency response (spec 1b), zero-order hold compensated.

    Parameters
    ----------
    freq : (n_f,) array
        Frequency lines, Hz, strictly increasing, > 0.
    G : (n_f, n_y, n_u) complex array
        Response from applied input to measured output (m/N).
    G_var : (n_f, n_y, n_u) array or None
        Variance of each element of ``G`` ((m/N)^2).
    fs : float or None
        Sampling frequency of the experiment behind the FRF, Hz.
    """

    freq: np.ndarray
    G: np.ndarray
    G_var: np.ndarray | None = None
    fs: float | None = None
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        src = "frf data"
        freq = _array(self.freq, src, "freq")
        if freq.ndim != 1 or freq.size < 1:
            raise InputError(f"{src}: key 'freq': expected shape (n_f,), got {describe(freq)}")
        freq = _real(freq, src, "freq")
        if np.any(freq <= 0):
            raise InputError(
                f"{src}: key 'freq': expected frequencies > 0 Hz, got minimum {freq.min():g}"
            )
        if freq.size > 1 and np.any(np.diff(freq) <= 0):
            k = int(np.flatnonzero(np.diff(freq) <= 0)[0])
            raise InputError(
                f"{src}: key 'freq': expected strictly increasing lines, got "
                f"freq[{k}]={freq[k]:g} followed by freq[{k + 1}]={freq[k + 1]:g}"
            )
        G = _array(self.G, src, "G")
        if G.ndim != 3 or G.shape[0] != freq.size:
            raise InputError(
                f"{src}: key 'G': expected shape ({freq.size}, n_y, n_u) matching 'freq', "
                f"got {describe(G)}"
            )
        if not np.issubdtype(G.dtype, np.number) or G.dtype == bool:
            raise InputError(f"{src}: key 'G': expected a complex array, got {describe(G)}")
        G = G.astype(complex)
        _finite(G, src, "G")
        G_var = None
        if self.G_var is not None:
            G_var = _real(_array(self.G_var, src, "G_var"), src, "G_var")
            if G_var.shape != G.shape:
                raise InputError(
                    f"{src}: key 'G_var': expected shape {G.shape} like 'G', got {G_var.shape}"
                )
            if np.any(G_var < 0):
                raise InputError(f"{src}: key 'G_var': expected variances >= 0, got negative")
        fs = None if self.fs is None else _positive_scalar(self.fs, src, "fs")
        object.__setattr__(self, "freq", readonly(freq))
        object.__setattr__(self, "G", readonly(G))
        object.__setattr__(self, "G_var", None if G_var is None else readonly(G_var))
        object.__setattr__(self, "fs", fs)
        _store_channel_names(self, G.shape[2], G.shape[1], src)

    @property
    def n_f(self) -> int:
        return self.freq.size

    @property
    def n_u(self) -> int:
        return self.G.shape[2]

    @property
    def n_y(self) -> int:
        return self.G.shape[1]

    @property
    def omega(self) -> np.ndarray:
        """Frequency lines in rad/s."""
        return 2 * np.pi * self.freq

    @property
    def kind(self) -> str:
        return "frf"


Measurement = TimeData | FrfData


# ------------------------------------------------------------ value checking
def _array(value, src: str, key: str) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype.hasobject:
        raise InputError(f"{src}: key '{key}': expected a numeric array, got an object array")
    return a


def _finite(a: np.ndarray, src: str, key: str) -> None:
    bad = ~np.isfinite(a)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(
            f"{src}: key '{key}': expected finite values, got {a[idx]} at index {idx} "
            f"({int(bad.sum())} non-finite in all)"
        )


def _real(a: np.ndarray, src: str, key: str) -> np.ndarray:
    if np.iscomplexobj(a):
        raise InputError(f"{src}: key '{key}': expected real values, got {describe(a)}")
    if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
        raise InputError(f"{src}: key '{key}': expected a real numeric array, got {describe(a)}")
    a = a.astype(float)
    _finite(a, src, key)
    return a


def _real_2d(value, src: str, key: str) -> np.ndarray:
    a = _array(value, src, key)
    if a.ndim != 2:
        raise InputError(f"{src}: key '{key}': expected shape (N, n_channels), got {describe(a)}")
    if a.shape[1] < 1:
        raise InputError(f"{src}: key '{key}': expected at least one channel, got {describe(a)}")
    return _real(a, src, key)


def _positive_scalar(value, src: str, key: str) -> float:
    a = np.asarray(value)
    if a.ndim != 0 and a.size != 1:
        raise InputError(f"{src}: key '{key}': expected a scalar, got {describe(a)}")
    if a.dtype.hasobject or np.iscomplexobj(a) or not np.issubdtype(a.dtype, np.number):
        raise InputError(f"{src}: key '{key}': expected a real scalar, got {describe(a)}")
    v = float(a.reshape(()))
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{src}: key '{key}': expected a finite value > 0, got {v:g}")
    return v


def _string(value: np.ndarray, src: str, key: str) -> str:
    if value.ndim != 0 or value.dtype.kind not in "US":
        raise InputError(f"{src}: key '{key}': expected a string, got {describe(value)}")
    return str(value)


def _string_list(value: np.ndarray | None, src: str, key: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if value.ndim != 1 or value.dtype.kind not in "US":
        raise InputError(
            f"{src}: key '{key}': expected a 1-D array of strings, got {describe(value)}"
        )
    return tuple(str(s) for s in value)


def _file_names(arrays: dict[str, Any], src: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """A file's optional ``input_names`` and ``output_names`` keys (empty when absent)."""
    return tuple(
        _string_list(None if arrays.get(key) is None else np.asarray(arrays[key]), src, key)
        for key in ("input_names", "output_names")
    )


# ---------------------------------------------------------------- safe reading
_MAX_BYTES = 8 * 2**30  # no measurement we handle is larger than 8 GiB


def read_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every array of an ``.npz`` file, safely.

    Refuses, with a one-line :class:`InputError`: a missing file, a file that
    is not a zip archive (a text file named ``.npz``), a truncated or corrupt
    archive, object (pickled) arrays, and headers that claim more data than the
    archive holds.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{path}: no such file")
    if not zipfile.is_zipfile(p):
        raise InputError(
            f"{path}: expected an .npz archive written by numpy.savez, got a file that is not "
            "a complete zip archive (truncated, or another kind of file)"
        )
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(p) as zf:
            for info in zf.infolist():
                name = info.filename
                key = name[:-4] if name.endswith(".npy") else name
                with zf.open(info) as fh:
                    try:
                        version = np.lib.format.read_magic(fh)
                        if version == (1, 0):
                            shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
                        else:
                            shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
                    except ValueError as exc:
                        raise InputError(
                            f"{path}: key '{key}': unreadable array header ({exc})"
                        ) from None
                    if dtype.hasobject:
                        raise InputError(
                            f"{path}: key '{key}': expected a numeric or string array, got an "
                            "object (pickled) array, which is never loaded"
                        )
                    claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
                    held = info.file_size - fh.tell()
                    if claimed > min(held, _MAX_BYTES):
                        raise InputError(
                            f"{path}: key '{key}': header claims {claimed} bytes of data "
                            f"(shape {shape}), the archive holds {held}: truncated or corrupt"
                        )
                with zf.open(info) as fh:
                    out[key] = np.lib.format.read_array(fh, allow_pickle=False)
    except InputError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise InputError(
            f"{path}: truncated or corrupt .npz archive ({type(exc).__name__}: {exc})"
        ) from None
    return out


def _require(arrays: dict[str, np.ndarray], key: str, src: str, what: str) -> np.ndarray:
    if key not in arrays:
        have = ", ".join(sorted(arrays)) or "none"
        raise InputError(f"{src}: missing key '{key}' ({what}); keys present: {have}")
    return arrays[key]


def _with_src(exc: InputError, src: str, generic: str) -> InputError:
    msg = str(exc)
    if msg.startswith(generic):
        msg = src + msg[len(generic) :]
    return InputError(msg)


def measurement_from_arrays(arrays: dict[str, Any], src: str = "measurement") -> Measurement:
    """Build a :class:`TimeData` or :class:`FrfData` from spec arrays."""
    kind = _string(np.asarray(_require(arrays, "kind", src, "'time' or 'frf'")), src, "kind")
    get = arrays.get
    in_names, out_names = _file_names(arrays, src)
    try:
        if kind == "time":
            period = get("period")
            if period is not None:
                period = np.asarray(period)
                if (
                    period.ndim != 0
                    or period.dtype.kind not in "iuf"
                    or not np.isfinite(period)
                    or float(period) != int(period)
                ):
                    raise InputError(
                        f"time data: key 'period': expected an integer, got {describe(period)}"
                    )
                period = int(period)
            return TimeData(
                fs=_require(arrays, "fs", src, "sampling frequency, Hz"),
                u=_require(arrays, "u", src, "(N, n_u) plant input"),
                y=_require(arrays, "y", src, "(N, n_y) measured output"),
                r=get("r"),
                loop=_string(
                    np.asarray(_require(arrays, "loop", src, "'open' or 'closed'")), src, "loop"
                ),
                period=period,
                input_names=in_names,
                output_names=out_names,
            )
        if kind == "frf":
            return FrfData(
                freq=_require(arrays, "freq", src, "(n_f,) frequency lines, Hz"),
                G=_require(arrays, "G", src, "(n_f, n_y, n_u) complex response"),
                G_var=get("G_var"),
                fs=get("fs"),
                input_names=in_names,
                output_names=out_names,
            )
    except InputError as exc:
        raise _with_src(exc, src, f"{kind} data") from None
    raise InputError(f"{src}: key 'kind': expected 'time' or 'frf', got {kind!r}")


def load_measurement(path: str | os.PathLike) -> Measurement:
    """Read a measurement file (spec 1a or 1b)."""
    return measurement_from_arrays(read_npz(path), src=str(path))


def measurement_arrays(data: Measurement) -> dict[str, np.ndarray]:
    """The spec arrays of a measurement, ready for ``np.savez``."""
    out: dict[str, np.ndarray] = {
        "kind": np.array(data.kind),
        "input_names": np.array(data.input_names),
        "output_names": np.array(data.output_names),
    }
    if isinstance(data, TimeData):
        out.update(fs=np.array(data.fs), u=data.u, y=data.y, loop=np.array(data.loop))
        if data.r is not None:
            out["r"] = data.r
        if data.period is not None:
            out["period"] = np.array(data.period)
    else:
        out.update(freq=data.freq, G=data.G)
        if data.G_var is not None:
            out["G_var"] = data.G_var
        if data.fs is not None:
            out["fs"] = np.array(data.fs)
    return out


def save_measurement(path: str | os.PathLike, data: Measurement) -> None:
    """Write a measurement file atomically."""
    save_npz(path, **measurement_arrays(data))


# ---------------------------------------------------------------------- models
def lti_model_from_arrays(arrays: dict[str, Any], src: str = "model"):
    """Build a :class:`~workbench.core.model.LTIModel` from spec model arrays, validated.

    The optional key ``delay_s`` (a scalar >= 0, s) is the model's exact input
    delay; the matrices are the model without it.
    """
    from workbench.core.model import LTIModel

    mats = {key: _require(arrays, key, src, "state-space matrix") for key in "ABCD"}
    dt_arr = np.asarray(
        _require(arrays, "dt", src, "0.0 for continuous time, else the sample time in s")
    )
    if dt_arr.ndim != 0 or not np.issubdtype(dt_arr.dtype, np.number) or np.iscomplexobj(dt_arr):
        raise InputError(f"{src}: key 'dt': expected a real scalar, got {describe(dt_arr)}")
    get = arrays.get
    in_names, out_names = _file_names(arrays, src)
    delay = get("delay_s")
    if delay is not None:
        d = np.asarray(delay)
        if d.size != 1 or d.dtype.kind not in "iuf" or not np.isfinite(d).all() or d.item() < 0:
            raise InputError(
                f"{src}: key 'delay_s': expected a scalar input delay >= 0 s, got {describe(d)}"
                + (f" = {d.item()!r}" if d.size == 1 else "")
            )
    try:
        return LTIModel(
            mats["A"],
            mats["B"],
            mats["C"],
            mats["D"],
            dt=dt_arr,
            delay_s=0.0 if delay is None else np.asarray(delay).item(),
            input_names=in_names,
            output_names=out_names,
        )
    except InputError as exc:
        raise _with_src(exc, src, "model") from None


def model_from_arrays(arrays: dict[str, Any], src: str = "model"):
    """The rational part of a spec model as a python-control ``StateSpace``.

    A ``StateSpace`` cannot hold the ``delay_s`` key: callers that need the
    delay use :func:`lti_model_from_arrays` (or :func:`read_model`).
    """
    return lti_model_from_arrays(arrays, src).without_delay().to_statespace()


def read_model(path: str | os.PathLike):
    """Read a model file (spec 2, with its ``delay_s``) into an ``LTIModel``."""
    return lti_model_from_arrays(read_npz(path), src=str(path))


def load_model(path: str | os.PathLike):
    """Read a model file's rational part into a python-control ``StateSpace``.

    The delay (key ``delay_s``) is not part of it: :func:`read_model` keeps it.
    """
    return model_from_arrays(read_npz(path), src=str(path))


def model_names(sys) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Input and output names of a ``StateSpace`` (python-control labels) or an LTIModel."""
    from workbench.core.model import as_model

    m = as_model(sys)
    return m.input_names, m.output_names


def model_arrays(sys) -> dict[str, np.ndarray]:
    """The spec arrays of a model (``LTIModel`` or ``StateSpace``); ``delay_s`` when > 0."""
    from workbench.core.model import as_model

    m = as_model(sys)
    out = {
        "A": np.asarray(m.A, float),
        "B": np.asarray(m.B, float),
        "C": np.asarray(m.C, float),
        "D": np.asarray(m.D, float),
        "dt": np.array(m.dt),
        "input_names": np.array(m.input_names),
        "output_names": np.array(m.output_names),
    }
    if m.delay_s > 0:
        out["delay_s"] = np.array(m.delay_s)
    return out


def save_model(path: str | os.PathLike, sys, **extra: np.ndarray) -> None:
    """Write a model (``LTIModel`` or ``StateSpace``) as a spec model file, atomically.

    An ``LTIModel``'s delay goes exact into the key ``delay_s``. ``extra``
    arrays are stored beside the spec keys; giving ``delay_s`` there as well
    as in the model is refused.
    """
    arrays = model_arrays(sys)
    clash = sorted(set(arrays) & set(extra))
    if clash:
        raise InputError(f"{path}: key '{clash[0]}' given twice (in the model and as an extra)")
    save_npz(path, **arrays, **extra)


def save_controller(
    path: str | os.PathLike, controller, *, delay_samples: int | None = None
) -> None:
    """Write a controller as a spec-5 controller file, atomically.

    ``controller`` is a Controller (its ``statespace()``) or a discrete
    python-control ``StateSpace`` e = r - y -> u; its input names are the
    measured outputs', its output names the plant inputs'. The keys are a
    model file's (spec 2, without ``delay_s``: the loop's delay is not in the
    matrices) plus ``role = "controller"`` and ``delay_samples``, the loop
    computation delay the design assumed (default the controller's own
    ``delay_samples`` attribute, else 0).
    """
    sys = controller.statespace() if hasattr(controller, "statespace") else controller
    if delay_samples is None:
        delay_samples = getattr(controller, "delay_samples", 0)
    if int(delay_samples) != delay_samples or delay_samples < 0:
        raise InputError(f"{path}: delay_samples: expected an integer >= 0, got {delay_samples}")
    arrays = model_arrays(sys)
    if float(arrays["dt"]) <= 0:
        raise InputError(
            f"{path}: expected a discrete controller (dt > 0), got dt = {arrays['dt']}"
        )
    if "delay_s" in arrays:
        raise InputError(
            f"{path}: expected a controller without delay_s (the loop delay belongs to the plant)"
        )
    save_npz(
        path, **arrays, role=np.array("controller"), delay_samples=np.array(int(delay_samples))
    )


def load_any(path: str | os.PathLike):
    """Read a measurement or a model file (an LTIModel), told apart by its keys."""
    arrays = read_npz(path)
    if "kind" in arrays:
        return measurement_from_arrays(arrays, src=str(path))
    if "A" in arrays:
        return lti_model_from_arrays(arrays, src=str(path))
    have = ", ".join(sorted(arrays)) or "none"
    raise InputError(
        f"{path}: expected a measurement (key 'kind') or a model (keys A, B, C, D, dt), "
        f"got keys: {have}"
    )


def check_model_matches(
    sys, data: Measurement, *, model_src: str = "model", data_src: str = "data"
) -> None:
    """Refuse a model (``LTIModel`` or ``StateSpace``) whose input/output count does not
    match the data."""
    from workbench.core.model import as_model

    m = as_model(sys)
    if m.n_u != data.n_u or m.n_y != data.n_y:
        raise InputError(
            f"{model_src}: expected a model with {data.n_u} inputs and {data.n_y} outputs to match "
            f"{data_src}, got {m.n_u} inputs and {m.n_y} outputs"
        )
