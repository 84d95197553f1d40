"""The model as the diagnosis starts from it: the one modal model, rigid modes merged.

Every linear effect of the vocabulary is a change to one field of the
:class:`workbench.modal.model.ModalModel` (no second model type)::

    G(s) = T_out Hy(s) [ D + sum_k (N1_k s + N0_k) / d_k(s) ] Hu(s) T_in exp(-s delay_s)

where ``d_k`` is ``s^2 + 2 z w s + w^2`` for a flexible mode (``s^2`` for the
rigid-body modes, merged into one mode by
:meth:`~workbench.modal.model.ModalModel.with_rigid_merged`), ``s + a0`` for a
real pole; ``Hu``, ``Hy`` the actuator and sensor lags ``tau_in``,
``tau_out``; ``T_in``, ``T_out`` static coupling (crosstalk). A missing mode
appends a mode (``effect="missing_mode"``), a modal mismatch moves one
(:meth:`~workbench.modal.model.Mode.moved`), a suspension moves the rigid
mode (``effect="suspension_stiffness"``), residual compliance adds to ``D``.
Frequency response: ``ModalModel.frf`` / ``core_frf`` / ``channel_factor``;
exact ZOH simulation: :mod:`workbench.modal.simulate`; state space:
``ModalModel.to_lti``.
"""

from __future__ import annotations

from workbench.modal.model import ModalModel

__all__ = ["decompose"]


def decompose(sys) -> ModalModel:
    """A state-space model as the sum of its modes, the form the diagnosis edits.

    Parameters
    ----------
    sys : control.StateSpace or workbench.core.model.LTIModel
        Continuous, or discrete (converted by the exact ZOH inverse,
        :func:`workbench.core.d2c.d2c`, which refuses poles at z = 0 and on the
        negative real axis with an InputError). An LTIModel's delay is kept.

    Returns
    -------
    ModalModel
        ``ModalModel.from_statespace(sys, exact=True).with_rigid_merged()``:
        lossless (same FRF), the rigid-body modes at s = 0 as one mode over
        ``s^2`` with their summed numerator ``N1 s + N0``, every pole pair and
        real pole with its exact numerator, then by frequency; D. Raises
        InputError when A has Jordan chains other than rigid-body double
        integrators (not representable).
    """
    return ModalModel.from_statespace(sys, exact=True).with_rigid_merged()
