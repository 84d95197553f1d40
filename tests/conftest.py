"""Test configuration.

- tests/ on sys.path, so tests and benchmarks share casegen and indepgen;
- ``SHARED``: the project's shared folder, which sits beside the checkout (``../shared``):
  examples, real records, FE cases. ``SHARED_EXAMPLES`` is its ``examples`` folder.

One rule for tests that read shared files: call :func:`require_shared` first. When the folder
is absent the test is skipped on a developer's machine (a checkout elsewhere) and FAILS under CI
(``CI`` set), where shared/ always sits beside the checkout: a wrong path can never pass as a
skip there.

Under pytest-xdist (pyproject's addopts run the suite on 2 workers) each worker's BLAS runs on
one thread: two workers with a thread per core each would oversubscribe the cores (small dense
linear algebra gets slower, not faster). An explicit ``OPENBLAS_NUM_THREADS`` /
``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` in the environment is kept; a serial run (``-n 0``)
is left alone.
"""

import os
import sys
from pathlib import Path

import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")  # before numpy loads BLAS; subprocesses inherit it

sys.path.insert(0, str(Path(__file__).resolve().parent))

SHARED = Path(__file__).resolve().parents[2] / "shared"
SHARED_EXAMPLES = SHARED / "examples"
SHARED_REALDATA = SHARED / "realdata"
SHARED_FE_EXAMPLES = SHARED / "fe_examples"


def require_shared(path: Path = SHARED_EXAMPLES) -> Path:
    """``path`` (inside shared/) if it exists; otherwise skip, or fail under CI."""
    path = Path(path)
    if path.exists():
        return path
    message = f"shared file or folder not found: {path} (expected ../shared beside the checkout)"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


def one_line(err: str) -> str:
    """The single line of a CLI's bad-input message (no traceback), asserted and returned."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="session")
def beam_measured_truth():
    """The true beam's measured loops (s1, s2, s5 from F1..F3) with its own delay (0), an
    LTIModel: what the inferential scenarios' controllers are judged on again."""
    from plants.beam import beam
    from workbench.core.model import LTIModel

    p = beam()
    return LTIModel.from_statespace(p.linear_model()[[0, 1, 4], :], delay_s=p.delay_s)


def run_scenario(tmp_path_factory, scenario: Path, name: str) -> tuple[Path, dict]:
    """``workbench run`` of a scenario into a fresh folder: (the folder, its inferential.json)."""
    import json

    from workbench.cli.main import main

    out = tmp_path_factory.mktemp(name)
    status = main(["run", str(scenario), "--results", str(out), "--quiet"])
    assert status == 0
    return out, json.loads((out / "inferential.json").read_text())
