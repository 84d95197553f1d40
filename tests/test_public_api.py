"""``import workbench as wb``: every public name resolves, the version is the installed one."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys

import pytest

import workbench as wb


def test_every_public_name_resolves():
    for name in wb.__all__:
        assert getattr(wb, name) is not None, name
    with pytest.raises(AttributeError):
        wb.no_such_entry_point  # noqa: B018


def test_version_is_the_installed_distribution():
    assert wb.__version__ == importlib.metadata.version("motion-workbench")


def test_import_is_lazy():
    # importing the package must not pull in the heavy libraries (CLI start, user sessions)
    code = "import sys, workbench; print('control' in sys.modules, 'matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_every_scenario_stage_has_a_function_without_import_side_effects():
    from workbench.cli.pipeline import stage_functions
    from workbench.io.scenario import STAGES

    assert set(stage_functions()) == set(STAGES)
    assert all(callable(f) for f in stage_functions().values())
