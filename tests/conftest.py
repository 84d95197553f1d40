"""Test configuration.

- tests/ on sys.path, so tests and benchmarks share casegen and indepgen;
- ``SHARED_EXAMPLES``: the shared example cases, which sit in ``shared/``
  beside the checkout (``../shared/examples``).
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

SHARED_EXAMPLES = Path(__file__).resolve().parents[2] / "shared" / "examples"
if not SHARED_EXAMPLES.is_dir():  # a checkout elsewhere on this machine
    SHARED_EXAMPLES = Path("/work/shared/examples")
