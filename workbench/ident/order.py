"""Model order from the singular values of a subspace method: a suggestion and a plot."""

from __future__ import annotations

import os

import numpy as np

__all__ = ["suggest_order", "plot_singular_values", "format_singular_values"]


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


def format_singular_values(
    singular_values, *, order: int, suggested: int, gap: float, n_show: int = 40
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
    return "\n".join(lines)


def plot_singular_values(
    singular_values, path: str | os.PathLike, *, order: int, suggested: int, title: str = ""
) -> None:
    """Save a semilog plot of the singular values with the chosen and suggested orders (PNG)."""
    from matplotlib.figure import Figure  # no pyplot: no global state, any backend

    from workbench.atomic import atomic_path

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
