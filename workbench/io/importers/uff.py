"""Universal files, dataset 58 (function at nodal DOF): FRFs and time records, through pyuff.

Reading
-------
- The dataset 58 records of one function type form one measurement: FRFs
  (function type 4) or time responses (type 1). Records of several types
  (FRFs beside coherences, FRFs beside time records) are refused unless the
  map's ``kind`` picks one; the records left out are then listed in a note.
  Other datasets (geometry, ...) are skipped; a units dataset 164 is read.
- Channels: a record's response, and for an FRF its reference, is a channel,
  named by its entity name, or by node and direction (``101+Z``, ``7-RX``,
  ``3`` for a scalar) when the entity name is NONE. FRFs: references are the
  inputs, responses the outputs, one record per pair, all on the same
  frequency lines. Time records: one per channel, all of one length and time
  axis; force records (ordinate data type 13 or 9) are inputs, displacement
  records (8) outputs, unless the map's ``[variables]`` ``u``, ``y``, ``r``
  name the channels.
- Units: the units dataset 164's length and force factors applied by each
  record's data types (displacement, velocity, acceleration per force, with
  the rotational directions' exponents), else the map's ``[units]`` (by
  channel, or by spec key ``u``, ``y``, ``r``, ``G``); a record with neither is
  refused.
- FRFs of velocity or acceleration per force (mobility, accelerance) become
  displacement per force (divided by j 2 pi f, or by (j 2 pi f)^2); time
  records of velocity or acceleration are refused: the spec's outputs are
  positions.
- Sampling: an even abscissa's increment is printed to 6 digits (E13.5);
  ``fs`` is the shortest number whose increment prints the same (3000 Hz for
  ``3.33333E-04``), or the exact value of the ID-line tag below. An uneven
  time axis must be uniform.

Writing (``workbench export ... --out FILE.uff``)
-------------------------------------------------
A units dataset 164 (SI), then binary 58b records in double precision, so
that the numbers come back bit for bit:

- FRF: one record per output/input pair (function type 4), response = the
  output (data type 8, displacement), reference = the input (13, force), the
  frequency lines written exactly (uneven abscissa). ``G_var`` has no place in
  a dataset 58 and is left out (a note says so; .mat keeps it).
- Time record: one record per channel (type 1), inputs and excitations as
  force (13), outputs as displacement (8), even abscissa.
- Nodes: inputs 1..n_u, outputs next, excitations last, direction 0
  (scalar); the entity name is the channel name when it fits (at most 10
  ASCII characters, no blanks), else NONE (the name stays in ID line 1).
- ID line 5 holds what the fixed-width fields cannot hold exactly, as
  ``workbench fs_hz=3333.3333333333335 role=u loop=closed period=1000``.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workbench.core.atomic import atomic_path
from workbench.core.errors import InputError
from workbench.io.formats import FrfData, Measurement

from . import units as U
from .axes import frequency_lines, rate_from_printed_step, rate_from_time_axis
from .build import Imported, frf_data, settle, time_data
from .mapping import ImportMap

__all__ = ["read_uff", "write_uff"]

_FUNCTIONS = {
    0: "general",
    1: "time response",
    2: "auto spectrum",
    3: "cross spectrum",
    4: "FRF",
    5: "transmissibility",
    6: "coherence",
    7: "auto correlation",
    8: "cross correlation",
    9: "PSD",
}
_KIND_FUNCTION = {"time": 1, "frf": 4}
_DIRECTIONS = {0: "", 1: "+X", 2: "+Y", 3: "+Z", 4: "+RX", 5: "+RY", 6: "+RZ"}
_DIRECTIONS.update({-k: "-" + v[1:] for k, v in _DIRECTIONS.items() if k})
_DISPLACEMENT, _VELOCITY, _ACCELERATION = 8, 11, 12
_ORDER = {_DISPLACEMENT: 0, _VELOCITY: 1, _ACCELERATION: 2}
_FORCES = (9, 13)
_DATA_TYPES = {0: "unknown", 1: "general", 8: "displacement", 9: "reaction force"}
_DATA_TYPES.update({11: "velocity", 12: "acceleration", 13: "excitation force"})
_TAG = re.compile(r"^workbench((?:\s+\w+=\S+)*)\s*$")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


# --------------------------------------------------------------------- reading
@dataclass(frozen=True)
class _Channel:
    """A measurement point: entity name, node, direction (-6..6)."""

    entity: str
    node: int
    direction: int

    @property
    def node_label(self) -> str:
        return f"{self.node}{_DIRECTIONS.get(self.direction, f'/{self.direction}')}"

    @property
    def label(self) -> str:
        named = self.entity and self.entity.upper() != "NONE"
        return self.entity if named else self.node_label

    @property
    def rotational(self) -> bool:
        return abs(self.direction) >= 4


@dataclass(frozen=True)
class _Record:
    """One dataset 58: its position in the file (1-based) and pyuff's fields."""

    number: int
    fields: dict

    def channel(self, side: str) -> _Channel:
        f = self.fields
        return _Channel(
            str(f.get(f"{side}_ent_name", "NONE")), int(f[f"{side}_node"]), int(f[f"{side}_dir"])
        )

    @property
    def function(self) -> int:
        return int(self.fields["func_type"])

    @property
    def tag(self) -> dict[str, str]:
        match = _TAG.match(str(self.fields.get("id5", "")).strip())
        return {} if match is None else dict(p.split("=", 1) for p in match[1].split())

    def where(self, path, what: str = "") -> str:
        return f"{path}: record {self.number}" + (f" ({what})" if what else "")


def _read_sets(path: Path) -> tuple[list[_Record], tuple[float, float] | None]:
    """The dataset 58 records and the units factors (length, force) of dataset 164, if any."""
    import pyuff

    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        uf = pyuff.UFF(str(path))
        types = [int(t) for t in uf.get_set_types()]
    except Exception as exc:
        raise InputError(f"{path}: unreadable universal file ({_one_line(exc)})") from None
    if not types:
        raise InputError(
            f"{path}: expected universal file datasets (blocks delimited by -1 lines), got none"
        )
    records, factors, others = [], set(), Counter()
    for i, kind in enumerate(types):
        if kind not in (58, 164):
            others[kind] += 1
            continue
        try:
            fields = uf.read_sets(i)
        except Exception as exc:
            raise InputError(
                f"{path}: dataset {i + 1} (type {kind}): unreadable ({_one_line(exc)})"
            ) from None
        if kind == 164:
            factors.add((float(fields["length"]), float(fields["force"])))
        else:
            records.append(_Record(i + 1, fields))
    if len(factors) > 1:
        raise InputError(
            f"{path}: field 'units': expected one units dataset (164), got several with "
            f"different factors {sorted(factors)}"
        )
    if not records:
        got = ", ".join(str(t) for t in sorted(others)) or "none"
        raise InputError(
            f"{path}: expected dataset 58 records (functions at nodal DOF), got types {got}"
        )
    return records, (factors.pop() if factors else None)


def _pick_kind(path, records: list[_Record], m: ImportMap) -> tuple[str, list[_Record], list[str]]:
    by_type: dict[int, list[int]] = {}
    for rec in records:
        by_type.setdefault(rec.function, []).append(rec.number)

    def describe(types) -> str:
        return ", ".join(f"{len(by_type[t])} {_FUNCTIONS.get(t, 'function')} ({t})" for t in types)

    if m.kind is not None:
        want = _KIND_FUNCTION[m.kind]
        picked = [rec for rec in records if rec.function == want]
        if not picked:
            raise InputError(
                f"{m.where('kind')}: expected {_FUNCTIONS[want]} ({want}) records in {path}, got "
                f"{describe(by_type)}"
            )
        rest = [t for t in by_type if t != want]
        notes = [f"left out records of other function types: {describe(rest)}"] if rest else []
        return m.kind, picked, notes
    if len(by_type) > 1 or not set(by_type) <= {1, 4}:
        hint = "; pick one with kind in the map" if set(by_type) & {1, 4} else ""
        raise InputError(
            f"{path}: field 'function type' of the dataset 58 records: expected records of one "
            f"kind, FRF (4) or time response (1), to form one measurement, got {describe(by_type)}"
            f"{hint}"
        )
    return ("frf" if 4 in by_type else "time"), records, []


def _labels_unique(path, channels: list[_Channel], what: str) -> None:
    seen: dict[str, _Channel] = {}
    for ch in channels:
        other = seen.setdefault(ch.label, ch)
        if other != ch:
            raise InputError(
                f"{path}: expected distinct {what} channels, got two named {ch.label!r} "
                f"(nodes {other.node_label} and {ch.node_label})"
            )


def _select(path, channels: list[_Channel], m: ImportMap, key: str) -> list[_Channel] | None:
    """The channels the map's [variables] key names, in its order (None when it names none)."""
    if key not in m.variables:
        return None
    labels = m.variables[key]
    out = []
    for label in (labels,) if isinstance(labels, str) else labels:
        found = [ch for ch in channels if label in (ch.label, ch.node_label)]
        if not found:
            have = ", ".join(dict.fromkeys(ch.label for ch in channels))
            raise InputError(
                f"{m.where('variables.' + key)}: channel {label!r} is not in {path} "
                f"(channels: {have})"
            )
        if len(set(found)) > 1:
            raise InputError(
                f"{m.where('variables.' + key)}: channel {label!r} names several channels in "
                f"{path} ({', '.join(ch.node_label for ch in found)}): name it by node+direction"
            )
        out.append(found[0])
    return out


def _map_scale(m: ImportMap, keys: tuple[str, ...], expect) -> float | None:
    """SI factor of a record's values from the map's [units], or None when the map has none."""
    by_map = m.unit(*keys)
    if by_map is None:
        return None
    return U.si_factor(by_map[1], expect, m.where("units." + by_map[0]))


def _file_factor(data_type: int, ch: _Channel, factors) -> float | None:
    """SI factor of a displacement-like (8, 11, 12) or force (9, 13) record from dataset 164."""
    if factors is None:
        return None
    length, force = factors  # SI = value / factor
    if data_type in _ORDER:
        return 1.0 if ch.rotational else 1.0 / length
    if data_type in _FORCES:
        return 1.0 / (length * force) if ch.rotational else 1.0 / force
    return None


def _units_missing(where: str, what: str, factors, types: str, key: str) -> InputError:
    got = "no units dataset 164" if factors is None else f"data types {types}"
    return InputError(
        f"{where}: field 'units': expected a units dataset (164) and {what}, or the map's "
        f"[units] {key}, got {got}"
    )


def _stated_fs(path, records: list[_Record], m: ImportMap) -> tuple[float | None, str]:
    tags = {rec.tag.get("fs_hz") for rec in records} - {None}
    if len(tags) > 1:
        raise InputError(
            f"{path}: ID line 5: expected one fs_hz for all records, got {sorted(tags)}"
        )
    if not tags:
        return m.fs, f"the map's fs ({m.source})"
    try:
        tagged = float(tags.pop())
    except ValueError:
        raise InputError(
            f"{path}: ID line 5: expected fs_hz=<number>, got {records[0].tag}"
        ) from None
    return settle(tagged, m.fs, m, "fs", f"{path} (ID line 5)"), "ID line 5's fs_hz"


def read_uff(path: str | Path, m: ImportMap) -> Imported:
    """Read the dataset 58 records of a universal file into one measurement (spec 1a or 1b)."""
    path = Path(path)
    m.refuse_variables(
        ("t", "freq", "G", "G_var", "fs", "input_names", "output_names", "kind", "loop", "period"),
        "a universal file",
    )
    records, factors = _read_sets(path)
    kind, records, notes = _pick_kind(path, records, m)
    if kind == "frf":
        return _read_frf(path, records, factors, m, notes)
    return _read_time(path, records, factors, m, notes)


def _read_frf(path, records, factors, m: ImportMap, notes: list[str]) -> Imported:
    if "r" in m.variables:
        raise InputError(f"{m.where('variables.r')}: does not apply to FRF records")
    responses = list(dict.fromkeys(rec.channel("rsp") for rec in records))
    references = list(dict.fromkeys(rec.channel("ref") for rec in records))
    _labels_unique(path, responses, "response")
    _labels_unique(path, references, "reference")
    outputs = _select(path, responses, m, "y") or responses
    inputs = _select(path, references, m, "u") or references
    grid: dict[tuple[_Channel, _Channel], _Record] = {}
    for rec in records:
        pair = (rec.channel("rsp"), rec.channel("ref"))
        if pair[0] not in outputs or pair[1] not in inputs:
            continue
        if pair in grid:
            raise InputError(
                f"{path}: records {grid[pair].number} and {rec.number}: expected one FRF per "
                f"response/reference pair, got two from {pair[1].label} to {pair[0].label}"
            )
        grid[pair] = rec
    left = len(records) - len(grid)
    if left:
        notes.append(f"left out {left} records of channels the map does not name")
    first = grid.get((outputs[0], inputs[0]))
    x0 = None if first is None else np.asarray(first.fields["x"], float)
    G = None
    fs, _ = _stated_fs(path, list(grid.values()), m)
    converted: Counter = Counter()
    for j, out in enumerate(outputs):
        for i, inp in enumerate(inputs):
            rec = grid.get((out, inp))
            what = f"{out.label}/{inp.label}"
            if rec is None:
                raise InputError(
                    f"{path}: expected an FRF record for every response/reference pair "
                    f"({len(outputs)} x {len(inputs)}), got none from {inp.label} to {out.label}"
                )
            x = np.asarray(rec.fields["x"], float)
            if x.shape != x0.shape or not np.array_equal(x, x0):
                got = f"{x.size} lines" if x.shape != x0.shape else "other lines"
                raise InputError(
                    f"{rec.where(path, what)}: field 'abscissa': expected the {x0.size} frequency "
                    f"lines of record {first.number}, got {got}"
                )
            if G is None:
                freq, dropped = frequency_lines(x0, f"{rec.where(path, what)}: field 'abscissa'")
                keep = slice(1, None) if dropped else slice(None)
                G = np.empty((freq.size, len(outputs), len(inputs)), dtype=complex)
            num = int(rec.fields.get("ordinate_spec_data_type", 0))
            den = int(rec.fields.get("orddenom_spec_data_type", 0))
            scale = _map_scale(m, (what, "G"), U.FRF)
            if scale is None:
                a, b = _file_factor(num, out, factors), _file_factor(den, inp, factors)
                if a is None or b is None or num not in _ORDER or den not in _FORCES:
                    raise _units_missing(
                        rec.where(path, what),
                        "data types displacement, velocity or acceleration (8, 11, 12) per "
                        "force (13)",
                        factors,
                        f"{num} ({_DATA_TYPES.get(num, 'other')}) / {den} "
                        f"({_DATA_TYPES.get(den, 'other')})",
                        'G = "m/N"',
                    )
                scale = a / b
            order = _ORDER.get(num, 0)
            values = np.asarray(rec.fields["data"])[keep] * scale
            if order:
                converted[_DATA_TYPES[num]] += 1
                values = values / (2j * np.pi * freq) ** order
            G[:, j, i] = values
    if dropped:
        notes.append("dropped the 0 Hz line (the spec's lines are > 0 Hz)")
    for what, count in converted.items():
        notes.append(f"{count} FRF records of {what} per force converted to displacement per force")
    data = frf_data(
        str(path),
        m,
        freq=freq,
        G=G,
        fs=fs,
        input_names=[ch.label for ch in inputs],
        output_names=[ch.label for ch in outputs],
    )
    return Imported(data, tuple(notes), f"UFF58, {len(grid)} FRF records")


def _time_role(path, rec: _Record, ch: _Channel, roles_by_map) -> str:
    if roles_by_map is not None:
        for key, chans in roles_by_map.items():
            if ch in chans:
                return key
        return ""
    role = rec.tag.get("role")
    if role in ("u", "y", "r"):
        return role
    num = int(rec.fields.get("ordinate_spec_data_type", 0))
    if num in _FORCES:
        return "u"
    if num == _DISPLACEMENT:
        return "y"
    what = f"{num} ({_DATA_TYPES.get(num, 'other')})"
    if num in (_VELOCITY, _ACCELERATION):
        raise InputError(
            f"{rec.where(path, ch.label)}: field 'ordinate data type': expected displacement (8) "
            f"or force (13) for a time record, got {what}: the spec's outputs are positions"
        )
    raise InputError(
        f"{rec.where(path, ch.label)}: field 'ordinate data type': expected displacement (8) or "
        f"force (13) to tell output from input, got {what}: name the channels with [variables] "
        "u and y in the map"
    )


def _read_time(path, records, factors, m: ImportMap, notes: list[str]) -> Imported:
    channels = [rec.channel("rsp") for rec in records]
    for rec, ch in zip(records, channels):
        if channels.count(ch) > 1:
            other = records[channels.index(ch)]
            raise InputError(
                f"{path}: records {other.number} and {rec.number}: expected one time record per "
                f"channel, got two for {ch.label}"
            )
    roles_by_map = None
    if any(k in m.variables for k in ("u", "y", "r")):
        roles_by_map = {k: _select(path, channels, m, k) or [] for k in ("u", "y", "r")}
    roles: dict[str, list[tuple[_Record, _Channel]]] = {"u": [], "y": [], "r": []}
    for rec, ch in zip(records, channels):
        role = _time_role(path, rec, ch, roles_by_map)
        if role:
            roles[role].append((rec, ch))
    if roles_by_map is not None:
        for key in roles:  # the map's order
            roles[key].sort(key=lambda rc, key=key: roles_by_map[key].index(rc[1]))
        left = len(records) - sum(len(v) for v in roles.values())
        if left:
            notes.append(f"left out {left} records of channels the map does not name")
    for key, what in (("u", "input (force)"), ("y", "output (displacement)")):
        if not roles[key]:
            raise InputError(f"{path}: expected at least one {what} time record, got none")
        _labels_unique(path, [ch for _, ch in roles[key]], what)
    used = [rc for key in ("u", "y", "r") for rc in roles[key]]
    first, first_ch = used[0]
    n = len(first.fields["data"])
    for rec, ch in used:
        if len(rec.fields["data"]) != n:
            raise InputError(
                f"{path}: channels of unequal length: record {rec.number} ({ch.label}) has "
                f"{len(rec.fields['data'])} samples, record {first.number} ({first_ch.label}) "
                f"has {n}"
            )
        if np.iscomplexobj(rec.fields["data"]):
            raise InputError(
                f"{rec.where(path, ch.label)}: field 'ordinate data type': expected real values "
                "for a time record, got complex"
            )
    stated, stated_by = _stated_fs(path, [rc[0] for rc in used], m)
    where = first.where(path, first_ch.label) + ": field 'abscissa'"
    if int(first.fields.get("abscissa_spacing", 1)) == 1:
        axis = (float(first.fields["abscissa_min"]), float(first.fields["abscissa_inc"]))
        for rec, ch in used:
            if (float(rec.fields["abscissa_min"]), float(rec.fields["abscissa_inc"])) != axis:
                raise InputError(
                    f"{rec.where(path, ch.label)}: field 'abscissa': expected the time axis of "
                    f"record {first.number} (start {axis[0]:g} s, step {axis[1]:g} s), got "
                    f"start {float(rec.fields['abscissa_min']):g} s, step "
                    f"{float(rec.fields['abscissa_inc']):g} s"
                )
        fs = rate_from_printed_step(axis[1], where, stated=stated, stated_by=stated_by)
    else:
        t = np.asarray(first.fields["x"], float)
        for rec, ch in used:
            if not np.array_equal(np.asarray(rec.fields["x"], float), t):
                raise InputError(
                    f"{rec.where(path, ch.label)}: field 'abscissa': expected the time axis of "
                    f"record {first.number}, got other instants"
                )
        binary = bool(first.fields.get("binary"))
        single = int(first.fields.get("ord_data_type", 4)) in (2, 5)
        rel = 0.0 if binary and not single else (6e-8 if binary else 5e-6)
        fs = rate_from_time_axis(
            t, where, resolution=rel * float(np.max(np.abs(t))), stated=stated, stated_by=stated_by
        )

    def matrix(key: str) -> np.ndarray:
        cols = []
        for rec, ch in roles[key]:
            num = int(rec.fields.get("ordinate_spec_data_type", 0))
            scale = _map_scale(m, (ch.label, ch.node_label, key), U.CHANNEL)
            if scale is None:
                scale = _file_factor(num, ch, factors)
                if scale is None or num not in (_DISPLACEMENT, *_FORCES):
                    raise _units_missing(
                        rec.where(path, ch.label),
                        "data type displacement (8) or force (13)",
                        factors,
                        f"{num} ({_DATA_TYPES.get(num, 'other')})",
                        f'"{ch.label}" = "m" (or {key} = "m")',
                    )
            cols.append(np.asarray(rec.fields["data"], float) * scale)
        return np.column_stack(cols)

    r = None
    if roles["r"]:
        if len(roles["r"]) != len(roles["u"]):
            raise InputError(
                f"{path}: expected one excitation (r) record per input ({len(roles['u'])}), got "
                f"{len(roles['r'])}"
            )
        r = matrix("r")
    tag = first.tag
    period = tag.get("period")
    if period is not None and not period.isdigit():
        raise InputError(
            f"{first.where(path)}: ID line 5: expected period=<samples>, got {period!r}"
        )
    data = time_data(
        str(path),
        m,
        fs=fs,
        u=matrix("u"),
        y=matrix("y"),
        r=r,
        loop=tag.get("loop"),
        period=None if period is None else int(period),
        input_names=[ch.label for _, ch in roles["u"]],
        output_names=[ch.label for _, ch in roles["y"]],
    )
    return Imported(data, tuple(notes), f"UFF58, {len(used)} time records of {n} samples")


# --------------------------------------------------------------------- writing
def _entity(name: str) -> str:
    fits = 0 < len(name) <= 10 and name.isascii() and name.upper() != "NONE"
    fits = fits and not any(c.isspace() for c in name)
    return name if fits else "NONE"


def _tag(**fields) -> str:
    return "workbench " + " ".join(f"{k}={v}" for k, v in fields.items() if v is not None)


def _record(**fields) -> dict:
    import pyuff

    return pyuff.prepare_58(binary=1, rsp_dir=0, ref_dir=0, **fields)


def write_uff(path: str | Path, data: Measurement) -> tuple[str, ...]:
    """Write a measurement as a universal file (dataset 164 + binary 58b records), atomically.

    Returns notes (one line each) on what the file cannot hold: ``G_var``,
    channel names too long for an entity name.
    """
    import pyuff

    notes = []
    n_u, n_y = data.n_u, data.n_y
    names = [*data.input_names, *data.output_names]
    long = [name for name in names if _entity(name) == "NONE"]
    if long:
        notes.append(
            f"channel names that do not fit a UFF entity name (10 characters, no blanks) are "
            f"written as NONE and read back as node numbers: {', '.join(long)}"
        )
    units = {
        "type": 164,
        "units_code": 1,
        "units_description": "SI",
        "temp_mode": 2,
        "length": 1.0,
        "force": 1.0,
        "temp": 1.0,
        "temp_offset": 273.15,
    }
    sets = []
    fs = None if data.fs is None else repr(float(data.fs))
    if isinstance(data, FrfData):
        if data.G_var is not None:
            notes.append(
                "G_var not written: a dataset 58 holds no variance (export to .mat keeps it)"
            )
        for j, out in enumerate(data.output_names):
            for i, inp in enumerate(data.input_names):
                sets.append(
                    _record(
                        func_type=4,
                        id1=f"{out} / {inp}",
                        id5=_tag(fs_hz=fs),
                        rsp_ent_name=_entity(out),
                        rsp_node=n_u + j + 1,
                        ref_ent_name=_entity(inp),
                        ref_node=i + 1,
                        data=np.array(data.G[:, j, i], dtype=complex),
                        x=np.array(data.freq, dtype=float),
                        abscissa_spacing=0,
                        abscissa_spec_data_type=18,
                        ordinate_spec_data_type=_DISPLACEMENT,
                        orddenom_spec_data_type=13,
                    )
                )
        counts = [3 * data.n_f * 8] * len(sets)
    else:
        channels = [
            ("u", i, data.u[:, i], name, 13, i + 1) for i, name in enumerate(data.input_names)
        ]
        channels += [
            ("y", j, data.y[:, j], name, _DISPLACEMENT, n_u + j + 1)
            for j, name in enumerate(data.output_names)
        ]
        if data.r is not None:
            channels += [
                ("r", i, data.r[:, i], name, 13, n_u + n_y + i + 1)
                for i, name in enumerate(data.input_names)
            ]
        t = np.arange(data.n_samples) / data.fs
        for role, _, values, name, data_type, node in channels:
            sets.append(
                _record(
                    func_type=1,
                    id1=f"{name} ({role})",
                    id5=_tag(fs_hz=fs, role=role, loop=data.loop, period=data.period),
                    rsp_ent_name=_entity(name),
                    rsp_node=node,
                    ref_node=0,
                    data=np.array(values, dtype=float),
                    x=t,
                    abscissa_spacing=1,
                    abscissa_spec_data_type=17,
                    ordinate_spec_data_type=data_type,
                    orddenom_spec_data_type=0,
                )
            )
        counts = [data.n_samples * 8] * len(sets)
    with atomic_path(path) as tmp:
        # mode "add" into the empty temporary file: pyuff's "overwrite" truncates a binary
        # record it has just begun
        pyuff.UFF(str(tmp)).write_sets([units, *sets], mode="add")
        _fix_byte_counts(tmp, counts)
    return tuple(notes)


def _fix_byte_counts(path: Path, counts: list[int]) -> None:
    """Write the true data byte count into each 58b header (pyuff writes values x 8 bytes,
    short of the imaginary parts and the abscissa that follow them)."""
    raw = bytearray(path.read_bytes())
    pos = 0
    for count in counts:
        pos = raw.index(b"    58b", pos)
        field = slice(pos + 31, pos + 43)  # "    58b" I6 I6 I12 then I12: the byte count
        raw[field] = b"%12d" % count
        for _ in range(12):  # the header line and the 11 ASCII lines before the binary data
            pos = raw.index(b"\n", pos) + 1
        pos += count
    path.write_bytes(bytes(raw))
