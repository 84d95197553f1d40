"""Model-versus-measurement diagnosis: which physical effect is the model missing?

Data flow::

    model (StateSpace) ──decompose──> ExtendedModel (modal terms + effect fields)   modal.py
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
:func:`workbench.augment.augment`.
"""

from workbench.diagnosis.diagnose import Diagnosis, Finding, diagnose

__all__ = ["diagnose", "Diagnosis", "Finding"]
