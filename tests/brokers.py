"""A real MQTT broker for the tests: mosquitto on a free loopback port (amqtt when absent)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

HOST = "127.0.0.1"


def mosquitto_binary() -> str | None:
    """The mosquitto executable, or None."""
    found = shutil.which("mosquitto")
    if found:
        return found
    return "/usr/sbin/mosquitto" if os.access("/usr/sbin/mosquitto", os.X_OK) else None


def amqtt_binary() -> str | None:
    """The amqtt broker executable beside this interpreter (or on PATH), or None."""
    beside = Path(sys.executable).with_name("amqtt")
    if beside.exists():
        return str(beside)
    return shutil.which("amqtt")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((HOST, 0))
        return int(sock.getsockname()[1])


@dataclass(frozen=True)
class TlsFiles:
    """A self-signed server certificate for 127.0.0.1 (also its own CA)."""

    cert: Path
    key: Path


def make_self_signed(folder: Path) -> TlsFiles:
    """Create a self-signed certificate for 127.0.0.1 with the ``openssl`` command."""
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("openssl is not installed: cannot make a test certificate")
    cert, key = folder / "broker.crt", folder / "broker.key"
    subprocess.run(
        [openssl, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
         "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
         "-keyout", str(key), "-out", str(cert)],
        check=True, capture_output=True, timeout=60,
    )
    return TlsFiles(cert, key)


@dataclass
class Broker:
    """A broker process the test owns; ``stop()`` and ``start()`` keep the same port."""

    folder: Path
    port: int
    users: dict[str, str] = field(default_factory=dict)
    tls: TlsFiles | None = None
    kind: str = "mosquitto"
    process: subprocess.Popen[bytes] | None = None

    @property
    def log_file(self) -> Path:
        return self.folder / f"{self.kind}.log"

    def start(self) -> None:
        """Start the broker and wait until its port accepts connections."""
        command = self._mosquitto_command() if self.kind == "mosquitto" else self._amqtt_command()
        log = self.log_file.open("ab")
        self.process = subprocess.Popen(command, stdout=log, stderr=log, cwd=self.folder)
        log.close()
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"{self.kind} exited: {self.log_file.read_text()[-2000:]}")
            try:
                with socket.create_connection((HOST, self.port), timeout=0.5):
                    return
            except OSError:
                time.sleep(0.05)
        self.stop()
        raise RuntimeError(f"{self.kind} did not listen on {self.port}")

    def stop(self) -> None:
        """Stop the broker by its PID and wait for it."""
        if self.process is None or self.process.poll() is not None:
            return
        self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=10)

    def _mosquitto_command(self) -> list[str]:
        binary = mosquitto_binary()
        assert binary is not None
        lines = [f"listener {self.port} {HOST}", "persistence false", "log_type all"]
        if os.geteuid() == 0:
            lines.append("user root")  # otherwise it drops to `mosquitto` before reading files
        if self.users:
            passwords = self.folder / "passwords"
            passwords.unlink(missing_ok=True)
            for name, secret in self.users.items():
                flags = ["-b"] if passwords.exists() else ["-c", "-b"]
                subprocess.run(
                    ["mosquitto_passwd", *flags, str(passwords), name, secret],
                    check=True, capture_output=True, timeout=30,
                )
            lines += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            lines.append("allow_anonymous true")
        if self.tls is not None:
            lines += [f"certfile {self.tls.cert}", f"keyfile {self.tls.key}"]
        conf = self.folder / "mosquitto.conf"
        conf.write_text("\n".join(lines) + "\n")
        return [binary, "-c", str(conf)]

    def _amqtt_command(self) -> list[str]:
        binary = amqtt_binary()
        assert binary is not None
        conf = self.folder / "amqtt.yaml"
        conf.write_text(
            "listeners:\n"
            "  default:\n"
            "    type: tcp\n"
            f"    bind: {HOST}:{self.port}\n"
            "auth:\n"
            "  allow-anonymous: true\n"
            "topic-check:\n"
            "  enabled: false\n"
        )
        return [binary, "-c", str(conf)]


def start_broker(
    folder: Path, users: dict[str, str] | None = None, tls: TlsFiles | None = None
) -> Broker:
    """Start a real broker in ``folder`` (mosquitto; amqtt when mosquitto is missing).

    With ``users`` the broker refuses anonymous clients. ``HOSTD_TEST_BROKER=amqtt``
    in the environment picks amqtt even when mosquitto is there. amqtt is only a
    fallback for plain anonymous tests: a test needing passwords or TLS is
    skipped under it.
    """
    folder.mkdir(parents=True, exist_ok=True)
    wanted = os.environ.get("HOSTD_TEST_BROKER", "")  # "amqtt" tries the fallback on purpose
    if wanted != "amqtt" and mosquitto_binary() is not None:
        kind = "mosquitto"
    elif amqtt_binary() is not None:
        if users or tls:
            pytest.skip("only amqtt is available: broker passwords and TLS need mosquitto")
        kind = "amqtt"
    else:
        pytest.skip("no MQTT broker: install mosquitto (or pip install amqtt)")
    broker = Broker(folder, free_port(), dict(users or {}), tls, kind)
    broker.start()
    return broker
