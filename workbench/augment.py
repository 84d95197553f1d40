"""Add one named physical effect to a model, fit it to the data, return the augmented model.

The same engine as :func:`workbench.diagnosis.diagnose`, restricted to one
effect: every structure of that effect is screened and fitted (for
``modal_mismatch`` each mode of the model in the band, for ``crosstalk`` both
the output and the input side) and the best is kept.

A delay is exact, exp(-s delay_s), on frequency responses; in state space it is
kept apart (``delay_s``) and, for tools that need states, also given as a Pade
approximation (:func:`pade_delay`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from workbench.diagnosis import LINEAR_EFFECTS, detect
from workbench.diagnosis.diagnose import _spec_error
from workbench.diagnosis.effects import candidate_structures
from workbench.diagnosis.fit import FitResult, fit, screen
from workbench.diagnosis.modal import ExtendedModel, decompose
from workbench.diagnosis.problem import make_problem
from workbench.errors import InputError
from workbench.formats import FrfData, TimeData, check_model_matches
from workbench.jsonutil import jsonable
from workbench.lti import as_matrices
from workbench.nonlinear import PortNonlinearity

__all__ = ["EFFECTS", "Augmented", "augment", "pade_delay"]

#: what ``augment`` can add: every effect of the vocabulary but 'none'
EFFECTS = LINEAR_EFFECTS + ("nonlinearity",)


@dataclass(frozen=True)
class Augmented:
    """A model with one effect added and fitted.

    Attributes
    ----------
    model : control.StateSpace
        Continuous linear part with the effect (the delay kept apart).
    delay_s : float
        Input-output delay, s (exact exp(-s delay_s)).
    effect : str
    parameters, parameters_std : dict
        Fitted physical parameters and standard deviations.
    error_before, error_after : float
        The spec error measure before and after.
    extended : ExtendedModel or None
        The modal representation (None for nonlinearity).
    """

    model: Any
    delay_s: float
    effect: str
    parameters: dict
    parameters_std: dict
    error_before: float
    error_after: float
    extended: ExtendedModel | None = field(default=None, repr=False)
    note: str = ""
    nonlinear: PortNonlinearity | None = field(default=None, repr=False)

    def to_json(self) -> dict:
        return {
            "effect": self.effect,
            "parameters": jsonable(self.parameters),
            "parameters_std": jsonable(self.parameters_std),
            "delay_s": float(self.delay_s),
            "error_before": float(self.error_before),
            "error_after": float(self.error_after),
            "note": self.note,
        }


def pade_delay(delay_s: float, order: int):
    """Pade approximation of exp(-s delay_s) as a SISO ``control.StateSpace`` (order states)."""
    import control

    num, den = control.pade(delay_s, order)
    return control.ss(control.tf(num, den))


def pade_order(delay_s: float, f_max_hz: float, *, max_phase_error_deg: float = 1.0) -> int:
    """Smallest Pade order whose phase error stays below the limit up to ``f_max_hz``."""
    import control

    if delay_s <= 0:
        return 0
    w = 2 * np.pi * np.linspace(f_max_hz / 50, f_max_hz, 50)
    for n in range(1, 11):
        num, den = control.pade(delay_s, n)
        h = np.polyval(num, 1j * w) / np.polyval(den, 1j * w)
        err = np.degrees(np.abs(np.angle(h * np.exp(1j * w * delay_s))))
        if err.max() < max_phase_error_deg:
            return n
    return 10


def with_pade(sys, delay_s: float, order: int):
    """``sys`` with a Pade delay of ``order`` states on every input (continuous)."""
    import control

    if order == 0 or delay_s <= 0:
        return sys
    n_u = sys.ninputs
    d = pade_delay(delay_s, order)
    A = np.kron(np.eye(n_u), d.A)
    B = np.kron(np.eye(n_u), d.B)
    C = np.kron(np.eye(n_u), d.C)
    D = np.kron(np.eye(n_u), d.D)
    return control.series(control.ss(A, B, C, D), sys)


def augment(
    model, data: FrfData | TimeData, effect: str, *, blas_threads: int | None = 1
) -> Augmented:
    """Add ``effect`` to ``model``, fit its parameters to ``data``.

    Parameters
    ----------
    model : control.StateSpace
        Continuous or discrete (dt = 1/fs for time data) model.
    data : FrfData or TimeData
    effect : str
        One of :data:`EFFECTS`.
    blas_threads : int or None
        BLAS threads during the call (restored on return); None keeps the caller's setting.

    Returns
    -------
    Augmented
    """
    from workbench.blas import limited_blas

    if effect not in EFFECTS:
        raise InputError(f"--effect: expected one of {', '.join(EFFECTS)}, got {effect!r}")
    check_model_matches(model, data)
    _, _, _, _, dt = as_matrices(model)
    if isinstance(data, TimeData) and dt > 0 and abs(dt * data.fs - 1) > 1e-9:
        raise InputError(f"model: expected dt = 1/fs = {1 / data.fs:g} s, got dt = {dt:g} s")
    with limited_blas(blas_threads):
        try:
            base = decompose(model)
        except ValueError as exc:
            raise InputError(f"model: {exc}") from None
        problem = make_problem(data)
        error_before = _spec_error(model, data)
        if effect == "nonlinearity":
            return _augment_nonlinearity(model, data, base, problem, error_before)
        structures = [s for s in candidate_structures(base, problem) if s.effect == effect]
        if not structures:
            raise InputError(
                f"--effect {effect}: does not apply to this model (e.g. suspension_stiffness "
                "needs rigid-body modes, modal_mismatch a mode in the measured band)"
            )
        best: FitResult | None = None
        for s in structures:
            _, starts = screen(s, problem, base)
            r = fit(s, problem, base, starts=starts)
            if best is None or r.cost < best.cost:
                best = r
        params, params_std = best.structure.report(best, problem, base)
        sys, delay = best.model.to_statespace()
        note = "; ".join(base.notes)
        return Augmented(
            sys, delay, effect, params, params_std, error_before, best.error, best.model, note
        )


def _augment_nonlinearity(model, data, base, problem, error_before) -> Augmented:
    """Nonlinearity: its level (unexcited lines), and Coulomb friction added to the
    simulation model (:mod:`workbench.nonlinear`) when the data are a time record of a
    square model, so the time-domain comparison can run with it."""
    from workbench.nonlinear import fit_friction

    sys, delay = base.to_statespace()
    nl = detect.nonlinearity(data, problem.predict(base)) if isinstance(data, TimeData) else None
    params: dict = {} if nl is None else {"level": nl.level, "f_stat": nl.f_stat}
    notes = []
    if nl is None:
        notes.append("the level needs a periodic time record with at least 3 periods")
    error_after, friction = error_before, None
    if isinstance(data, TimeData) and sys.ninputs == sys.noutputs:
        friction, _, error_after = fit_friction(sys, data.u, data.y, data.fs, delay_s=delay)
        params["friction_force"] = [
            float(v) for v in np.broadcast_to(friction.friction_force, (sys.ninputs,))
        ]
        params["friction_velocity"] = friction.friction_velocity
        notes.append(
            "Coulomb friction at the input ports added to the simulation model "
            "(workbench.nonlinear); the linear model file cannot hold it"
        )
    else:
        notes.append("reported only: friction is fitted on time records of square models")
    return Augmented(
        sys,
        delay,
        "nonlinearity",
        params,
        {},
        error_before,
        error_after,
        base,
        "; ".join(notes),
        friction,
    )
