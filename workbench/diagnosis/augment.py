"""Add one named physical effect to a model, fit it to the data, return the augmented model.

The same engine as :func:`workbench.diagnosis.diagnose`, restricted to one
effect: every structure of that effect is screened and fitted (for
``modal_mismatch`` each mode of the model in the band, for ``crosstalk`` both
the output and the input side) and the best is kept.

The model's delay travels with it: an :class:`~workbench.core.model.LTIModel` in
(its ``delay_s`` is the delay the model already has), an ``LTIModel`` out, the
delay exact, exp(-s delay_s); for tools that need states it is realized as Pade
states on request (:meth:`~workbench.core.model.LTIModel.to_statespace`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.core.errors import InputError
from workbench.core.jsonutil import jsonable
from workbench.core.model import LTIModel, as_model, pade_delay, pade_order, with_pade
from workbench.diagnosis import LINEAR_EFFECTS, detect
from workbench.diagnosis.diagnose import (
    _bic,
    _spec_error,
    base_model,
    compare_start_error,
    model_notes,
)
from workbench.diagnosis.effects import candidate_structures, refinements
from workbench.diagnosis.fit import FitResult, fit, fit_budget, screen
from workbench.diagnosis.nonlinear import PortNonlinearity
from workbench.diagnosis.problem import make_problem
from workbench.io.formats import FrfData, TimeData, check_model_matches
from workbench.modal.model import ModalModel

# pade_delay, pade_order, with_pade live in workbench.core.model; kept importable here
__all__ = ["EFFECTS", "Augmented", "augment", "pade_delay", "pade_order", "with_pade"]

#: what ``augment`` can add: every effect of the vocabulary but 'none'
EFFECTS = LINEAR_EFFECTS + ("nonlinearity",)


@dataclass(frozen=True)
class Augmented:
    """A model with one effect added and fitted.

    Attributes
    ----------
    model : LTIModel
        Continuous linear part with the effect, its input delay (exact,
        exp(-s delay_s)) in ``model.delay_s``.
    effect : str
    parameters, parameters_std : dict
        Fitted physical parameters and standard deviations.
    error_before, error_after : float
        The spec error measure before and after.
    extended : ModalModel or None
        The modal representation (the diagnosis's form,
        :func:`workbench.diagnosis.modal.decompose`, with the effect).
    """

    model: LTIModel
    effect: str
    parameters: dict
    parameters_std: dict
    error_before: float
    error_after: float
    extended: ModalModel | None = field(default=None, repr=False)
    note: str = ""
    nonlinear: PortNonlinearity | None = field(default=None, repr=False)

    @property
    def delay_s(self) -> float:
        """The augmented model's input delay, s (``model.delay_s``)."""
        return self.model.delay_s

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


def augment(
    model, data: FrfData | TimeData, effect: str, *, blas_threads: int | None = 1
) -> Augmented:
    """Add ``effect`` to ``model``, fit its parameters to ``data``.

    Parameters
    ----------
    model : LTIModel, control.StateSpace or model file path
        Continuous or discrete (dt = 1/fs for time data) model; an LTIModel's
        delay is the delay the model already has and is kept (refitted by
        ``time_delay``).
    data : FrfData or TimeData
    effect : str
        One of :data:`EFFECTS`.
    blas_threads : int or None
        BLAS threads during the call (restored on return); None keeps the caller's setting.

    Returns
    -------
    Augmented
    """
    from workbench.core.blas import limited_blas

    if effect not in EFFECTS:
        raise InputError(f"--effect: expected one of {', '.join(EFFECTS)}, got {effect!r}")
    lti_model = as_model(model)
    check_model_matches(lti_model, data)
    delay0 = lti_model.delay_s
    model = lti_model.without_delay().to_statespace()
    with limited_blas(blas_threads):
        base = base_model(model, data, delay0)
        problem = make_problem(data)
        error_before = _spec_error(model, data, delay0)
        if effect == "nonlinearity":
            return _augment_nonlinearity(model, data, base, problem, error_before)
        start_note = ""
        given = None
        if getattr(problem, "transient", False):
            # error before and after on the same footing: both from the start compare
            # estimates (diagnose's measure too, :func:`compare_start_error`)
            given = compare_start_error(model, data, delay0)
            start_note = (
                "the record does not start at rest: errors are from the estimated start as "
                "compare computes it (one initial state for all outputs); "
                f"from rest {error_before:.4g}"
            )
            if given is None:  # compare cannot estimate it: the fit's own start
                given = problem.error(base)
                start_note = (
                    "the record does not start at rest: errors are from the start fitted per "
                    f"output (compare cannot estimate one); from rest {error_before:.4g}"
                )
            error_before = given
        structures = [s for s in candidate_structures(base, problem) if s.effect == effect]
        if not structures:
            raise InputError(
                f"--effect {effect}: does not apply to this model (e.g. suspension_stiffness "
                "needs rigid-body modes, modal_mismatch a mode in the measured band)"
            )
        results: list[FitResult] = []
        for s in structures:
            _, starts = screen(s, problem, base)
            results.append(fit(s, problem, base, starts=starts))
        for r in list(results):  # a shared modal pattern refined mode by mode
            for s, start in refinements(r, base, problem):
                results.append(
                    fit(s, problem, base, starts=[start], n_starts=1, max_nfev=fit_budget(s))
                )
        # the structures differ in their number of parameters: rank as diagnose does (BIC)
        best = min(results, key=lambda r: _bic(r.cost, problem.n_obs, r.n_params))
        params, params_std = best.structure.report(best, problem, base)
        note = "; ".join([*model_notes(model), *([start_note] if start_note else [])])
        return Augmented(
            _lti(best.model),
            effect,
            params,
            params_std,
            error_before,
            best.error if given is None else _after(best.model, data, best.error),
            best.model,
            note,
        )


def _after(model: ModalModel, data, error: float) -> float:
    """The augmented model's error from compare's estimated start (its fit's own where that
    cannot be estimated)."""
    after = compare_start_error(model, data)
    return error if after is None else after


def _lti(model: ModalModel) -> LTIModel:
    """The modal model's balanced realization (states (w q, dq/dt) per mode) with its delay."""
    return model.to_lti(form="scaled")


def _augment_nonlinearity(model, data, base, problem, error_before) -> Augmented:
    """Nonlinearity: its level (unexcited lines), and Coulomb friction added to the
    simulation model (:mod:`workbench.diagnosis.nonlinear`) when the data are a time record of a
    square model, so the time-domain comparison can run with it."""
    from workbench.diagnosis.nonlinear import fit_friction

    lti_model = _lti(base)
    sys = lti_model.without_delay().to_statespace()
    nl = detect.nonlinearity(data, problem.predict(base)) if isinstance(data, TimeData) else None
    params: dict = {} if nl is None else {"level": nl.level, "f_stat": nl.f_stat}
    notes = []
    if nl is None:
        notes.append("the level needs a periodic time record with at least 3 periods")
    error_after, friction = error_before, None
    if isinstance(data, TimeData) and sys.ninputs == sys.noutputs:
        friction, _, error_after = fit_friction(lti_model, data.u, data.y, data.fs)
        params["friction_force"] = [
            float(v) for v in np.broadcast_to(friction.friction_force, (sys.ninputs,))
        ]
        params["friction_velocity"] = friction.friction_velocity
        notes.append(
            "Coulomb friction at the input ports added to the simulation model "
            "(workbench.diagnosis.nonlinear); the linear model file cannot hold it"
        )
    else:
        notes.append("reported only: friction is fitted on time records of square models")
    return Augmented(
        lti_model,
        "nonlinearity",
        params,
        {},
        error_before,
        error_after,
        base,
        "; ".join(notes),
        friction,
    )
