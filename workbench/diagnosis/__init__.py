"""Model-versus-measurement diagnosis: which physical effect is the model missing?

Data flow::

    model (StateSpace) ──decompose──> ModalModel (modes + effect fields)          modal.py
    data (FrfData | TimeData) ──────> FrfProblem | TimeProblem (weights, linear fits) problem.py
                      │
                      ▼
    candidate structures, one per effect (effects.py) ──screen + fit (fit.py)──> FitResult
                      │
                      ▼
    rank by BIC, accept if the error falls, add it, refit the added modes jointly
    (effects.backfit / polish), repeat until compare finds the model within noise (diagnose.py)
                      │
                      ▼
    nonlinearity: a port element (friction, cubic spring, saturation) fitted and simulated
    (nonlinear.fit_port_element; ports: a square model's outputs, or the mode shapes a
    collocated sensor fixes; without ports a saturation alone, nonlinear.fit_saturation),
    a finding only when it lowers the error; tried on the model
    as given as soon as a modal mismatch or suspension (its linearization) is accepted
                      │
                      ▼
    Diagnosis(error_before, findings[effect, inputs, outputs, band_hz, parameters ± std,
              error_after, explanation (explain.py, detect.py)],
              remaining = compare's verdict on the final model) ──to_json()──> spec section 3

One physical cause is one finding: a modal_mismatch that moves every flexible mode by one
factor (a wrong Young's modulus, a damping guess) lists the ``modes`` and the ``pattern``.

Public entry points: :func:`diagnose` and, for one given effect,
:func:`workbench.diagnosis.augment.augment`.
"""

#: The effect vocabulary of the exchange spec (section 3), in its order.
VOCABULARY = (
    "time_delay",
    "missing_mode",
    "modal_mismatch",
    "residual_compliance",
    "actuator_dynamics",
    "sensor_dynamics",
    "suspension_stiffness",
    "crosstalk",
    "nonlinearity",
    "none",
)
#: The effects a linear model can take on (fitted and added by ``augment``).
LINEAR_EFFECTS = VOCABULARY[:8]

from workbench.diagnosis.diagnose import Diagnosis, Finding, diagnose  # noqa: E402

__all__ = ["diagnose", "Diagnosis", "Finding", "VOCABULARY", "LINEAR_EFFECTS"]
