"""The terminal dashboard, a client of the daemon's control API."""
