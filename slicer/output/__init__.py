"""G-code out: the per-layer formatting and its line budget and time, whole files written
by forked workers, object labels, thumbnails and previews.
"""
