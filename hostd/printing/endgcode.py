"""What a cancelled job ends with, wherever it is cancelled: the daemon's jobs and `hostd print`."""

from __future__ import annotations

# sent after the lines in flight when a job is cancelled: heaters and fan off, motors
# released (a sliced model's own ending is for a job that finished)
CANCEL_GCODE: tuple[str, ...] = ("M104 S0", "M140 S0", "M107", "M84")
