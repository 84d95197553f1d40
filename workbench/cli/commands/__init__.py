"""The CLI commands, one module each (``register(subparsers)``, ``run(args)``).

The arguments that several commands share are declared once here, so that
their names, metavars and help read the same in every command.
"""

from __future__ import annotations

import argparse

__all__ = [
    "add_model_and_data",
    "add_modal_model_arguments",
    "add_report_outputs",
    "load_checked",
    "check_model_quality",
]


def add_model_and_data(p: argparse.ArgumentParser) -> None:
    """``--model MODEL`` and ``--data DATA``, both required (a model against a measurement)."""
    p.add_argument("--model", required=True, metavar="MODEL", help="model .npz (A, B, C, D, dt)")
    p.add_argument("--data", required=True, metavar="DATA", help="measurement .npz")


def add_report_outputs(p: argparse.ArgumentParser, *, json_help: str) -> None:
    """``--json OUT`` (what it holds: ``json_help``) and ``--plots DIR`` (PNG figures)."""
    p.add_argument("--json", metavar="OUT", help=json_help)
    p.add_argument("--plots", metavar="DIR", help="write PNG figures into DIR")


def add_modal_model_arguments(p: argparse.ArgumentParser, *, json_help: str) -> None:
    """``MODEL`` (a model file to bring to modal form), ``--json``, ``--rigid-threshold-hz``."""
    p.add_argument("model", metavar="MODEL", help="model .npz (continuous or discrete)")
    p.add_argument("--json", action="store_true", help=json_help)
    p.add_argument("--rigid-threshold-hz", type=float, default=5.0, help="rigid-body threshold, Hz")


def load_checked(path, *, method: str | None = None, model=None, model_src: str | None = None):
    """Read a measurement and run the data-quality checks on it: one place for every command.

    The warnings of :func:`workbench.signals.quality.check_measurement` (one
    line each on stderr) come after the file and, when ``model`` is given, the
    model/data channel counts are accepted, so a refusal is never preceded by
    warnings. ``method``: the estimator ``identify`` runs (an open-loop method
    on closed-loop data is warned about).
    """
    from workbench.io.formats import check_model_matches, load_measurement
    from workbench.signals.quality import check_measurement

    data = load_measurement(path)
    if model is not None:
        check_model_matches(model, data, model_src=model_src or "model", data_src=str(path))
    check_measurement(data, src=str(path), method=method)
    return data


def check_model_quality(model, src) -> None:
    """Warn (one line) when a model has unstable poles other than rigid-body poles at 0."""
    from workbench.signals.quality import check_model

    check_model(model, src=str(src))
