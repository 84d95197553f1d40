"""FE model updating (seed 001, section 6): the spec-4 FE file, eigen-solve, updating,
prediction at any sensor, modal reduction."""

from .eigen import Modes, solve_modes
from .model import FEModel, fe_arrays, fe_from_arrays, read_fe, save_fe
from .predict import ModalTerms, PredictionError, modal_terms, predict_frf, prediction_error
from .reduce import reduce_fe
from .update import (
    MeasuredModes,
    UpdateResult,
    eigen_sensitivities,
    fe_residues,
    mac_matrix,
    pair_aliases,
    pair_modes,
    update_fe,
)

__all__ = [
    "FEModel",
    "MeasuredModes",
    "ModalTerms",
    "PredictionError",
    "Modes",
    "UpdateResult",
    "eigen_sensitivities",
    "fe_arrays",
    "fe_from_arrays",
    "fe_residues",
    "mac_matrix",
    "modal_terms",
    "pair_aliases",
    "pair_modes",
    "predict_frf",
    "prediction_error",
    "read_fe",
    "reduce_fe",
    "save_fe",
    "solve_modes",
    "update_fe",
]
