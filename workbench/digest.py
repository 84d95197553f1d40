"""The readable text of a run's summary: what ``workbench run`` prints and its report shows."""

from __future__ import annotations

__all__ = ["run_digest"]


def run_digest(summary: dict) -> str:
    """A readable summary: the few numbers a person wants first; everything is in summary.json.

    One section per stage that ran, in pipeline order, each a few lines of plain
    text (errors before -> after, findings with their key parameters, design
    crossovers); a stage this function does not know is shown as its scalar
    figures, wrapped, never as a raw JSON line.
    """
    sc = summary.get("scenario", {})
    lines = [f"scenario {sc.get('name', '?')} (seed {sc.get('seed', '?')})"]
    for key, section in summary.items():
        if key in ("scenario", "files") or not isinstance(section, dict):
            continue
        fmt = _SECTIONS.get(key, _generic)
        try:
            text = fmt(section)
        except (AttributeError, KeyError, TypeError, ValueError, IndexError):  # shape changed
            text = _generic(section)
        if text:
            lines.append(f"{key}: " + text if not text.startswith("\n") else key + ":" + text)
    secs = sc.get("stage_seconds") or {}
    if secs:
        lines.append(
            "time: "
            + ", ".join(f"{k} {v:.1f} s" for k, v in secs.items())
            + f" (total {sum(secs.values()):.1f} s)"
        )
    return "\n".join(_wrap(line) for line in lines)


# ------------------------------------------------------------------ formatting
def _num(v) -> str:
    if isinstance(v, bool) or v is None:
        return {True: "yes", False: "no", None: "-"}[v]
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


_UNITS = {"_hz": " Hz", "_s": " s", "_pa": " Pa"}
_SKIP = {"matrix", "residue_matrix", "text", "singular_values", "notes"}
#: a finding's mode-shape vectors: in findings.json, too long for a summary line
_SHAPES = {"b", "c", "residues", "shape", "mode_shape", "b_vec", "c_vec"}


def _param(key: str, v) -> str | None:
    """One ``key=value`` of a finding's parameters; matrices are named, not printed."""
    if key in _SKIP:
        return f"{key} ({len(v)}x{len(v[0])})" if key == "matrix" and v and v[0] else None
    if key == "delay_s" and isinstance(v, int | float):
        return f"delay {v * 1e6:.4g} us"
    unit = next((u for suf, u in _UNITS.items() if key.endswith(suf)), "")
    if isinstance(v, dict):
        inner = [x for x in (_param(k, w) for k, w in v.items()) if x]
        return f"{key} {{{', '.join(inner)}}}" if inner else None
    if isinstance(v, list | tuple):
        if not v:
            return None
        if isinstance(v[0], dict):  # e.g. modal_mismatch's modes
            return f"{len(v)} {key}"
        vals = [_num(x) for x in v[:6]] + (["..."] if len(v) > 6 else [])
        return f"{key} [{', '.join(vals)}]{unit}"
    return f"{key} {_num(v)}{unit}"


def _params(p: dict) -> str:
    items = ((k, v) for k, v in (p or {}).items() if k not in _SHAPES)
    return ", ".join(x for x in (_param(k, v) for k, v in items) if x)


def _compare(c: dict) -> str:
    if not c:
        return ""
    within = c.get("within_noise")
    verdict = "within noise" if within else f"{c.get('failing_bands', '?')} failing band(s)"
    return f"error {_num(c.get('error'))}, {verdict}"


def _diagnose(d: dict) -> str:
    out = [f"error before {_num(d.get('error_before'))}"]
    for k, f in enumerate(d.get("findings", []), 1):
        params = _params(f.get("parameters", {}))
        out.append(
            f"  {k}. {f.get('effect')}"
            + (f" ({params})" if params else "")
            + f" -> error after {_num(f.get('error_after'))}"
        )
    return "\n" + "\n".join("  " + x if i == 0 else x for i, x in enumerate(out))


def _augment(a: dict) -> str:
    steps = a.get("steps", [])
    if not steps:
        return a.get("note", "nothing added")
    added = ", ".join(s.get("effect", "?") for s in steps)
    last = steps[-1].get("error_after")
    after = _compare(a.get("compare_after", {}))
    return f"added {added} (error after {_num(last)}); compare after: {after}"


def _design(d: dict) -> str:
    out = []
    for method, v in d.get("designs", {}).items():
        if isinstance(v, dict) and "crossover_hz" in v:
            xs = ", ".join(_num(x) for x in v["crossover_hz"])
            out.append(f"{method} crossovers [{xs}] Hz")
        else:
            out.append(f"{method} {v}")
    head = "" if d.get("minimal", True) else "model not minimal; "
    return head + "; ".join(out)


def _text_block(key: str):
    def fmt(section: dict) -> str:
        text = section.get("text")
        # the text holds the table; the other figures only when they are not in it
        drop = {"text", "parameters"} if key == "update" else {"text"}
        rest = (
            "" if key == "modes" else _generic({k: v for k, v in section.items() if k not in drop})
        )
        block = "\n" + "\n".join("  " + x for x in str(text).splitlines()) if text else ""
        return (rest + block) if rest else block

    return fmt


def _generic(section: dict) -> str:
    """The scalar figures (and short lists) of a section, ``key value`` joined."""
    parts = []
    for k, v in section.items():
        if k in _SKIP:
            continue
        if isinstance(v, dict):
            inner = _generic(v)
            if inner:
                parts.append(f"{k} ({inner})")
        elif isinstance(v, list | tuple):
            if len(v) <= 6 and all(isinstance(x, int | float | str) for x in v):
                parts.append(_param(k, list(v)) or "")
        else:
            parts.append(_param(k, v) or "")
    return ", ".join(p for p in parts if p)


def _wrap(line: str, width: int = 100) -> str:
    import textwrap

    out = []
    for part in line.split("\n"):
        if len(part) <= width:
            out.append(part)
        else:
            indent = " " * (len(part) - len(part.lstrip()) + 4)
            out.append(textwrap.fill(part, width, subsequent_indent=indent))
    return "\n".join(out)


_SECTIONS = {
    "compare": _compare,
    "diagnose": _diagnose,
    "augment": _augment,
    "design": _design,
    "modes": _text_block("modes"),
    "evaluate": _text_block("evaluate"),
    "update": _text_block("update"),
}
