"""Test configuration.

- tests/ on sys.path, so tests and benchmarks share casegen and indepgen;
- ``SHARED``: the project's shared folder, which sits beside the checkout (``../shared``):
  examples, real records, FE cases. ``SHARED_EXAMPLES`` is its ``examples`` folder.

One rule for tests that read shared files: call :func:`require_shared` first. When the folder
is absent the test is skipped on a developer's machine (a checkout elsewhere) and FAILS under CI
(``CI`` set), where shared/ always sits beside the checkout: a wrong path can never pass as a
skip there.
"""

import os
import sys
from pathlib import Path

import pytest

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
