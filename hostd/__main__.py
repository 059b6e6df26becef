"""`python -m hostd`: the same as the `hostd` console script."""

from hostd.cli import entry

entry()
