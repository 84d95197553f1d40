"""Read-only array copies for the frozen dataclasses of the project."""

from __future__ import annotations

import numpy as np


def readonly(a, dtype=None) -> np.ndarray:
    """A copy of ``a`` (as ``dtype`` if given) that cannot be written to.

    Frozen dataclasses hold these, so a model, measurement or result never
    changes under the feet of whoever holds it, and never aliases the caller's
    array.
    """
    out = np.array(a, dtype=dtype, copy=True)
    out.setflags(write=False)
    return out
