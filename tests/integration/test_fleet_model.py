"""The fleet table's data (order, filter, counts, cells), broker lists and the lean MQTT client."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from support.brokers import HOST, start_broker

from bench.fleetpub import snapshot
from hostd.api import Snapshot
from hostd.app.cli import main
from tui.fleet_model import FleetModel, progress_bar, row_cells
from tui.mqtt_wire import WireClient, WireError
from tui.sources import parse_brokers


def model() -> FleetModel:
    fleet = FleetModel()
    for name, state in [("b-idle", "idle"), ("a-print", "printing"), ("c-err", "error"),
                        ("d-pause", "paused"), ("e-lost", "printing"), ("f-heat", "heating")]:
        fleet.put_status(name, snapshot(len(name), 1000.0, state, 900.0))
    fleet.put_online("e-lost", False)
    return fleet


def test_problems_come_first_and_a_last_will_overrides_the_last_status() -> None:
    fleet = model()
    assert fleet.ordered() == ["c-err", "e-lost", "d-pause", "a-print", "f-heat", "b-idle"]
    assert fleet.counts() == {"error": 1, "offline": 1, "paused": 1, "heating": 1,
                              "printing": 1, "idle": 1}
    fleet.put_status("e-lost", snapshot(1, 1001.0, "printing", 900.0))
    assert fleet.entries["e-lost"].state == "offline"  # a stale status does not revive it
    fleet.put_online("e-lost", True)
    assert fleet.entries["e-lost"].state == "printing"
    fleet.put_status("x-odd", Snapshot(state="melting"))
    assert fleet.ordered()[:2] == ["c-err", "x-odd"]  # an unknown state counts as a problem
    assert fleet.counts()["error"] == 2


def test_filter_matches_name_job_and_state_prefix() -> None:
    fleet = model()
    assert fleet.ordered("paus") == ["d-pause"]
    assert fleet.ordered("off") == ["e-lost"]
    assert fleet.ordered("PRINT") == ["a-print"]  # name a-print; e-lost is offline now
    assert fleet.ordered("a- print") == ["a-print"]  # every word must match
    assert fleet.ordered("part-06") == ["e-lost", "f-heat"]  # job names
    assert fleet.ordered("zzz") == []
    assert fleet.take_dirty() == {"a-print", "b-idle", "c-err", "d-pause", "e-lost", "f-heat"}
    assert fleet.take_dirty() == set()


def test_cells_and_progress_bar() -> None:
    fleet = model()
    cells = row_cells("c-err", fleet.entries["c-err"])
    assert cells[:3] == ("c-err", "error", "thermal runaway on the hotend")
    assert cells[6].endswith("/210")
    assert cells[7].endswith("/60")
    idle = row_cells("b-idle", fleet.entries["b-idle"])
    assert idle[3:6] == ("", "", "")
    assert idle[7] == "23"
    assert progress_bar(0.0).strip() == "0%"
    assert progress_bar(1.0) == "████████ 100%"
    assert progress_bar(0.5).startswith("████ ")
    assert len(progress_bar(0.5)) == 13
    assert progress_bar(2.0) == progress_bar(1.0)


def test_broker_lists() -> None:
    assert parse_brokers("a") == [("a", 1883)]
    assert parse_brokers("a:1, b:2,c") == [("a", 1), ("b", 2), ("c", 1883)]
    for bad in ["", "a:", "a:x", "a:70000", ":1", "a b:1"]:
        with pytest.raises(ValueError, match="broker"):
            parse_brokers(bad)


def test_cli_refuses_bad_fleet_options(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["tui", "--mqtt", "farm:http"]) == 2
    assert "--mqtt: broker 'farm:http'" in capsys.readouterr().err
    assert main(["tui", "--username", "x", "--socket", "/nonexistent"]) == 2
    assert "go with --mqtt" in capsys.readouterr().err
    assert main(["tui", "--cafile", "ca.crt", "--socket", "/nonexistent"]) == 2
    assert "go with --mqtt" in capsys.readouterr().err
    assert main(["tui", "--mqtt", "farm", "--cafile", "ca.crt"]) == 2
    assert "--cafile, --certfile and --keyfile go with --tls" in capsys.readouterr().err
    assert main(["tui", "--mqtt", "farm", "--tls", "--certfile", "me.crt"]) == 2
    assert "needs both --certfile and --keyfile" in capsys.readouterr().err
    missing = tmp_path / "nothing.crt"
    assert main(["tui", "--mqtt", "farm", "--tls", "--cafile", str(missing)]) == 2
    assert f"--tls: CA file {missing}: no such file" in capsys.readouterr().err
    garbage = tmp_path / "garbage.crt"
    garbage.write_text("not a certificate\n")
    assert main(["tui", "--mqtt", "farm", "--tls", "--cafile", str(garbage)]) == 2
    assert f"CA file {garbage}: not a PEM certificate" in capsys.readouterr().err
    assert main(["tui", "--mqtt", "farm", "--tls", "--certfile", str(garbage),
                 "--keyfile", str(garbage)]) == 2
    assert f"certificate {garbage} with key {garbage}: cannot be loaded" in \
        capsys.readouterr().err


def test_wire_client_reports_a_refusal_and_reads_messages(tmp_path: Path) -> None:
    broker = start_broker(tmp_path / "broker", users={"fleet": "right"})

    async def scenario() -> list[tuple[str, bytes, bool]]:
        refused = r"refused the connection: (bad user name or password|not authorised)"
        with pytest.raises(WireError, match=refused):
            async with WireClient(HOST, broker.port, client_id="t1", username="fleet",
                                  password="wrong"):
                pass
        async with WireClient(HOST, broker.port, client_id="t3", username="fleet",
                              password="right") as reader:
            reader.subscribe("hostd/+/status", qos=1)
            reader.subscribe("hostd/+/event", qos=0)
            # the broker takes a client's packets in order: the reader's own message
            # comes back once both subscriptions are in place
            stream = reader.messages()
            await reader.publish("hostd/ready/status", b"", qos=1)
            async with asyncio.timeout(10):
                async for message in stream:
                    if message.topic == "hostd/ready/status":
                        break
            async with WireClient(HOST, broker.port, client_id="t2", username="fleet",
                                  password="right") as sender:
                await sender.publish("hostd/p1/status", b"x" * 300, qos=1)  # 2-byte length
                await sender.publish("hostd/p2/event", b'{"event":"done"}', qos=1)
                got: list[tuple[str, bytes, bool]] = []
                async with asyncio.timeout(10):
                    async for message in stream:
                        got.append((message.topic, message.payload, message.retain))
                        if len(got) == 2:
                            return got
        raise AssertionError("unreachable")

    try:
        got = asyncio.run(scenario())
    finally:
        broker.stop()
    assert got == [("hostd/p1/status", b"x" * 300, False),
                   ("hostd/p2/event", b'{"event":"done"}', False)]


def test_fleet_view_over_tls_with_its_own_ca_and_a_client_certificate(tmp_path: Path) -> None:
    """``--tls --cafile --certfile --keyfile``: a broker whose CA is not the system's and
    which admits only clients with a certificate that CA signed (and a password)."""
    from support.brokers import make_ca_chain
    from support.fleet_helpers import rows
    from support.waiting import until

    from tui.fleet import FleetApp
    from tui.sources import MqttSource, tls_context

    chain = make_ca_chain(tmp_path / "pki")
    broker = start_broker(tmp_path / "broker", users={"fleet": "right"}, tls=chain.server)
    login = {"username": "fleet", "password": "right"}
    with_cert = tls_context(str(chain.ca), str(chain.client_cert), str(chain.client_key))
    status = snapshot(3, 1000.0, "paused", 900.0).to_json().encode()

    async def scenario() -> None:
        with pytest.raises(WireError, match="cannot connect"):  # the system CAs do not know it
            async with WireClient(HOST, broker.port, client_id="t0", tls=tls_context(), **login):
                pass
        with pytest.raises(WireError):  # the broker's CA trusted, but no client certificate
            async with WireClient(HOST, broker.port, client_id="t1",
                                  tls=tls_context(str(chain.ca)), **login) as bare:
                bare.subscribe("hostd/+/status")
                async with asyncio.timeout(10):
                    async for _message in bare.messages():
                        pass
        async with WireClient(HOST, broker.port, client_id="t2", tls=with_cert,
                              **login) as sender:
            await sender.publish("hostd/p7/status", status, qos=1, retain=True)
        app = FleetApp(MqttSource(HOST, broker.port, tls=with_cert, **login), refresh_s=0.05)
        async with app.run_test(size=(80, 24)):
            await until(lambda: rows(app) == [("p7", "paused")], what=lambda: rows(app))

    try:
        asyncio.run(scenario())
    finally:
        broker.stop()

