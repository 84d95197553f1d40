"""Extended modal model: mass-normalized mode shapes from rank-one residues (seed 001, sec. 5).

A fitted mode has the residue ``R_k = c_k b_k^T`` (outputs x inputs); the split
of its scale between ``c_k`` and ``b_k`` is free. For a structure with mass-
normalized mode shapes ``phi_k``, ``R_k = phi_k(sensors) phi_k(actuators)^T``
(Betti-Maxwell reciprocity: the same shape drives and observes). With one
sensor ``i`` collocated with actuator ``j`` the two must agree there,
``[v_k]_i = [w_k]_j``, which fixes the split (Theorem 2)::

    v_k = beta c_k,  w_k = b_k / beta,  beta* = sqrt([b_k]_j / [c_k]_i)

Then ``v_k`` is ``phi_k`` at every sensor and ``w_k`` at every actuator: the
mode shape is known at ``n_y + n_u - 1`` points (the collocated pair counted
once), in 1/sqrt(kg) when G is in m/N.

Data flow::

    ModalModel (fitted: flexible modes c_k b_k^T)  --scale_modes(sensor, actuator)-->
    ExtendedModes (phi at sensors and actuators, the model with b_k, c_k scaled)
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from workbench.core.arrays import readonly
from workbench.core.errors import DataWarning, InputError
from workbench.modal.model import ModalModel

__all__ = ["ExtendedModes", "collocation_scale", "scale_modes"]


def collocation_scale(b: np.ndarray, c: np.ndarray, *, sensor: int, actuator: int) -> np.ndarray:
    """Theorem 2's ``beta*`` per mode: ``sqrt([b_k]_j / [c_k]_i)``.

    Parameters
    ----------
    b : (n_m, n_u) array
        Input vectors ``b_k`` (rows).
    c : (n_m, n_y) array
        Output vectors ``c_k`` (rows).
    sensor, actuator : int
        The collocated pair: output index ``i``, input index ``j``.

    Returns
    -------
    beta : (n_m,) array
        NaN for a mode whose driving-point residue ``[c_k]_i [b_k]_j`` is not
        positive (a node at the pair, or not a physical mode).
    """
    b = np.atleast_2d(np.asarray(b, float))
    c = np.atleast_2d(np.asarray(c, float))
    ratio = b[:, actuator] / np.where(c[:, sensor] != 0, c[:, sensor], np.nan)
    return np.sqrt(np.where(ratio > 0, ratio, np.nan))


@dataclass(frozen=True)
class ExtendedModes:
    """Mass-normalized mode shapes at every sensor and actuator.

    Attributes
    ----------
    model : ModalModel
        The input model with each flexible mode's ``c_k, b_k`` replaced by the
        scaled ``phi_k`` at sensors and actuators (the same response).
    freq_hz, damping : (n_m,) arrays
        Of the scaled (flexible) modes.
    phi_sensors : (n_m, n_y) array, phi_actuators : (n_m, n_u) array
        Mode shapes, 1/sqrt(kg) for G in m/N; NaN rows for modes that could
        not be scaled. Sign: positive at the collocated pair.
    sensor, actuator : str
        Names of the collocated pair.
    """

    model: ModalModel
    freq_hz: np.ndarray
    damping: np.ndarray
    phi_sensors: np.ndarray
    phi_actuators: np.ndarray
    sensor: str
    actuator: str

    def __post_init__(self):
        for key in ("freq_hz", "damping", "phi_sensors", "phi_actuators"):
            object.__setattr__(self, key, readonly(getattr(self, key), float))

    @property
    def point_names(self) -> tuple[str, ...]:
        """Names of the extended points: every sensor, then every actuator but the collocated."""
        acts = [a for a in self.model.input_names if a != self.actuator]
        return tuple(self.model.output_names) + tuple(acts)

    @property
    def shapes(self) -> np.ndarray:
        """(n_m, n_y + n_u - 1) mode shapes at :attr:`point_names`."""
        j = list(self.model.input_names).index(self.actuator)
        return np.hstack([self.phi_sensors, np.delete(self.phi_actuators, j, axis=1)])


def channel_index(names: tuple[str, ...], key: str | int, what: str) -> int:
    """Index of channel ``key`` (a name or an index) in ``names``; one-line refusal otherwise."""
    if isinstance(key, int | np.integer):
        if not 0 <= key < len(names):
            raise InputError(f"{what}: expected an index in 0..{len(names) - 1}, got {key}")
        return int(key)
    if key not in names:
        raise InputError(f"{what}: expected one of {', '.join(names)}, got {key!r}")
    return names.index(key)


def scale_modes(model: ModalModel, *, sensor: str | int, actuator: str | int) -> ExtendedModes:
    """Scale a fitted modal model's flexible modes to mass-normalized shapes (Theorem 2).

    Parameters
    ----------
    model : ModalModel
        Flexible modes with rank-one residues ``c_k b_k^T`` (e.g.
        :attr:`workbench.modal.fit.ModalFit.model`); other modes (rigid term,
        upper residual) are kept as they are.
    sensor, actuator : str or int
        The collocated sensor (output) and actuator (input), by name or index.

    Returns
    -------
    ExtendedModes

    Warns
    -----
    DataWarning
        When a mode's driving-point residue is not positive: its shape is NaN
        and its ``b_k, c_k`` stay unscaled in the model.
    """
    if not isinstance(model, ModalModel):
        raise InputError(f"scale_modes: expected a ModalModel, got {type(model).__name__}")
    i = channel_index(model.output_names, sensor, "collocated sensor")
    j = channel_index(model.input_names, actuator, "collocated actuator")
    flex = [k for k, m in enumerate(model.modes) if m.kind == "flexible" and m.is_ideal]
    if not flex:
        raise InputError("scale_modes: expected flexible modes with rank-one residues, got none")
    b = np.array([model.modes[k].b for k in flex])
    c = np.array([model.modes[k].c for k in flex])
    beta = collocation_scale(b, c, sensor=i, actuator=j)
    # the shapes' sign is free: make them positive at the collocated pair
    sign = np.sign(c[:, i])
    phi_s = (sign * beta)[:, None] * c
    phi_a = b / (sign * beta)[:, None]
    bad = ~np.isfinite(beta)
    if np.any(bad):
        at = ", ".join(f"{model.modes[flex[k]].freq_hz:.4g}" for k in np.flatnonzero(bad))
        warnings.warn(
            "scale_modes: driving-point residue not positive (node at the collocated pair?) "
            f"for modes at {at} Hz; "
            "their shapes are NaN",
            DataWarning,
            stacklevel=2,
        )
    modes = list(model.modes)
    for n, k in enumerate(flex):
        if not bad[n]:
            modes[k] = replace(modes[k], b=phi_a[n], c=phi_s[n])
    return ExtendedModes(
        model=replace(model, modes=tuple(modes)),
        freq_hz=np.array([model.modes[k].freq_hz for k in flex]),
        damping=np.array([model.modes[k].damping for k in flex]),
        phi_sensors=phi_s,
        phi_actuators=phi_a,
        sensor=model.output_names[i],
        actuator=model.input_names[j],
    )
