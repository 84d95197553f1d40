"""Model order from the singular values of a subspace method: a suggestion and a plot."""

from __future__ import annotations

import os

import numpy as np

__all__ = [
    "suggest_order",
    "gap_verdict",
    "plot_singular_values",
    "format_singular_values",
    "format_order_scan",
    "plot_order_scan",
    "order_where_fit_stops_paying",
    "runner_up_gap",
]

# Gap ratios s[n-1]/s[n]: at or above CLEAR_GAP the singular values decide the
# order (the simulator's records give 20-100); below WEAK_GAP they do not (a
# real record with coloured noise and unmodelled dynamics decays smoothly: the
# CD-player arm gives 1.75) and the order is a modelling choice for the
# validation fit.
CLEAR_GAP = 10.0
WEAK_GAP = 3.0


def suggest_order(singular_values, *, max_order: int) -> tuple[int, float]:
    """Order at the largest relative gap of the singular values.

    Parameters
    ----------
    singular_values : (n_sv,) array
        Largest first, >= 0.
    max_order : int
        Largest order considered.

    Returns
    -------
    order : int
        ``n`` maximizing ``s[n-1] / s[n]`` over ``1 <= n <= max_order``; of
        gaps within a factor 2 (in log) of the largest, the highest order, so
        that weak but clearly separated modes (flexible modes next to the
        dominant rigid-body states) are kept.
    gap : float
        ``s[order-1] / s[order]``.

    Notes
    -----
    Noise spreads the singular values of the unmodelled directions into a
    slowly decaying floor; the system's own directions stand above it. The
    rule is a suggestion: the plot of :func:`plot_singular_values` shows what
    it rests on, and the user overrides it with an explicit order.
    """
    s = np.asarray(singular_values, float)
    n_max = max(1, min(int(max_order), s.size - 1))
    floor = np.finfo(float).tiny
    logs = np.log10(np.maximum(s[: n_max + 1], floor))
    gaps = logs[:-1] - logs[1:]  # gaps[n-1] = log10(s[n-1]/s[n])
    if gaps.size == 0:
        return 1, float("inf")
    best = float(np.max(gaps))
    candidates = np.flatnonzero(gaps >= 0.5 * best)
    n = int(candidates[-1]) + 1
    return n, float(10 ** gaps[n - 1])


def gap_verdict(gap: float, *, runner_up: float | None = None) -> str:
    """Plain words on how far a gap ratio decides the order.

    ``runner_up``: the second-largest gap ratio among the orders considered;
    a gap that barely beats it is no decision either.
    """
    gap = float(gap)
    close = runner_up is not None and np.isfinite(gap) and runner_up > gap ** (2.0 / 3.0)
    if gap >= CLEAR_GAP and not close:
        return f"clear gap (ratio {gap:.3g} >= {CLEAR_GAP:g}): the singular values decide the order"
    if gap >= WEAK_GAP:
        return (
            f"moderate gap (ratio {gap:.3g}"
            + (f", next largest {runner_up:.3g}" if runner_up is not None else "")
            + "): plausible order; confirm it by validation fit (--orders A:B)"
        )
    return (
        f"NO clear gap (ratio {gap:.3g} < {WEAK_GAP:g}"
        + (f", next largest {runner_up:.3g}" if runner_up is not None else "")
        + "): the singular values do not decide the order here; choose it by validation fit "
        "(--validate FRACTION --orders A:B)"
    )


def runner_up_gap(s: np.ndarray, suggested: int, n_max: int) -> float | None:
    s = np.asarray(s, float)[: n_max + 1]
    if s.size < 3:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = s[:-1] / s[1:]
    ratios = np.delete(ratios, suggested - 1)
    ratios = ratios[np.isfinite(ratios)]
    return float(ratios.max()) if ratios.size else None


def format_singular_values(
    singular_values,
    *,
    order: int,
    suggested: int,
    gap: float,
    n_show: int = 40,
    max_order: int | None = None,
) -> str:
    """Text table of the leading singular values, the suggestion and the chosen order."""
    s = np.asarray(singular_values, float)
    lines = ["  n   singular value   ratio to next"]
    for k in range(min(n_show, s.size)):
        ratio = s[k] / s[k + 1] if k + 1 < s.size and s[k + 1] > 0 else float("inf")
        mark = ""
        if k + 1 == suggested:
            mark += "  <- suggested"
        if k + 1 == order and order != suggested:
            mark += "  <- chosen"
        lines.append(f"{k + 1:3d}   {s[k]:14.6e}   {ratio:12.4g}{mark}")
    lines.append(
        f"suggested order {suggested} (gap s[{suggested}]/s[{suggested + 1}] = {gap:.4g}); "
        f"order used {order}"
    )
    n_max = max_order if max_order is not None else s.size - 1
    lines.append(gap_verdict(gap, runner_up=runner_up_gap(s, suggested, n_max)))
    return "\n".join(lines)


def plot_singular_values(
    singular_values, path: str | os.PathLike, *, order: int, suggested: int, title: str = ""
) -> None:
    """Save a semilog plot of the singular values with the chosen and suggested orders (PNG)."""
    from matplotlib.figure import Figure  # no pyplot: no global state, any backend

    from workbench.core.atomic import atomic_path

    s = np.asarray(singular_values, float)
    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.subplots()
    k = np.arange(1, s.size + 1)
    ax.semilogy(k, s, "o-", ms=3)
    ax.axvline(suggested + 0.5, color="tab:green", ls="--", label=f"suggested n = {suggested}")
    if order != suggested:
        ax.axvline(order + 0.5, color="tab:red", ls=":", label=f"chosen n = {order}")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value")
    ax.set_title(title or "Subspace singular values")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)


def order_where_fit_stops_paying(orders, mean_fits, *, tolerance: float = 1.0) -> int:
    """Smallest order whose mean validation fit is within ``tolerance`` points of the best."""
    orders = np.asarray(orders, int)
    f = np.asarray(mean_fits, float)
    best = np.nanmax(f)
    return int(orders[np.flatnonzero(f >= best - tolerance)[0]])


def format_order_scan(orders, fits, *, output_names, tolerance: float = 1.0) -> str:
    """Table of the validation fit per order (``fits``: :class:`~workbench.ident.validate.Fit`)."""
    names = list(output_names)
    head = "  n  " + " ".join(f"{n[:10]:>10s}" for n in names) + "   mean fit (%)"
    lines = [head]
    means = [f.mean for f in fits]
    if not np.any(np.isfinite(means)):
        return "\n".join([head, "every order diverges on the validation part (unstable models)"])
    best = int(orders[int(np.nanargmax(means))])
    pay = order_where_fit_stops_paying(orders, means, tolerance=tolerance)
    for n, f in zip(orders, fits):
        mark = ("  <- best" if n == best else "") + (
            f"  <- within {tolerance:g} point of the best" if n == pay and n != best else ""
        )
        if f.note:
            mark += f"  ({f.note})"
        lines.append(
            f"{n:3d}  " + " ".join(f"{v:10.1f}" for v in f.fit) + f"   {f.mean:10.1f}{mark}"
        )
    lines.append(
        f"validation fit (initial state by least squares): best {max(means):.1f} % at order "
        f"{best}; more states stop paying at order {pay} (within {tolerance:g} point of the best)"
    )
    return "\n".join(lines)


def plot_order_scan(
    orders, fits, path: str | os.PathLike, *, output_names, title: str = ""
) -> None:
    """Save the validation fit against the order, per output and mean (PNG)."""
    from matplotlib.figure import Figure

    from workbench.core.atomic import atomic_path

    orders = np.asarray(orders, int)
    F = np.array([f.fit for f in fits], float)
    F[~np.isfinite(F)] = np.nan  # a diverging (unstable) model: a gap in the curve
    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.subplots()
    for k, name in enumerate(output_names):
        ax.plot(orders, F[:, k], "o-", ms=3, alpha=0.6, label=str(name))
    ax.plot(orders, F.mean(axis=1), "ks-", ms=4, lw=2, label="mean")
    ax.set_xlabel("model order n")
    ax.set_ylabel("validation fit (%)")
    if np.any(np.isfinite(F)):
        # a very poor order must not flatten the rest
        lo = max(np.nanmin(F), np.nanmax(F) - 40.0)
        ax.set_ylim(lo - 2.0, min(100.0, np.nanmax(F)) + 2.0)
    ax.set_title(title or "Validation fit by order (initial state by least squares)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
