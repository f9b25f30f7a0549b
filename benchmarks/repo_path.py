"""Puts the repository root on `sys.path`, so a script run from benchmarks/ can import this
repository's studies as `benchmarks.studies` (they are not in the wheel). A script imports it
first: `import repo_path  # noqa: F401`."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.append(str(ROOT))
