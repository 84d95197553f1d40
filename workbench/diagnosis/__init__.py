"""Model-versus-measurement diagnosis: which physical effect is the model missing?

Data flow::

    model (StateSpace) ──decompose──> ModalModel (modes + effect fields)          modal.py
    data (FrfData | TimeData) ──────> FrfProblem | TimeProblem (weights, linear fits) problem.py
                      │
                      ▼
    candidate structures, one per effect (effects.py) ──screen + fit (fit.py)──> FitResult
                      │
                      ▼
    rank by BIC, accept if the error falls, add it, repeat (diagnose.py)
                      │
                      ▼
    Diagnosis(error_before, findings[effect, inputs, outputs, band_hz, parameters ± std,
              error_after, explanation (explain.py, detect.py)]) ──to_json()──> spec section 3

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
