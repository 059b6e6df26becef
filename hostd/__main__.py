"""`python -m hostd`: the same as the `hostd` console script."""

import sys

from hostd.cli import main

sys.exit(main())
