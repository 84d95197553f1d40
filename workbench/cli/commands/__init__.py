"""The CLI commands, one module each (``register(subparsers)``, ``run(args)``).

The arguments that several commands share are declared once here, so that
their names, metavars and help read the same in every command.
"""

from __future__ import annotations

import argparse

__all__ = ["add_model_and_data", "add_modal_model_arguments", "add_report_outputs"]


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
