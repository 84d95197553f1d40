"""Discrete to continuous time: the inverse of the zero-order-hold discretization.

python-control has ``c2d`` but no ``d2c``. With ZOH,
``[[Ad, Bd], [0, I]] = expm([[A, B], [0, 0]] dt)``, so the matrix logarithm of
the left side, divided by ``dt``, returns ``A`` and ``B`` at once; ``C`` and
``D`` are unchanged.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from workbench.core.errors import InputError
from workbench.core.lti import as_matrices

__all__ = ["d2c", "check_log_defined"]


def check_log_defined(Ad: np.ndarray, *, zero_tol: float = 1e-6, axis_tol: float = 1e-9) -> None:
    """Refuse a discrete ``A`` whose real matrix logarithm does not exist (or is not unique).

    Parameters
    ----------
    Ad : (n, n) array
        Discrete state matrix.
    zero_tol : float
        Poles with ``|z| < zero_tol`` count as poles at 0 (pure delays).
    axis_tol : float
        Poles with ``|Im z| <= axis_tol |z|`` and ``Re z < 0`` count as on the
        negative real axis.

    Raises
    ------
    InputError
        Naming the offending poles and what they usually are.
    """
    z = np.linalg.eigvals(np.asarray(Ad, float))
    at_zero = z[np.abs(z) < zero_tol]
    if at_zero.size:
        raise InputError(
            f"model: cannot convert to continuous time: {at_zero.size} pole(s) at z = 0 "
            f"(|z| < {zero_tol:g}: {_fmt(at_zero)}), which have no logarithm; they are usually "
            "the states of an input delay: identify with a known input delay (--input-delay) "
            "or remove those states before the modal analysis"
        )
    neg = z[(z.real < 0) & (np.abs(z.imag) <= axis_tol * np.abs(z))]
    if neg.size:
        raise InputError(
            f"model: cannot convert to continuous time: {neg.size} pole(s) on the negative real "
            f"axis ({_fmt(neg)}): the ZOH maps no real continuous pole there (a mode at exactly "
            "the Nyquist frequency or a sampling artefact); lower the model order or resample"
        )


def _fmt(z: np.ndarray) -> str:
    return ", ".join(
        f"{v.real:.4g}{v.imag:+.4g}j" if v.imag else f"{v.real:.4g}" for v in z[:6]
    ) + (", ..." if z.size > 6 else "")


def d2c(sys, *, zero_tol: float = 1e-6):
    """Continuous-time model whose ZOH discretization is ``sys``.

    The one discrete-to-continuous conversion of the workbench (modal
    analysis, identification and diagnosis all use it).

    Parameters
    ----------
    sys : control.StateSpace or LTIModel
        Discrete model, ``dt > 0`` s; ``A`` (n, n), ``B`` (n, n_u),
        ``C`` (n_y, n), ``D`` (n_y, n_u).
    zero_tol : float
        Poles with ``|z| < zero_tol`` are refused as poles at 0.

    Returns
    -------
    control.StateSpace or LTIModel
        Continuous model (``dt = 0``) of the same kind as ``sys``, same state
        coordinates, same ``C``, ``D``, names (and, for an LTIModel, delay).

    Raises
    ------
    InputError
        A continuous model, or poles at ``z = 0`` or on the negative real axis.

    Notes
    -----
    ``logm([[Ad, Bd], [0, I]]) / dt = [[A, B], [0, 0]]`` (principal logarithm;
    exact inverse of ZOH for poles with ``|Im s| < pi / dt``, i.e. below
    Nyquist). A double pole at ``z = 1`` (rigid body) is fine: its logarithm is
    the nilpotent Jordan block. References: G.F. Franklin, J.D. Powell, M.L.
    Workman, Digital Control of Dynamic Systems, 3rd ed., 1998, sec. 4.3;
    N.J. Higham, Functions of Matrices, SIAM 2008, ch. 11.
    """
    import control

    A, B, C, D, dt = as_matrices(sys)
    if dt <= 0:
        raise InputError("model: d2c expects a discrete model (dt > 0), got a continuous one")
    n, n_u = B.shape
    check_log_defined(A, zero_tol=zero_tol)
    M = np.zeros((n + n_u, n + n_u))
    M[:n, :n] = A
    M[:n, n:] = B
    M[n:, n:] = np.eye(n_u)
    L = scipy.linalg.logm(M)
    if np.iscomplexobj(L):
        if np.max(np.abs(L.imag)) > 1e-8 * max(1.0, np.max(np.abs(L.real))):
            raise InputError(
                "model: cannot convert to continuous time: the matrix logarithm is not real"
            )
        L = L.real
    L = L / dt
    from workbench.core.model import LTIModel

    if isinstance(sys, LTIModel):
        return sys.replace(A=L[:n, :n], B=L[:n, n:], dt=0.0)
    return control.ss(
        L[:n, :n],
        L[:n, n:],
        C,
        D,
        0,
        inputs=list(sys.input_labels),
        outputs=list(sys.output_labels),
    )
