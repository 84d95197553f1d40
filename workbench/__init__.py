"""motion-workbench: identification, modal models, model-vs-measurement diagnosis and
controller design for rigid-flexible precision motion systems.

``import workbench as wb`` gives the main entry points; they are imported on first use, so
that ``import workbench`` (and the command line's start) stays fast.

Data flow, and the package that owns each concept::

    plants/ (true machines) --experiments, sim--> time record (io: spec 1a)
    time record --signals (periodic record, FRF)--> FRF (io: spec 1b)
    time record --ident (subspace, refine)--> LTIModel (core) --modal--> ModalModel, minimality
    model + measurement --validate (compare)--> where it fails --diagnosis--> findings, augment
    model --controllers/ (designs) + loop (analysis) + sim (closed loop)--> evaluation

    core        LTIModel, as_model, lti (FRF), d2c, errors, atomic files, BLAS threads
    io          spec files (measurements, models, findings), scenario files
    signals     excitation, PeriodicRecord, FRF estimation, data quality
    sim         the one simulator: ZOH with exact delays, nonlinear ports, closed loop
    ident       subspace identification, validation fit, ML refinement
    modal       ModalModel (the one modal model), minimality
    fe          FE models (spec 4): eigen-solve, updating, prediction at any sensor, reduction
    validate    compare a model with a measurement
    diagnosis   which physical effect is missing; augment the model with it
    loop        L, S, T, crossovers and margins of a plant with a controller
    scan        4th-order scan setpoints, MA / MSD tracking figures
    testing     pytest assertions: stable, margins, bandwidth, tracking
    cli         the command line, its commands and the scenario pipeline
"""

from __future__ import annotations

import importlib
from importlib import metadata

try:
    __version__ = metadata.version("motion-workbench")
except metadata.PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

#: public name -> module that defines it
_EXPORTS = {
    "InputError": "workbench.core.errors",
    "DataWarning": "workbench.core.errors",
    "LTIModel": "workbench.core.model",
    "as_model": "workbench.core.model",
    "TimeData": "workbench.io.formats",
    "FrfData": "workbench.io.formats",
    "load_measurement": "workbench.io.formats",
    "save_measurement": "workbench.io.formats",
    "load_model": "workbench.io.formats",
    "save_model": "workbench.io.formats",
    "PeriodicRecord": "workbench.signals.periodic",
    "periodic_record": "workbench.signals.periodic",
    "simulate_zoh": "workbench.sim",
    "closed_loop": "workbench.sim",
    "analyze_loop": "workbench.loop",
    "frf_multisine": "workbench.signals.frf",
    "frf_h1": "workbench.signals.frf",
    "estimate_frf": "workbench.signals.frf",
    "identify_subspace": "workbench.ident",
    "refine_modal_model": "workbench.ident",
    "modal_crb": "workbench.ident",
    "d2c": "workbench.core.d2c",
    "ModalModel": "workbench.modal.model",
    "check_minimality": "workbench.modal.minimality",
    "compare": "workbench.validate.compare",
    "diagnose": "workbench.diagnosis",
    "augment": "workbench.diagnosis.augment",
    "load_scenario": "workbench.io.scenario",
    "run_scenario": "workbench.cli.pipeline",
    "ScanLimits": "workbench.scan",
    "point_to_point": "workbench.scan",
    "tracking_figures": "workbench.scan",
    "testing": "workbench.testing",  # the module: wb.testing.assert_stable(...)
    "read_fe": "workbench.fe.model",
    "update_fe": "workbench.fe.update",
    "predict_frf": "workbench.fe.predict",
    "reduce_fe": "workbench.fe.reduce",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'workbench' has no attribute {name!r}")
    mod = importlib.import_module(module)
    value = mod if mod.__name__ == f"{__name__}.{name}" else getattr(mod, name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(__all__)
