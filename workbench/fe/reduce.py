"""Modal reduction of an FE model for control: first n modes plus residual compliance.

The result is the project's one :class:`workbench.modal.model.ModalModel`
(flexible modes with mass-normalized ``b_k``, ``c_k``; rigid modes below
``rigid_threshold_hz``; the residual compliance of the dropped modes as ``D``),
so ``.to_statespace()`` gives the python-control StateSpace for design.
"""

from __future__ import annotations

from workbench.modal.model import ModalModel, Mode

from .model import FEModel
from .predict import modal_terms

__all__ = ["reduce_fe"]


def reduce_fe(
    fe: FEModel,
    n_modes: int,
    *,
    outputs=None,
    inputs=None,
    rigid_threshold_hz: float = 1e-3,
) -> ModalModel:
    """The first ``n_modes`` modes of ``fe`` and the residual compliance of the rest.

    Parameters
    ----------
    fe : FEModel
        At its own alpha and damping (the damping of the first ``n_modes`` must be given).
    n_modes : int
    outputs, inputs : sequence of str, optional
        Channel names (default all).
    rigid_threshold_hz : float
        Modes below this frequency are rigid (double integrators), Hz.
    """
    t = modal_terms(fe, outputs=outputs, inputs=inputs, n_modes=n_modes)
    modes = []
    for f, z, c, b in zip(t.freq_hz, t.damping, t.c, t.b, strict=True):
        if f < rigid_threshold_hz:
            modes.append(Mode("rigid", 0.0, 0.0, b, c))
        else:
            modes.append(Mode("flexible", f, z, b, c))
    names_out = fe.output_names if outputs is None else tuple(outputs)
    names_in = fe.input_names if inputs is None else tuple(inputs)
    return ModalModel(
        modes=tuple(modes), D=t.D, input_names=tuple(names_in), output_names=tuple(names_out)
    )
