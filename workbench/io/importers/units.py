"""Units of imported data: the factor that brings a value in a named unit to SI.

The spec files are SI throughout (N, m, rad, s, Hz). An importer multiplies
every value by :func:`si_factor` of the unit the file (or the map) names for
it. A unit is one of the names below, a ratio ``a/b`` of two of them (an FRF:
``um/N``), or a squared ratio ``(a/b)^2`` (an FRF variance).

| dimension | units (factor to SI) |
|---|---|
| length | m, mm, um (µm), nm |
| angle | rad, mrad, urad (µrad), deg |
| force | N, mN, kN |
| torque | Nm (N*m, N.m), mNm |
| voltage, current | V, mV, A, mA |
| time | s, ms, us (µs) |
| frequency | Hz, kHz, rad/s |
"""

from __future__ import annotations

import math

from workbench.core.errors import InputError

__all__ = ["si_factor", "CHANNEL", "FRF", "FRF_VARIANCE", "TIME", "FREQUENCY", "ANGLE"]

_MICRO = ("u", "µ", "μ")  # ASCII u, micro sign U+00B5, Greek mu U+03BC

# name -> (factor to SI, dimension)
_UNITS: dict[str, tuple[float, str]] = {
    "m": (1.0, "length"),
    "mm": (1e-3, "length"),
    "nm": (1e-9, "length"),
    "rad": (1.0, "angle"),
    "mrad": (1e-3, "angle"),
    "deg": (math.pi / 180.0, "angle"),
    "N": (1.0, "force"),
    "mN": (1e-3, "force"),
    "kN": (1e3, "force"),
    "Nm": (1.0, "torque"),
    "N*m": (1.0, "torque"),
    "N.m": (1.0, "torque"),
    "mNm": (1e-3, "torque"),
    "V": (1.0, "voltage"),
    "mV": (1e-3, "voltage"),
    "A": (1.0, "current"),
    "mA": (1e-3, "current"),
    "s": (1.0, "time"),
    "ms": (1e-3, "time"),
    "Hz": (1.0, "frequency"),
    "kHz": (1e3, "frequency"),
    "rad/s": (1.0 / (2.0 * math.pi), "frequency"),
}
for _mu in _MICRO:
    _UNITS[f"{_mu}m"] = (1e-6, "length")
    _UNITS[f"{_mu}rad"] = (1e-6, "angle")
    _UNITS[f"{_mu}s"] = (1e-6, "time")

# what each kind of value may be measured in
CHANNEL = frozenset({"length", "angle", "force", "torque", "voltage", "current"})
FRF = frozenset(f"{a}/{b}" for a in CHANNEL for b in CHANNEL)
FRF_VARIANCE = frozenset(f"({d})^2" for d in FRF)
TIME = frozenset({"time"})
FREQUENCY = frozenset({"frequency"})
ANGLE = frozenset({"angle"})

_EXAMPLES = {
    CHANNEL: "m, um, rad, N, Nm, V, A",
    FRF: "m/N, um/N, rad/Nm",
    FRF_VARIANCE: "(m/N)^2",
    TIME: "s, ms, us",
    FREQUENCY: "Hz, kHz, rad/s",
    ANGLE: "deg, rad",
}


def _parse(unit: str) -> tuple[float, str] | None:
    """(factor, dimension) of a unit string, or None when it is not one we know."""
    u = unit.strip()
    if u in _UNITS:
        return _UNITS[u]
    if u.startswith("(") and u.endswith(")^2"):
        inner = _parse(u[1:-3])
        if inner is None or "/" not in inner[1]:
            return None
        return inner[0] ** 2, f"({inner[1]})^2"
    if u.count("/") == 1:
        num, den = (_UNITS.get(part.strip()) for part in u.split("/"))
        if num is None or den is None:
            return None
        return num[0] / den[0], f"{num[1]}/{den[1]}"
    return None


def si_factor(unit: str, expect: frozenset[str], where: str) -> float:
    """The factor that brings a value in ``unit`` to SI, refusing a unit of another kind.

    Parameters
    ----------
    unit : str
        The unit as the file or the map writes it (``"um"``, ``"m/N"``, ``"deg"``).
    expect : frozenset of str
        The dimensions allowed here (:data:`CHANNEL`, :data:`FRF`, :data:`TIME` ...).
    where : str
        ``"<file>: <field>"`` for the one-line refusal.
    """
    parsed = _parse(unit)
    if parsed is None or parsed[1] not in expect:
        raise InputError(
            f"{where}: expected a unit such as {_EXAMPLES[expect]}, got {unit!r}"
            + ("" if parsed is None else f" (a {parsed[1]})")
        )
    return parsed[0]
