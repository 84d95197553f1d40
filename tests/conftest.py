"""Test configuration: tests/ on sys.path so tests and benchmarks share casegen."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
