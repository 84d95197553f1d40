"""System identification from time records: subspace methods and their order choice.

Data flow::

    TimeData (u, y, r, fs)
        -> gram.hankel_gram        structured Gram of the block-Hankel data (O(N rows))
        -> subspace._data_factor   small LQ factor L, projected onto r for closed loop
        -> subspace._weighted_svd  N4SID / MOESP / CVA weighting, singular values
        -> order.suggest_order     order at the largest gap (user may override)
        -> A, C (shift invariance); B, D: open loop jointly with x0 by least
           squares on the simulated output (validate.least_squares_bd_x0),
           closed loop from the projected data's Toeplitz relation
        -> SubspaceResult.model    control.StateSpace, dt = 1/fs
        -> validate.simulation_fit    fit on data not used for identification, x0 by
                                      least squares; order scan by that fit
    then workbench.core.d2c -> workbench.modal.model (ModalModel)
        -> refine.refine_modal_model   maximum-likelihood refinement on periodic data,
                                       near the Cramer-Rao bound (refine.modal_crb)
        -> workbench.modal.minimality.
"""

from workbench.ident.order import (
    format_order_scan,
    format_singular_values,
    gap_verdict,
    plot_order_scan,
    plot_singular_values,
    suggest_order,
)
from workbench.ident.refine import RefineResult, modal_crb, periodic_spectra, refine_modal_model
from workbench.ident.subspace import METHODS, SubspaceResult, identify_subspace
from workbench.ident.validate import (
    Fit,
    Offsets,
    fit_percent,
    remove_offsets,
    simulation_fit,
    split_record,
)

__all__ = [
    "METHODS",
    "SubspaceResult",
    "identify_subspace",
    "suggest_order",
    "format_singular_values",
    "plot_singular_values",
    "gap_verdict",
    "format_order_scan",
    "plot_order_scan",
    "Fit",
    "Offsets",
    "fit_percent",
    "simulation_fit",
    "remove_offsets",
    "split_record",
    "refine_modal_model",
    "RefineResult",
    "modal_crb",
    "periodic_spectra",
]
