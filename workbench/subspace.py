"""Subspace identification (compatibility entry point); see :mod:`workbench.ident`."""

from workbench.ident import (
    METHODS,
    SubspaceResult,
    format_singular_values,
    identify_subspace,
    plot_singular_values,
    suggest_order,
)

__all__ = [
    "METHODS",
    "SubspaceResult",
    "identify_subspace",
    "suggest_order",
    "format_singular_values",
    "plot_singular_values",
]
