"""The last step of every importer: the spec measurement, the map speaking where the file is silent.

A value the file states and the map states too must agree (:func:`settle`);
the map's channel names replace the file's (renaming is what they are for).
The measurement is built by :class:`~workbench.io.formats.TimeData` /
:class:`~workbench.io.formats.FrfData`, whose checks then name the file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.core.errors import InputError
from workbench.io.formats import FrfData, Measurement, TimeData

from .mapping import ImportMap

__all__ = ["Imported", "settle", "time_data", "frf_data"]


@dataclass(frozen=True)
class Imported:
    """An imported measurement and what the importer did to get it.

    Attributes
    ----------
    data : TimeData or FrfData
        The measurement, as the spec files hold it (SI units).
    notes : tuple of str
        One line each: unit conversions, a dropped 0 Hz line, records left out.
    description : str
        What was read, e.g. ``"UFF58, 6 FRF records"``.
    """

    data: Measurement
    notes: tuple[str, ...] = ()
    description: str = ""


def settle(stated, by_map, m: ImportMap, key: str, file_says: str):
    """The file's value if it states one, else the map's; both must agree when both do."""
    if stated is None:
        return by_map
    if by_map is not None and by_map != stated:
        raise InputError(f"{m.where(key)}: {file_says} says {stated!r}, the map says {by_map!r}")
    return stated


def _names(file_names, by_map, m: ImportMap, key: str, n: int) -> tuple[str, ...]:
    if by_map is None:
        return tuple(file_names)
    if len(by_map) != n:
        raise InputError(
            f"{m.where(key)}: expected {n} names (the file's channels), got {len(by_map)}"
        )
    return tuple(by_map)


def _built(src: str, generic: str, build):
    try:
        return build()
    except InputError as exc:
        msg = str(exc)
        raise InputError(src + msg[len(generic) :] if msg.startswith(generic) else msg) from None


def time_data(
    src: str,
    m: ImportMap,
    *,
    fs: float,
    u: np.ndarray,
    y: np.ndarray,
    r: np.ndarray | None = None,
    loop: str | None = None,
    period: int | None = None,
    input_names=(),
    output_names=(),
) -> TimeData:
    """A time record (spec 1a) from imported arrays: u (N, n_u), y (N, n_y), r (N, n_u), fs Hz.

    ``loop`` defaults to ``"closed"`` when ``r`` is recorded, else ``"open"``.
    """
    loop = settle(loop, m.loop, m, "loop", "the file")
    period = settle(period, m.period, m, "period", "the file")
    u, y = np.asarray(u), np.asarray(y)
    return _built(
        src,
        "time data",
        lambda: TimeData(
            fs=fs,
            u=u,
            y=y,
            r=r,
            loop=loop or ("open" if r is None else "closed"),
            period=period,
            input_names=_names(input_names, m.input_names, m, "input_names", u.shape[-1]),
            output_names=_names(output_names, m.output_names, m, "output_names", y.shape[-1]),
        ),
    )


def frf_data(
    src: str,
    m: ImportMap,
    *,
    freq: np.ndarray,
    G: np.ndarray,
    G_var: np.ndarray | None = None,
    fs: float | None = None,
    input_names=(),
    output_names=(),
) -> FrfData:
    """A frequency response (spec 1b): freq (n_f,) Hz, G (n_f, n_y, n_u), G_var like G."""
    fs = settle(fs, m.fs, m, "fs", "the file")
    G = np.asarray(G)
    return _built(
        src,
        "frf data",
        lambda: FrfData(
            freq=freq,
            G=G,
            G_var=G_var,
            fs=fs,
            input_names=_names(input_names, m.input_names, m, "input_names", G.shape[2]),
            output_names=_names(output_names, m.output_names, m, "output_names", G.shape[1]),
        ),
    )
