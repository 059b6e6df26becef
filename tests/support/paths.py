"""Where things are: the repository, the tests' data folder, the `hostd` command."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
# the `hostd` console script, run by this interpreter
HOSTD = [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]
