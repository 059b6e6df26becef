"""Real MQTT brokers for the tests on loopback: mosquitto (amqtt when absent), a nats cluster."""

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
    """A server certificate for 127.0.0.1: self-signed (its own CA), or signed by ``ca``.

    With ``ca`` the broker also requires each client to present a certificate signed by it.
    """

    cert: Path
    key: Path
    ca: Path | None = None


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


@dataclass(frozen=True)
class CaChain:
    """A test CA, the broker's certificate it signed, and a client certificate it signed."""

    ca: Path
    server: TlsFiles
    client_cert: Path
    client_key: Path


def make_ca_chain(folder: Path) -> CaChain:
    """A CA, a server certificate for 127.0.0.1 and a client certificate (``openssl``, EC keys)."""
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("openssl is not installed: cannot make test certificates")
    folder.mkdir(parents=True, exist_ok=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]

    def run(*args: str) -> None:
        subprocess.run([openssl, *args], check=True, capture_output=True, timeout=60)

    ca, ca_key = folder / "ca.crt", folder / "ca.key"
    run("req", "-x509", *ec, "-days", "2", "-subj", "/CN=hostd test CA",
        "-keyout", str(ca_key), "-out", str(ca))
    made: dict[str, tuple[Path, Path]] = {}
    for name, subject, extension in (
        ("server", "/CN=127.0.0.1", "subjectAltName=IP:127.0.0.1"),
        ("client", "/CN=fleet view", "extendedKeyUsage=clientAuth"),
    ):
        key, request, cert = (folder / f"{name}.{ext}" for ext in ("key", "csr", "crt"))
        run("req", *ec, "-subj", subject, "-keyout", str(key), "-out", str(request))
        ext_file = folder / f"{name}.ext"
        ext_file.write_text(extension + "\n")
        run("x509", "-req", "-in", str(request), "-CA", str(ca), "-CAkey", str(ca_key),
            "-CAcreateserial", "-days", "2", "-extfile", str(ext_file), "-out", str(cert))
        made[name] = (cert, key)
    server_cert, server_key = made["server"]
    return CaChain(ca, TlsFiles(server_cert, server_key, ca), *made["client"])


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
            if self.tls.ca is not None:
                lines += [f"cafile {self.tls.ca}", "require_certificate true"]
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


def nats_binary() -> str | None:
    """The nats-server executable (Debian's package installs /usr/sbin/nats-server), or None."""
    found = shutil.which("nats-server")
    if found:
        return found
    return "/usr/sbin/nats-server" if os.access("/usr/sbin/nats-server", os.X_OK) else None


@dataclass
class NatsNode:
    """One nats-server of a cluster: MQTT listener, JetStream, routes to the others."""

    folder: Path
    name: str
    client_port: int
    route_port: int
    mqtt_port: int
    process: subprocess.Popen[bytes] | None = None

    @property
    def log_file(self) -> Path:
        return self.folder / f"{self.name}.log"

    def configure(self, routes: list[int]) -> Path:
        """Write this node's configuration file (MQTT needs a server name and JetStream)."""
        store = self.folder / f"{self.name}-jetstream"
        conf = self.folder / f"{self.name}.conf"
        others = ", ".join(f'"nats-route://{HOST}:{port}"' for port in routes)
        conf.write_text(
            f"server_name: {self.name}\n"
            f"listen: {HOST}:{self.client_port}\n"
            f'jetstream {{ store_dir: "{store}" }}\n'
            f"cluster {{\n  name: hostd\n  listen: {HOST}:{self.route_port}\n"
            f"  routes: [{others}]\n}}\n"
            # replicas on all three nodes: a stream must keep its quorum when one node stops
            f"mqtt {{ listen: {HOST}:{self.mqtt_port}, stream_replicas: 3 }}\n"
        )
        return conf

    def start(self) -> None:
        """Start the node (it joins the cluster through its routes)."""
        binary = nats_binary()
        assert binary is not None
        log = self.log_file.open("ab")
        self.process = subprocess.Popen([binary, "-c", str(self.folder / f"{self.name}.conf")],
                                        stdout=log, stderr=log, cwd=self.folder)
        log.close()

    def stop(self) -> None:
        """Stop the node by its PID (SIGTERM: a clean shutdown) and wait for it."""
        if self.process is None or self.process.poll() is not None:
            return
        self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=10)


@dataclass
class NatsCluster:
    """Three nats-server nodes on loopback forming one JetStream cluster with MQTT."""

    nodes: list[NatsNode]

    def hosts(self) -> list[str]:
        """``host:port`` of each node's MQTT listener."""
        return [f"{HOST}:{node.mqtt_port}" for node in self.nodes]

    def stop(self) -> None:
        for node in self.nodes:
            node.stop()


def start_nats_cluster(folder: Path, size: int = 3, timeout: float = 60.0) -> NatsCluster:
    """Start a ``size``-node nats-server cluster and wait until MQTT works on every node.

    Skips the test when nats-server is not installed (``make test`` installs it).
    Ready means a retained QoS 1 message published on the first node is read back
    on every node.
    """
    if nats_binary() is None:
        pytest.skip("nats-server is not installed (apt-get install nats-server; make test does)")
    folder.mkdir(parents=True, exist_ok=True)
    nodes = [NatsNode(folder, f"n{i + 1}", free_port(), free_port(), free_port())
             for i in range(size)]
    for node in nodes:
        node.configure([other.route_port for other in nodes if other is not node])
    cluster = NatsCluster(nodes)
    for node in nodes:
        node.start()
    try:
        wait_cluster_ready(cluster, timeout)
    except BaseException:
        cluster.stop()
        raise
    return cluster


def wait_cluster_ready(cluster: NatsCluster, timeout: float) -> None:
    """Wait until a retained QoS 1 message published on the first node is read on every node."""
    import asyncio

    import aiomqtt

    async def round_trip() -> None:
        first = cluster.nodes[0].mqtt_port
        async with aiomqtt.Client(HOST, first, timeout=3) as client:
            await client.publish("hostd-test/ready", "1", qos=1, retain=True)
        for node in cluster.nodes:
            async with aiomqtt.Client(HOST, node.mqtt_port, timeout=3) as client:
                await client.subscribe("hostd-test/ready", qos=1)
                async with asyncio.timeout(5):
                    async for _message in client.messages:
                        break

    deadline = time.monotonic() + timeout
    while True:
        for node in cluster.nodes:
            if node.process is not None and node.process.poll() is not None:
                raise RuntimeError(f"nats-server {node.name} exited: "
                                   f"{node.log_file.read_text()[-2000:]}")
        try:
            asyncio.run(round_trip())
            return
        except (aiomqtt.MqttError, OSError, TimeoutError):
            if time.monotonic() > deadline:
                raise RuntimeError("the nats cluster did not become ready") from None
            time.sleep(0.5)
