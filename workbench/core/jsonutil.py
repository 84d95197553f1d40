"""Plain JSON from the workbench's results (NumPy arrays and scalars, non-finite values)."""

from __future__ import annotations

import math

import numpy as np


def jsonable(x):
    """``x`` with arrays as lists, NumPy scalars as Python ones, NaN/inf as None.

    Complex numbers become ``{"re": ..., "im": ...}``; dict keys become strings.
    """
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, complex):
        return {"re": jsonable(x.real), "im": jsonable(x.imag)}
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
