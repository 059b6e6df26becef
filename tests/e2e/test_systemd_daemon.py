"""`hostd run` under a stand-in service manager: READY, STATUS, WATCHDOG, STOPPING over a socket."""

from __future__ import annotations

import json
import os
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
HOSTD = ["-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]


def write_config(folder: Path) -> Path:
    config = folder / "hostd.toml"
    config.write_text(
        "[jobs]\nfolder = \"jobs\"\nsettle_s = 0.2\n"
        "[state]\nfolder = \"var\"\n"
        "[simulator]\ntime_scale = 0\nbaud = 0\n"
    )
    return config


class Manager:
    """The notify socket a service manager listens on, and what arrived on it."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.path = path
        self.messages: list[str] = []

    def wait_for(self, test: str, timeout: float = 30.0) -> str:
        """The first message (so far or arriving) that starts with ``test``."""
        deadline = time.monotonic() + timeout
        while True:
            for message in self.messages:
                if message.startswith(test):
                    return message
            left = deadline - time.monotonic()
            assert left > 0, f"no {test!r} in {self.messages}"
            self.sock.settimeout(left)
            self.messages.extend(self.sock.recv(65536).decode().split("\n"))


def test_the_daemon_speaks_the_notify_protocol(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    manager = Manager(tmp_path / "notify")
    env = {**os.environ, "PYTHONPATH": str(REPO), "NOTIFY_SOCKET": str(manager.path),
           "WATCHDOG_USEC": "1000000"}
    daemon = subprocess.Popen(
        [sys.executable, *HOSTD, "run", "--config", str(config)],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        manager.wait_for("READY=1")
        sock = tmp_path / "var" / "hostd.sock"
        assert stat.S_IMODE(sock.lstat().st_mode) == 0o600
        manager.wait_for("WATCHDOG=1")
        manager.wait_for("STATUS=idle", timeout=20)
        status = subprocess.run(
            [sys.executable, *HOSTD, "status", "--json", "--socket", str(sock)],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=30,
        )
        assert status.returncode == 0, status.stderr
        assert json.loads(status.stdout)["printer"]["connected"] is True
        pings = manager.messages.count("WATCHDOG=1")
        manager.messages.clear()
        manager.wait_for("WATCHDOG=1")  # the watchdog keeps going
        assert pings >= 1
        daemon.send_signal(signal.SIGTERM)
        manager.wait_for("STOPPING=1")
        output, _ = daemon.communicate(timeout=30)
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()
        manager.sock.close()
    assert daemon.returncode == 0, output
    assert not sock.exists(), "the control socket is removed on a clean stop"
