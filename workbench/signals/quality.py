"""Data-quality checks: poor but usable measurements, reported as warnings.

:func:`check_measurement` looks at a :class:`~workbench.io.formats.TimeData` or
:class:`~workbench.io.formats.FrfData` and returns one message per finding, each
also emitted as a :class:`~workbench.core.errors.DataWarning` (the CLI prints it as
one ``warning: ...`` line and still exits 0). Every message names the channel
or the band it concerns.

Checks, time data:

- a constant input channel (it excites nothing);
- rank-deficient MIMO excitation: two excitation channels identical or
  linearly dependent over the record; for periodic data whose periods differ
  (multi-experiment data), the excitation matrix across the experiment blocks
  (:mod:`workbench.signals.periodic`) per line;
- closed-loop data without the reference ``r``;
- a clipped sensor (many samples at exactly the channel's max or min);
- a gap in the excitation: lines inside the excited band of ``r`` (or ``u``)
  with far less power than their neighbours, or missing from the line grid.

With ``method`` (the estimator the caller will run on the record): an
open-loop method (one not named ``cl-*``) on closed-loop data.

Checks, FRF data:

- lines where the noise variance exceeds ``|G|^2`` (SNR below 0 dB), per
  element, with the band;
- a gap in ``freq`` much larger than the local line spacing.

Models (:func:`check_model`): unstable poles other than rigid-body poles at 0.

Every command that reads a measurement calls :func:`check_measurement` (the
CLI through :func:`workbench.cli.commands.load_checked`), so the warnings read
the same in ``info``, ``compare``, ``diagnose``, ``identify``, ``frf``,
``modalfit``, ``update``, ``predict`` and ``augment``.
"""

from __future__ import annotations

import warnings

import numpy as np

from workbench.core.errors import DataWarning
from workbench.io.formats import FrfData, TimeData
from workbench.signals.periodic import EXCITED_REL_POWER

__all__ = ["check_measurement", "check_model", "unstable_poles", "runs"]

# Thresholds, with the reasoning behind each (see the check functions).
_DEPENDENT_TOL = 1e-6  # relative singular value below which channels are linearly dependent
_CLIP_MIN_COUNT = 10  # at least this many samples at an extreme ...
_CLIP_RATIO = 10.0  # ... and this many times the typical count of one value
_WEAK_POWER = 1e-2  # an excited line 20 dB below its neighbours' median is a gap
_GRID_GAP = 5.0  # a spacing this many times the local typical spacing is a gap
_BAND_POWER = 1e-2  # the excited band: lines within 20 dB of the strongest
_SNR_MIN_RUN = 3  # lines in a row below the noise before an FRF band is reported


def runs(mask: np.ndarray, *, gap: int = 0) -> list[tuple[int, int]]:
    """Contiguous runs of True in a 1-D mask, as half-open ``(start, stop)`` index pairs.

    Runs separated by at most ``gap`` False entries are merged.
    """
    m = np.concatenate([[0], np.asarray(mask, bool).astype(np.int8), [0]])
    d = np.diff(m)
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    out: list[tuple[int, int]] = []
    for s, e in zip(starts.tolist(), stops.tolist()):
        if out and s - out[-1][1] <= gap:
            out[-1] = (out[-1][0], e)
        else:
            out.append((s, e))
    return out


def _band_text(freq: np.ndarray, spans: list[tuple[int, int]], limit: int = 4) -> str:
    parts = [f"{freq[s]:g}-{freq[e - 1]:g} Hz" for s, e in spans[:limit]]
    if len(spans) > limit:
        parts.append(f"and {len(spans) - limit} more")
    return ", ".join(parts)


# ------------------------------------------------------------------ time data
def _constant_inputs(data: TimeData) -> list[str]:
    out = []
    for j, name in enumerate(data.input_names):
        col = data.u[:, j]
        if np.ptp(col) == 0:
            out.append(
                f"input '{name}' (channel {j}) is constant ({col[0]:g}) over the record: "
                "it excites nothing, its column of the response cannot be identified"
            )
    return out


def _excitation(data: TimeData) -> tuple[np.ndarray, str]:
    return (data.r, "r") if data.r is not None else (data.u, "u")


def _dependent_excitation(data: TimeData) -> list[str]:
    e, key = _excitation(data)
    if e.shape[1] < 2:
        return []
    e = e - e.mean(axis=0)
    norms = np.linalg.norm(e, axis=0)
    live = np.flatnonzero(norms > 0)  # constant channels are reported on their own
    if live.size < 2:
        return []
    en = e[:, live] / norms[live]
    out = []
    names = data.input_names
    # identical (or proportional) pairs: named explicitly
    corr = en.T @ en
    pairs = []
    for a in range(live.size):
        for b in range(a + 1, live.size):
            if abs(corr[a, b]) > 1 - 1e-9:
                pairs.append((live[a], live[b]))
                out.append(
                    f"excitation '{key}': channels '{names[live[a]]}' and '{names[live[b]]}' "
                    f"({live[a]}, {live[b]}) are proportional (correlation {corr[a, b]:+.6f}): "
                    "their effects cannot be told apart"
                )
    if not pairs:
        s = np.linalg.svd(en, compute_uv=False)
        rank = int(np.sum(s > _DEPENDENT_TOL * s[0]))
        if rank < live.size:
            # the channels carrying the null direction
            _, _, vt = np.linalg.svd(en, full_matrices=False)
            null = vt[-1]
            involved = [int(live[i]) for i in np.flatnonzero(np.abs(null) > 1e-3)]
            out.append(
                f"excitation '{key}': rank {rank} of {live.size}; channels "
                f"{', '.join(repr(names[i]) for i in involved)} ({involved}) are linearly dependent"
            )
    out += _per_line_rank(data, key, e)
    return out


def _record(data: TimeData):
    """The record's experiment blocks, all periods kept (None if not periodic or no excitation)."""
    from workbench.core.errors import InputError
    from workbench.signals.periodic import periodic_record

    if data.period is None:
        return None
    try:
        return periodic_record(data, n_transient=0)
    except InputError:
        return None


def _per_line_rank(data: TimeData, key: str, e: np.ndarray) -> list[str]:
    """Multi-experiment periodic data: the excitation matrix across experiments, per line.

    With identical periods (one periodic experiment) each line sees one input
    direction only, by design; that is not checked here (``info`` states it).
    When the record holds several experiments (blocks of identical periods,
    :mod:`workbench.signals.periodic`), at each excited line the (n_blocks, n_u) matrix
    of their input spectra must have full column rank for a per-line MIMO estimate.
    """
    rec = _record(data)
    if rec is None or rec.n_blocks < 2:
        return []
    E = rec.R if data.r is not None else rec.U  # (n_b, n_bins, n_u), the excitation's
    excited = rec.lines
    n_u = e.shape[1]
    s = np.linalg.svd(np.moveaxis(E[:, excited, :], 1, 0), compute_uv=False)  # (n_ex, min(b,u))
    rank = np.sum(s > _DEPENDENT_TOL * s[:, :1], axis=1)
    bad = np.zeros(E.shape[1], bool)
    bad[excited[rank < n_u]] = True
    if not bad.any():
        return []
    spans = runs(bad, gap=max(1, int(np.median(np.diff(excited))) if excited.size > 1 else 1))
    return [
        f"excitation '{key}': per-line excitation matrix over the {rec.n_blocks} experiments "
        f"(blocks of identical periods) has rank {int(rank.min())} < {n_u} inputs at "
        f"{int(bad.sum())} lines ({_band_text(rec.freq_hz, spans)}): "
        "the inputs cannot be separated there"
    ]


def _closed_without_r(data: TimeData) -> list[str]:
    if data.loop == "closed" and data.r is None:
        return [
            "closed-loop data without the reference 'r': the noise is correlated with 'u', "
            "so open-loop estimates from (u, y) are biased"
        ]
    return []


def _clipped(x: np.ndarray, names: tuple[str, ...], what: str) -> list[str]:
    out = []
    for i, name in enumerate(names):
        col = x[:, i]
        if np.ptp(col) == 0:
            continue
        values, counts = np.unique(col, return_counts=True)
        typical = max(1.0, float(np.median(counts)))
        for label, c in (("max", counts[-1]), ("min", counts[0])):
            if c >= _CLIP_MIN_COUNT and c >= _CLIP_RATIO * typical:
                v = values[-1] if label == "max" else values[0]
                out.append(
                    f"{what} '{name}' (channel {i}) looks clipped: {int(c)} samples "
                    f"({100 * c / col.size:.1f} %) sit exactly at its {label} {v:g}"
                )
    return out


def _excitation_spectrum(data: TimeData) -> tuple[np.ndarray, np.ndarray, bool]:
    """Total excitation power per line, (n_lines,), and the line frequencies, Hz.

    Periodic data: the DFT power per period averaged over periods (exact lines,
    zeros where not excited). Otherwise a Welch estimate, smooth by construction.
    """
    e, _ = _excitation(data)
    e = e - e.mean(axis=0)
    rec = _record(data) if data.period is not None and data.period >= 8 else None
    if rec is not None:
        # mean power over the experiment blocks (multi-experiment blocks differ in phase)
        return rec.ref_power.mean(axis=0)[1:], rec.freq_hz[1:], True
    import scipy.signal

    nper = int(min(data.n_samples, max(64, 2 ** int(np.log2(max(data.n_samples // 8, 1))))))
    f, p = scipy.signal.welch(e, fs=data.fs, nperseg=nper, axis=0)
    return np.sum(p[1:], axis=1), f[1:], False


def _excitation_gaps(data: TimeData) -> list[str]:
    if data.n_samples < 64:
        return []
    power, freq, periodic = _excitation_spectrum(data)
    if power.size < 8 or power.max() <= 0:
        return []
    _, key = _excitation(data)
    strong = np.flatnonzero(power >= _BAND_POWER * power.max())
    lo, hi = strong[0], strong[-1]
    # periodic: the excited lines (exact zeros elsewhere); Welch: every line in the band
    if periodic:
        lines = np.flatnonzero(power > EXCITED_REL_POWER * power.max())
        lines = lines[(lines >= lo) & (lines <= hi)]
    else:
        lines = np.arange(lo, hi + 1)
    if lines.size < 5:
        return []
    out = []
    # (a) lines much weaker than their excited neighbours; the reference is the
    # upper quartile over a window of +-10 % of the lines, so that a gap up to a
    # quarter of the window wide does not pull the reference down with it
    import scipy.ndimage

    p = power[lines]
    half = max(10, lines.size // 10)
    ref = scipy.ndimage.percentile_filter(p, 75, size=2 * half + 1, mode="reflect")
    weak = p < _WEAK_POWER * ref
    min_run = 1 if periodic else 3  # Welch lines are correlated: one weak bin is not a gap
    spans = [(s, e) for s, e in runs(weak) if e - s >= min_run]
    if spans:
        fl = freq[lines]
        out.append(
            f"excitation '{key}': gap in the excited band {freq[lo]:g}-{freq[hi]:g} Hz, "
            f"{sum(e - s for s, e in spans)} lines more than 20 dB below their neighbours at "
            f"{_band_text(fl, spans)}"
        )
    # (b) periodic: holes in the grid of excited lines
    if periodic and lines.size > 5:
        out += _grid_gaps(freq[lines], f"excitation '{key}': gap in the excited lines")
    return out


def _grid_gaps(freq: np.ndarray, prefix: str) -> list[str]:
    """Spacings far wider than the local typical spacing (works for log grids too)."""
    d = np.diff(freq)
    if d.size < 4:
        return []
    half = 5
    local = np.array(
        [
            np.median(np.delete(d[max(0, k - half) : k + half + 1], min(k, half)))
            for k in range(d.size)
        ]
    )
    big = np.flatnonzero(d > _GRID_GAP * local)
    if big.size == 0:
        return []
    parts = [
        f"{freq[k]:g}-{freq[k + 1]:g} Hz ({d[k] / local[k]:.0f}x the spacing)" for k in big[:4]
    ]
    if big.size > 4:
        parts.append(f"and {big.size - 4} more")
    return [f"{prefix}: no lines between {', '.join(parts)}"]


# ------------------------------------------------------------------- FRF data
def _noise_dominated(data: FrfData) -> list[str]:
    """One summary line: where the noise variance exceeds |G|^2 (SNR below 0 dB).

    Isolated lines are expected near small elements (|G|^2 / G_var is
    exponential-like), so only runs of at least ``_SNR_MIN_RUN`` lines (merged
    over gaps of 2) count. Small cross-couplings are often below the noise over
    wide bands; one line lists the worst elements with their widest band
    rather than one warning per element.
    """
    if data.G_var is None:
        return []
    bad = data.G_var >= np.abs(data.G) ** 2  # (n_f, n_y, n_u)
    found = []  # (share, label, widest span, n_lines)
    total = 0
    for i, yname in enumerate(data.output_names):
        for j, uname in enumerate(data.input_names):
            spans = [(s, e) for s, e in runs(bad[:, i, j], gap=2) if e - s >= _SNR_MIN_RUN]
            if not spans:
                continue
            n = int(sum(bad[s:e, i, j].sum() for s, e in spans))
            total += n
            widest = max(spans, key=lambda se: se[1] - se[0])
            found.append((n / data.n_f, f"'{yname}'/'{uname}' ({i},{j})", widest))
    if not found:
        return []
    found.sort(key=lambda x: -x[0])
    parts = [
        f"{label} {100 * share:.0f} % (widest {data.freq[s]:g}-{data.freq[e - 1]:g} Hz)"
        for share, label, (s, e) in found[:5]
    ]
    if len(found) > 5:
        parts.append(f"and {len(found) - 5} more elements")
    return [
        f"FRF noise variance exceeds |G|^2 (SNR < 0 dB) on {total} of "
        f"{data.G.size} element-lines in {len(found)} elements (output, input): {'; '.join(parts)}"
    ]


def _open_loop_method(data: TimeData, method: str | None) -> list[str]:
    if method is None or method.startswith("cl-") or data.loop != "closed":
        return []
    how = "with" if data.r is not None else "without"
    return [
        f"open-loop method {method!r} on closed-loop data ({how} 'r'): the noise is correlated "
        "with 'u', so the estimate is biased"
        + (
            "; use a closed-loop method (cl-moesp) on the recorded 'r'"
            if data.r is not None
            else "; record the excitation 'r' and use a closed-loop method (cl-moesp)"
        )
    ]


# -------------------------------------------------------------------- public
def check_measurement(
    data: TimeData | FrfData, *, src: str = "measurement", method: str | None = None
) -> list[str]:
    """Check a measurement for poor data; warn and return the messages.

    Parameters
    ----------
    data : TimeData or FrfData
        A validated measurement (``workbench.io.formats``).
    src : str
        Name of the source (file) for the messages.
    method : str, optional
        The estimator the caller runs on a time record (``workbench identify``'s
        ``--method``): an open-loop one on closed-loop data is warned about.

    Returns
    -------
    list of str
        One message per finding, each naming the channel or band; empty for
        good data. Each is also emitted with
        ``warnings.warn(message, DataWarning, stacklevel=2)``.
    """
    if isinstance(data, TimeData):
        msgs = (
            _constant_inputs(data)
            + _dependent_excitation(data)
            + _closed_without_r(data)
            + _open_loop_method(data, method)
            + _clipped(data.y, data.output_names, "sensor")
            + _excitation_gaps(data)
        )
    elif isinstance(data, FrfData):
        msgs = _noise_dominated(data) + _grid_gaps(data.freq, "frequency lines")
    else:
        raise TypeError(f"data: expected TimeData or FrfData, got {type(data).__name__}")
    msgs = [f"{src}: {m}" for m in msgs]
    for m in msgs:
        warnings.warn(m, DataWarning, stacklevel=2)
    return msgs


#: poles with |s| / 2 pi below this count as rigid-body poles at 0 (Hz)
RIGID_POLE_HZ = 0.01


def unstable_poles(model, *, rigid_hz: float = RIGID_POLE_HZ) -> np.ndarray:
    """Continuous-time poles (rad/s) in the open right half plane, rigid-body poles at 0 excepted.

    A discrete model's poles are mapped by ``s = fs log z``; the input delay
    does not matter. A pole counts as unstable when its real part exceeds
    ``1e-9 |s|`` (round-off of a marginally stable pair) and it is not within
    ``rigid_hz`` of 0 (a rigid-body double integrator identified with a
    slightly unstable pole pair is still a rigid body).
    """
    from workbench.core.model import as_model

    m = as_model(model)
    A = np.asarray(m.A, float)
    if A.size == 0:
        return np.zeros(0, complex)
    p = np.linalg.eigvals(A).astype(complex)
    if m.dt:
        p = np.log(np.where(p == 0, 1e-300, p)) / m.dt
    w = np.abs(p)
    bad = (p.real > 1e-9 * np.maximum(w, 1.0)) & (w > 2 * np.pi * rigid_hz)
    out = p[bad]
    return out[np.argsort(np.abs(out))]


def check_model(model, *, src: str = "model") -> list[str]:
    """Warn (one line) when ``model`` has unstable poles other than rigid-body poles at 0.

    Returns the messages (zero or one), each also emitted as a
    :class:`~workbench.core.errors.DataWarning` with ``stacklevel=2``.
    """
    p = unstable_poles(model)
    if p.size == 0:
        return []
    p = p[p.imag >= 0]  # one of each conjugate pair
    parts = []
    for s_k in p[:6]:
        f = abs(s_k) / (2 * np.pi)
        kind = "pair" if abs(s_k.imag) > 0 else "real"
        parts.append(f"{f:.4g} Hz ({kind}, growth {s_k.real:.3g} 1/s)")
    if p.size > 6:
        parts.append(f"and {p.size - 6} more")
    n = int(unstable_poles(model).size)
    msgs = [
        f"{src}: model has {n} unstable pole(s) other than rigid-body poles at 0: "
        f"{', '.join(parts)}; its simulation grows without bound"
    ]
    for m in msgs:
        warnings.warn(m, DataWarning, stacklevel=2)
    return msgs
