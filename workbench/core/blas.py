"""BLAS threads for a call, as an explicit argument rather than a process-wide switch.

The workbench's inner loops (diagnosis screening, modal fits) do many small dense
operations; on a 2-core machine BLAS threads add synchronisation, not speed
(measured 3-100x slower with two threads on a loaded machine). Functions that
know this take ``blas_threads`` and apply it only for their own duration.
"""

from __future__ import annotations

import contextlib


def limited_blas(threads: int | None):
    """Context manager: at most ``threads`` BLAS threads inside, the caller's setting after.

    ``None`` leaves the caller's setting untouched (nothing is changed).
    """
    if threads is None:
        return contextlib.nullcontext()
    if int(threads) < 1:
        from workbench.core.errors import InputError

        raise InputError(f"blas_threads: expected an integer >= 1 or None, got {threads!r}")
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=int(threads), user_api="blas")
