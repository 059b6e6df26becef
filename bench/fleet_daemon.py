"""`hostd run` with a CPU-time sampler: the share of the daemon's CPU spent in MQTT code.

``python -m bench.fleet_daemon OUT -- run --config FILE`` runs the daemon in this
process. Every 2 ms of the process' CPU time (``ITIMER_PROF``) the main thread's
stack is sampled; a sample counts as MQTT when any of its frames is in the
bridge (``hostd/publishing/mqtt.py``), aiomqtt or paho. On SIGUSR1 one JSON line is
appended to OUT: samples so far, MQTT samples, and the process' CPU seconds.
The MQTT estimate errs high: a sample taken while another thread used the CPU
still counts when the main thread was at that moment inside MQTT code.
"""

from __future__ import annotations

import json
import resource
import signal
import sys
import time
from pathlib import Path
from types import FrameType

INTERVAL_S = 0.002
MQTT_CODE = ("/hostd/publishing/mqtt.py", "/aiomqtt/", "/paho/")


class Sampler:
    """Counts SIGPROF samples, and those whose main-thread stack is in MQTT code."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.samples = 0
        self.mqtt = 0

    def sample(self, _signum: int, frame: FrameType | None) -> None:
        self.samples += 1
        while frame is not None:
            name = frame.f_code.co_filename
            if any(part in name for part in MQTT_CODE):
                self.mqtt += 1
                return
            frame = frame.f_back

    def report(self, _signum: int, _frame: FrameType | None) -> None:
        usage = resource.getrusage(resource.RUSAGE_SELF)
        line = {"t": time.monotonic(), "samples": self.samples, "mqtt": self.mqtt,
                "cpu_s": usage.ru_utime + usage.ru_stime, "interval_s": INTERVAL_S}
        with self.out.open("a") as handle:
            handle.write(json.dumps(line) + "\n")


def main() -> int:
    """Install the sampler and run ``hostd`` with the arguments after ``--``."""
    out = Path(sys.argv[1])
    argv = sys.argv[sys.argv.index("--") + 1:]
    sampler = Sampler(out)
    signal.signal(signal.SIGPROF, sampler.sample)
    signal.signal(signal.SIGUSR1, sampler.report)
    signal.setitimer(signal.ITIMER_PROF, INTERVAL_S, INTERVAL_S)
    from hostd.app.cli import main as hostd_main

    try:
        return hostd_main(argv)
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0, 0)


if __name__ == "__main__":
    raise SystemExit(main())
