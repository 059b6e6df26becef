"""The hostd daemon: job folder, job store, just-in-time runner, status, MQTT and control API."""

__version__ = "0.1.0"
