"""`python -m hostd`: the same as the `hostd` console script."""

from hostd.app.cli import entry

entry()
