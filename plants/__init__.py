"""The true systems the workbench is tested against.

Every plant is a simulator of the machine, not of our model of it: physical
effects (delays, extra modes, actuator and sensor dynamics, suspension,
crosstalk, nonlinearities, noise, quantization) are fields of its frozen
configuration (:class:`plants.effects.Effects`). Identification and diagnosis
code never reads those fields; it sees only what an experiment records.

Data flow of every plant (:class:`plants.mechanical.MechanicalPlant`)::

    u ─► delay ─► saturation ─► actuator lag ─► input crosstalk ─► modes ─►
      output crosstalk ─► sensor lag ─► raw sensors (+ noise, quantization) ─► decoupling ─► y

    modes = rigid-body/suspension + flexible (frequency/damping errors)
            + residual (above Nyquist) + extra; friction and a cubic spring act
            at ports collocated with the inputs.

Constructors::

    plants.wafer_stage(**effects)        6-DOF stage: Fx..Tz (N, N m) -> x..Rz (m, rad), 5 kHz
    plants.beam(**effects)               beam: F1..F3 (N) -> s1..s5 (m), 2048 Hz
    plants.get_plant(name, **effects)    name in {"wafer_stage", "beam"}
    plants.beam_prior_model()            the (too stiff) prior FE model, control.StateSpace
    plants.beam_fe_model(), plants.beam_fe.assemble(model, alpha)   K(alpha), M(alpha)

Both constructors take ``config=`` (:class:`StageConfig`, :class:`BeamConfig`),
``effects=`` (a base :class:`Effects`) and any ``Effects`` field by name, e.g.
``plants.wafer_stage(delay_s=3e-4, sensor_cutoff_hz=2000.0, residual_max_hz=8e3)``.

Every plant follows :class:`plants.base.Plant`::

    plant.fs, plant.n_u, plant.n_y, plant.input_names, plant.output_names
    plant.linear_model()      -> control.StateSpace (continuous, true linear part, no delay)
    plant.delay_s             -> total input delay, s
    plant.frf(freq_hz)        -> (n_f, n_y, n_u) true linear FRF with the delay
    plant.simulate(u, rng=)   -> y (N, n_y): open loop from rest, with every effect
    plant.init(rng) -> state; plant.step(state, u_k) -> (y_k, state)   (closed loop)

and offers ``plant.nominal_model()`` (nominal modes, no effects),
``plant.with_effects(**fields)``, ``plant.modes`` (the true :class:`ModalSet`)
and ``plant.simulate_noise_free(u)``.
"""

from __future__ import annotations

from typing import Any

from workbench.core.errors import InputError

from .base import LinearPlant, Plant
from .beam import (
    BeamConfig,
    beam,
    beam_config,
    beam_fe_model,
    beam_modes,
    beam_prior_config,
    beam_prior_model,
)
from .effects import Effects, ExtraMode
from .mechanical import MechanicalPlant, MechanicalPlantState
from .modal import ModalSet
from .wafer_stage import StageConfig, frame_rotation_crosstalk, stage_config, wafer_stage

__all__ = [
    "Plant",
    "LinearPlant",
    "MechanicalPlant",
    "MechanicalPlantState",
    "Effects",
    "ExtraMode",
    "ModalSet",
    "StageConfig",
    "BeamConfig",
    "wafer_stage",
    "beam",
    "beam_fe_model",
    "beam_modes",
    "beam_prior_config",
    "beam_prior_model",
    "frame_rotation_crosstalk",
    "get_plant",
    "plant_config",
    "PLANTS",
]

PLANTS = {"wafer_stage": wafer_stage, "beam": beam}
_CONFIGS = {"wafer_stage": stage_config, "beam": beam_config}


def plant_config(name: str, **fields: Any):
    """The machine configuration of plant ``name`` with ``fields`` changed (unknown: refused).

    Examples
    --------
    >>> plant_config("beam", sensor_tilt_rad=(0.0, 0.3, 0.0, 0.0, 0.0)).sensor_tilt_rad[1]
    0.3
    """
    key = {"stage": "wafer_stage"}.get(name, name)
    if key not in _CONFIGS:
        raise InputError(f"plant: unknown name {name!r}; expected one of {sorted(PLANTS)}")
    return _CONFIGS[key](**fields)


def get_plant(name: str, **config: Any) -> MechanicalPlant:
    """A plant by registry name.

    Parameters
    ----------
    name : str
        "wafer_stage" (alias "stage") or "beam".
    **config
        ``config=`` (StageConfig/BeamConfig), ``effects=`` (Effects) and
        ``Effects`` fields by name.

    Examples
    --------
    >>> get_plant("beam").output_names
    ('s1', 's2', 's3', 's4', 's5')
    """
    key = {"stage": "wafer_stage"}.get(name, name)
    if key not in PLANTS:
        raise InputError(f"plant: unknown name {name!r}; expected one of {sorted(PLANTS)}")
    return PLANTS[key](**config)
