"""Data shipped with hostd: the sample model and the demo configuration."""
