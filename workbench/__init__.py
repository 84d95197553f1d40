"""motion-workbench: identification, modal models, model-vs-measurement diagnosis and
controller design for rigid-flexible precision motion systems.

``import workbench as wb`` gives the main entry points; they are imported on first use, so
that ``import workbench`` (and the command line's start) stays fast.

Data flow (which module owns which concept)::

    measurements  wb.load_measurement / wb.save_measurement   workbench.formats (spec 1a/1b)
    periodic      wb.PeriodicRecord                           workbench.periodic
    FRF           wb.frf_multisine, wb.estimate_frf            workbench.frf_estimation
    models        wb.LTIModel, wb.load_model, wb.save_model    workbench.model, workbench.formats
    simulation    wb.simulate, wb.simulate_closed_loop          workbench.sim
    identify      wb.identify_subspace, wb.refine_modal_model   workbench.ident
    modal         wb.ModalModel, wb.check_minimality            workbench.modal, .minimality
    validate      wb.compare                                    workbench.compare
    diagnosis     wb.diagnose, wb.augment                       workbench.diagnosis, .augment
    scenarios     wb.load_scenario, wb.run_scenario             workbench.scenario, .pipeline
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
    "InputError": "workbench.errors",
    "DataWarning": "workbench.errors",
    "TimeData": "workbench.formats",
    "FrfData": "workbench.formats",
    "load_measurement": "workbench.formats",
    "save_measurement": "workbench.formats",
    "load_model": "workbench.formats",
    "save_model": "workbench.formats",
    "frf_multisine": "workbench.frf_estimation",
    "frf_h1": "workbench.frf_estimation",
    "estimate_frf": "workbench.frf_estimation",
    "identify_subspace": "workbench.ident",
    "refine_modal_model": "workbench.ident",
    "modal_crb": "workbench.ident",
    "d2c": "workbench.d2c",
    "ModalModel": "workbench.modal",
    "check_minimality": "workbench.minimality",
    "compare": "workbench.compare",
    "diagnose": "workbench.diagnosis",
    "augment": "workbench.augment",
    "load_scenario": "workbench.scenario",
    "run_scenario": "workbench.pipeline",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'workbench' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(__all__)
