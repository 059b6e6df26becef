"""The farm queue on a cluster that wants a password and TLS: `[farm] user`, `password`, `tls`,
`ca_file`, as for MQTT."""

from __future__ import annotations

import json
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.brokers import HOST, free_port, make_self_signed, nats_binary
from support.daemon_process import DaemonProcess
from support.paths import DATA, HOSTD, ROOT

USER, PASSWORD = "farm", "pw-35"


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[list[str], Path]]:
    """Three nats-server nodes requiring a user and TLS; yields their URLs and the CA file."""
    binary = nats_binary()
    if binary is None:
        pytest.skip("nats-server is not installed (apt-get install nats-server; make test does)")
    folder = tmp_path_factory.mktemp("secure")
    tls = make_self_signed(folder)
    ports = [(free_port(), free_port()) for _ in range(3)]
    processes = []
    for index, (client, route) in enumerate(ports):
        routes = ", ".join(f'"nats-route://{HOST}:{r}"' for _c, r in ports if r != route)
        conf = folder / f"s{index}.conf"
        conf.write_text(
            f"server_name: s{index}\nlisten: {HOST}:{client}\n"
            f'jetstream {{ store_dir: "{folder / f"s{index}-js"}" }}\n'
            f'authorization {{ user: "{USER}", password: "{PASSWORD}" }}\n'
            f'tls {{ cert_file: "{tls.cert}", key_file: "{tls.key}" }}\n'
            f"cluster {{\n  name: secure\n  listen: {HOST}:{route}\n  routes: [{routes}]\n}}\n")
        log = open(folder / f"s{index}.log", "ab")  # noqa: SIM115 - kept by the child
        processes.append(subprocess.Popen([binary, "-c", str(conf)], stdout=log, stderr=log))
        log.close()
    try:
        for client, _route in ports:
            deadline = time.monotonic() + 20
            while True:
                try:
                    with socket.create_connection((HOST, client), timeout=0.5):
                        break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.1)
        yield [f"tls://{HOST}:{client}" for client, _route in ports], tls.cert
    finally:
        for process in processes:
            process.terminate()
        for process in processes:
            process.wait(15)


def test_credentials_and_tls_are_used_and_required(secure: tuple[list[str], Path],
                                                   tmp_path: Path) -> None:
    urls, ca = secure
    base = ["farm", "--servers", ",".join(urls), "--tls", "--cafile", str(ca)]
    wrong = subprocess.run([*HOSTD, *base, "--user", USER, "--password", "nope", "list"],
                           capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert wrong.returncode == 1
    assert "cannot reach the farm's servers" in wrong.stderr
    servers = ", ".join(f'"{url}"' for url in urls)
    daemon = DaemonProcess(tmp_path, (
        "[jobs]\nsettle_s = 0.2\n[simulator]\ntime_scale = 0\nbaud = 0\n"
        '[printer]\nid = "sec1"\n'
        f'[farm]\nenabled = true\nservers = [{servers}]\nuser = "{USER}"\n'
        f'password = "{PASSWORD}"\ntls = true\nca_file = "{ca}"\n'))
    try:
        daemon.start()
        daemon.wait_for(lambda: "farm: connected" in daemon.run_log(), 60, "the farm link")
        submitted = subprocess.run(
            [*HOSTD, *base, "--user", USER, "submit", str(DATA / "cube20_xyz.stl"), "--json"],
            capture_output=True, text=True, timeout=120, cwd=ROOT,
            env={"HOSTD_FARM_PASSWORD": PASSWORD, "PATH": "/usr/bin:/bin"})
        assert submitted.returncode == 0, submitted.stderr
        [job] = json.loads(submitted.stdout)
        daemon.wait_for(lambda: (daemon.jobs / "done" / f"{job}.gcode").exists(), 90,
                        "the job printed over TLS")
    finally:
        daemon.close()


def test_a_server_that_cannot_hold_three_replicas_is_reported_at_once(tmp_path: Path) -> None:
    binary = nats_binary()
    if binary is None:
        pytest.skip("nats-server is not installed (apt-get install nats-server; make test does)")
    port = free_port()
    log = open(tmp_path / "single.log", "ab")  # noqa: SIM115 - kept by the child
    server = subprocess.Popen([binary, "-js", "-a", HOST, "-p", str(port), "-sd",
                               str(tmp_path / "js")], stdout=log, stderr=log)
    log.close()
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                with socket.create_connection((HOST, port), timeout=0.5):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        started = time.monotonic()
        result = subprocess.run([*HOSTD, "farm", "--servers", f"nats://{HOST}:{port}", "list"],
                                capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert result.returncode == 1
        assert "(3 replicas each) cannot be set up" in result.stderr
        assert "not supported in non-clustered mode" in result.stderr
        assert time.monotonic() - started < 30  # reported, not retried for a minute
    finally:
        server.terminate()
        server.wait(15)
