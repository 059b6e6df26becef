"""The farm queue end to end: `hostd run` daemons on simulated printers, a real three-node
nats-server cluster, and the `hostd farm` command line."""

from __future__ import annotations

import asyncio
import contextlib
import json
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.brokers import HOST, NatsCluster, start_nats_cluster
from support.daemon_process import DaemonProcess
from support.gcode_lines import commands_of, executed_job_lines
from support.paths import DATA, HOSTD, ROOT

from hostd.config import FarmConfig
from hostd.farm.queue import (
    CONSUMER,
    JOBS_BUCKET,
    MODELS_BUCKET,
    PRINTERS_BUCKET,
    STREAM,
    FarmQueue,
)
from hostd.farm.records import Entry

ACK_WAIT_S = 3.0


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[NatsCluster]:
    """Three nats-server nodes for the whole file."""
    nats = start_nats_cluster(tmp_path_factory.mktemp("nats"))
    yield nats
    nats.stop()


def servers(cluster: NatsCluster) -> list[str]:
    """The nodes' client URLs."""
    return [f"nats://{HOST}:{node.client_port}" for node in cluster.nodes]


@pytest.fixture
def farm(cluster: NatsCluster) -> Iterator[NatsCluster]:
    """The cluster with an empty farm (its stream, buckets and store removed after the test)."""
    yield cluster

    async def clear() -> None:
        import nats

        client = await nats.connect(servers=servers(cluster), connect_timeout=2)
        js = client.jetstream(timeout=10)
        for name in (STREAM, f"KV_{JOBS_BUCKET}", f"KV_{PRINTERS_BUCKET}",
                     f"OBJ_{MODELS_BUCKET}"):
            with contextlib.suppress(nats.js.errors.NotFoundError):
                await js.delete_stream(name)
        await client.close()

    asyncio.run(clear())


class Printers:
    """Daemons with the farm enabled, each in a folder of its own; killed at the end."""

    def __init__(self, root: Path, cluster: NatsCluster) -> None:
        self.root = root
        self.cluster = cluster
        self.started: dict[str, DaemonProcess] = {}

    def start(self, printer: str, material: str = "PLA", bed: str = "220, 220, 250",
              time_scale: float = 0.0, extra: str = "") -> DaemonProcess:
        urls = ", ".join(f'"{url}"' for url in servers(self.cluster))
        folder = self.root / printer
        folder.mkdir(exist_ok=True)
        daemon = DaemonProcess(folder, (
            "[jobs]\nsettle_s = 0.2\n"
            f"[simulator]\ntime_scale = {time_scale}\nbaud = 0\n"
            f'[printer]\nid = "{printer}"\nmaterial = "{material}"\nbed = [{bed}]\n'
            f"[farm]\nenabled = true\nservers = [{urls}]\nack_wait_s = {ACK_WAIT_S}\n"
            + extra))
        self.started[printer] = daemon
        daemon.start()
        daemon.wait_for(lambda: "farm: connected" in daemon.run_log(), 30, "the farm link")
        return daemon

    def close(self) -> None:
        for daemon in self.started.values():
            daemon.close()


@pytest.fixture
def printers(tmp_path: Path, farm: NatsCluster) -> Iterator[Printers]:
    made = Printers(tmp_path, farm)
    yield made
    made.close()


def hostd_farm(cluster: NatsCluster, *args: str, check: bool = True
               ) -> subprocess.CompletedProcess[str]:
    """`hostd farm --servers ... ARGS`."""
    result = subprocess.run(
        [*HOSTD, "farm", "--servers", ",".join(servers(cluster)), *args],
        capture_output=True, text=True, timeout=60, cwd=ROOT)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def submit(cluster: NatsCluster, model: Path, *args: str) -> list[str]:
    ids = json.loads(hostd_farm(cluster, "submit", str(model), *args, "--json").stdout)
    assert isinstance(ids, list)
    assert all(isinstance(i, str) for i in ids)
    return ids


def listing(cluster: NatsCluster) -> dict[str, dict[str, Any]]:
    rows = json.loads(hostd_farm(cluster, "list", "--json").stdout)
    for row in rows:
        assert set(row) >= {"id", "state", "printer", "reason"}
    return {row["id"]: row for row in rows}


def entry(cluster: NatsCluster, job_id: str) -> Entry:
    async def read() -> Entry:
        queue = await FarmQueue.open(FarmConfig(servers=tuple(servers(cluster))))
        try:
            return (await queue.entry(job_id))[0]
        finally:
            await queue.close()

    return asyncio.run(read())


def redelivered(cluster: NatsCluster) -> int:
    """How many deliveries the takers' consumer made beyond one per offer (an offer
    delivered again once its lease ran out, or given back by a printer it did not fit)."""
    async def read() -> int:
        queue = await FarmQueue.open(FarmConfig(servers=tuple(servers(cluster))))
        try:
            info = await queue.js.consumer_info(STREAM, CONSUMER)
            assert info.delivered is not None
            return int(info.delivered.consumer_seq or 0) - int(info.delivered.stream_seq or 0)
        finally:
            await queue.close()

    return asyncio.run(read())


def wait_rows(cluster: NatsCluster, check: Any, timeout: float, what: str
              ) -> dict[str, dict[str, Any]]:
    deadline = time.monotonic() + timeout
    rows: dict[str, dict[str, Any]] = {}
    while time.monotonic() < deadline:
        rows = listing(cluster)
        if check(rows):
            return rows
        time.sleep(0.3)
    pytest.fail(f"timed out waiting for {what}: {rows}")


def done_here(daemon: DaemonProcess) -> list[str]:
    """The farm job ids this printer printed (its done/ G-code files)."""
    return sorted(p.stem for p in (daemon.jobs / "done").glob("fj-*.gcode"))


def assert_printed_once(daemon: DaemonProcess, job_ids: list[str]) -> None:
    """What the simulated printer executed is each job's G-code, once, in the order taken."""
    local = sorted(((daemon.jobs / "done" / f"{i}.summary.txt").read_text(), i) for i in job_ids)
    ordered = [job_id for _text, job_id in sorted(
        local, key=lambda item: int(item[0].split()[1]))]  # "job N fj-....stl"
    expected: list[str] = []
    for job_id in ordered:
        expected += commands_of(daemon.jobs / "done" / f"{job_id}.gcode")
    assert executed_job_lines(daemon.state / "simulator-executed.log") == expected


def test_a_job_is_printed_once_by_the_printer_that_fits_and_one_none_fits_says_why(
        printers: Printers) -> None:
    cluster = printers.cluster
    pla = printers.start("pla1", material="PLA")
    petg = printers.start("petg1", material="PETG", bed="300, 300, 300")
    for_petg = submit(cluster, DATA / "cube20_xyz.stl", "--needs", "material=petg",
                      "--set", "infill.density=0.1")
    any_two = submit(cluster, DATA / "cube20_xyz.stl", "--copies", "2")
    wide = submit(cluster, DATA / "dogbone_100x30x5.stl", "--needs", "bed=250x250")
    abs_job = submit(cluster, DATA / "cube20_xyz.stl", "--needs", "material=ABS")
    nozzle = submit(cluster, DATA / "cube20_xyz.stl", "--needs", "nozzle=0.6")
    assert len(any_two) == 2
    done = {*for_petg, *any_two, *wide}
    rows = wait_rows(cluster, lambda r: all(r[i]["state"] == "printed" for i in done), 90,
                     "five printed jobs")
    assert rows[for_petg[0]]["printer"] == "petg1"
    assert rows[wide[0]]["printer"] == "petg1"
    assert rows[abs_job[0]] == {"id": abs_job[0], "state": "waiting", "printer": None,
                                "reason": "needs ABS: no printer has it loaded",
                                "name": "cube20_xyz.stl"}
    assert rows[nozzle[0]]["reason"] == "needs a 0.6 mm nozzle: no printer has one"
    # each job printed by one printer, and what each printer ran is its jobs, once each
    printed_pla, printed_petg = done_here(pla), done_here(petg)
    assert sorted(printed_pla + printed_petg) == sorted(done)
    for daemon, printed in ((pla, printed_pla), (petg, printed_petg)):
        assert_printed_once(daemon, printed)
        for job_id in printed:
            assert (daemon.jobs / "done" / f"{job_id}.stl").read_bytes() == \
                (DATA / ("dogbone_100x30x5.stl" if job_id in wide else "cube20_xyz.stl")
                 ).read_bytes()
    # the job's --set over the printer's own settings
    assert "; infill = linear 0.1\n" in (petg.jobs / "done" / f"{for_petg[0]}.gcode").read_text()
    assert "; infill = linear 0.2\n" in (petg.jobs / "done" / f"{wide[0]}.gcode").read_text()
    # the material is changed at run time: the ABS job goes to the printer that loads it
    subprocess.run([*HOSTD, "farm", "--config", str(pla.config), "material", "ABS"],
                   check=True, capture_output=True, timeout=30, cwd=pla.folder)
    rows = wait_rows(cluster, lambda r: r[abs_job[0]]["state"] == "printed", 60,
                     "the ABS job printed")
    assert rows[abs_job[0]]["printer"] == "pla1"
    # a printed job is not given back; the stream holds only the offer nobody took
    refused = hostd_farm(cluster, "requeue", abs_job[0], check=False)
    assert refused.returncode == 1
    assert "printed by pla1" in refused.stderr
    assert rows[nozzle[0]]["state"] == "waiting"


def test_bad_models_are_refused_at_submit_or_failed_once(printers: Printers,
                                                         tmp_path: Path) -> None:
    cluster = printers.cluster
    text = tmp_path / "notes.stl"
    text.write_text("these are not triangles\n")
    refused = hostd_farm(cluster, "submit", str(text), check=False)
    assert refused.returncode == 1
    assert "notes.stl is not an STL file" in refused.stderr
    small = tmp_path / "small.toml"
    urls = ", ".join(f'"{u}"' for u in servers(cluster))
    small.write_text(f"[farm]\nmax_bytes = 1000\nservers = [{urls}]\n")
    big = subprocess.run([*HOSTD, "farm", "--config", str(small), "submit",
                          str(DATA / "cube20_xyz.stl")],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert big.returncode == 1
    assert "over the farm's limit of 1000 bytes" in big.stderr
    assert listing(cluster) == {}  # nothing was stored or offered
    first, second = printers.start("a1"), printers.start("a2")
    [soup] = submit(cluster, DATA / "bad_triangle_soup.stl")
    rows = wait_rows(cluster, lambda r: r[soup]["state"] == "failed", 60, "the soup failed")
    failed_on = rows[soup]["printer"]
    assert failed_on in ("a1", "a2")
    assert rows[soup]["reason"]
    where = first if failed_on == "a1" else second
    other = second if where is first else first
    error = (where.jobs / "failed" / f"{soup}.error.txt").read_text().strip()
    assert error == rows[soup]["reason"]  # the slicer's sentence
    # failed once: the other printer never tried it, and it stays failed
    [cube] = submit(cluster, DATA / "cube20_xyz.stl")
    wait_rows(cluster, lambda r: r[cube]["state"] == "printed", 60, "a good job after it")
    assert not (other.jobs / "failed").exists()
    assert listing(cluster)[soup]["state"] == "failed"
    assert f"farm: job {soup}" not in other.log()


def test_a_killed_holder_keeps_the_job_until_it_is_given_back(printers: Printers) -> None:
    cluster = printers.cluster
    holder = printers.start("k1", time_scale=0.01)
    [job] = submit(cluster, DATA / "dogbone_100x30x5.stl")
    holder.wait_for(lambda: entry(cluster, job).layer >= 1, 60, "two layers printed")
    holder.kill9()
    other = printers.start("k2")
    time.sleep(ACK_WAIT_S * 2.5)  # the lease runs out: the offer is delivered again
    row = listing(cluster)[job]
    assert row["state"] == "taken"
    assert row["printer"] == "k1"
    assert "no heartbeat from k1" in row["reason"]
    # not given back while its printer may still be printing it, unless forced
    refused = hostd_farm(cluster, "requeue", job, check=False)
    assert refused.returncode == 1
    assert "restart its daemon" in refused.stderr
    assert done_here(other) == []
    assert not (other.state / "simulator-executed.log").exists() or \
        executed_job_lines(other.state / "simulator-executed.log") == []
    holder.start()  # its restart reports the job interrupted, on its bed
    rows = wait_rows(cluster, lambda r: r[job]["state"] == "interrupted", 30, "interrupted")
    assert rows[job]["printer"] == "k1"
    assert "hostd farm requeue" in rows[job]["reason"]
    hostd_farm(cluster, "requeue", job)
    rows = wait_rows(cluster, lambda r: r[job]["state"] == "printed", 90, "printed after requeue")
    # printed once, whole, by one printer; the holder's interrupted copy was removed
    printed = [d for d in (holder, other) if done_here(d) == [job]]
    assert len(printed) == 1
    assert (holder.jobs / "failed" / f"{job}.error.txt").read_text().strip() == \
        "given back to the farm queue"
    if printed[0] is other:
        assert_printed_once(other, [job])


def test_a_node_stopped_mid_run_loses_nothing(printers: Printers) -> None:
    cluster = printers.cluster
    first, second = printers.start("n1p"), printers.start("n2p")
    ids = submit(cluster, DATA / "cube20_xyz.stl", "--copies", "6")
    wait_rows(cluster, lambda r: any(r[i]["state"] == "printed" for i in ids), 60,
              "a first job printed")
    stopped = cluster.nodes[0]
    stopped.stop()
    try:
        rows = wait_rows(cluster, lambda r: all(r[i]["state"] == "printed" for i in ids),
                         120, "all six printed")
    finally:
        stopped.start()
    assert {rows[i]["printer"] for i in ids} <= {"n1p", "n2p"}
    printed = done_here(first) + done_here(second)
    assert sorted(printed) == sorted(ids)  # each once, none lost
    assert_printed_once(first, done_here(first))
    assert_printed_once(second, done_here(second))


class StallingRelay:
    """A TCP relay on loopback to one node whose traffic can be held (a network that stops
    carrying packets, connections kept), in a thread of its own."""

    def __init__(self, port: int) -> None:
        import threading

        self.target = port
        self.loop = asyncio.new_event_loop()
        self.flowing = asyncio.Event()
        self.port = 0
        ready = threading.Event()
        self.thread = threading.Thread(target=self._serve, args=(ready,), daemon=True)
        self.thread.start()
        assert ready.wait(10)

    def _serve(self, ready: Any) -> None:
        asyncio.set_event_loop(self.loop)

        async def pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            with contextlib.suppress(OSError, ConnectionError):
                while data := await reader.read(65536):
                    await self.flowing.wait()
                    writer.write(data)
                    await writer.drain()
            writer.close()

        async def relay(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            up_reader, up_writer = await asyncio.open_connection(HOST, self.target)
            await asyncio.gather(pump(reader, up_writer), pump(up_reader, writer))

        async def start() -> None:
            server = await asyncio.start_server(relay, HOST, 0)
            self.port = server.sockets[0].getsockname()[1]
            self.flowing.set()
            ready.set()
            await server.serve_forever()

        self.main = self.loop.create_task(start())
        with contextlib.suppress(asyncio.CancelledError):
            self.loop.run_until_complete(self.main)
        rest = asyncio.all_tasks(self.loop)
        for task in rest:
            task.cancel()
        self.loop.run_until_complete(asyncio.gather(*rest, return_exceptions=True))
        self.loop.close()

    def hold(self) -> None:
        self.loop.call_soon_threadsafe(self.flowing.clear)

    def release(self) -> None:
        self.loop.call_soon_threadsafe(self.flowing.set)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.main.cancel)
        self.thread.join(10)


def test_a_holder_cut_off_longer_than_the_ack_wait_still_prints_it_alone(
        printers: Printers) -> None:
    cluster = printers.cluster
    relay = StallingRelay(cluster.nodes[1].client_port)
    try:
        # the holder reaches the cluster only through the relay (a server list of one:
        # nodes the cluster announces are learnt once connected, so it stays on it)
        holder = printers.start("cut1", time_scale=0.01)
        text = holder.config.read_text()
        holder.config.write_text(text[:text.index("servers =")]
                                 + f'servers = ["nats://{HOST}:{relay.port}"]\n'
                                 + f"ack_wait_s = {ACK_WAIT_S}\n")
        holder.close()
        holder.start()
        holder.wait_for(lambda: "farm: connected" in holder.run_log(), 30, "the farm link")
        [job] = submit(cluster, DATA / "dogbone_100x30x5.stl")
        holder.wait_for(lambda: entry(cluster, job).layer >= 1, 60, "two layers printed")
        relay.hold()
        other = printers.start("cut2")
        time.sleep(ACK_WAIT_S * 3)  # the offer's lease runs out and it is delivered again
        row = listing(cluster)[job]
        assert row["printer"] == "cut1"
        assert "no heartbeat from cut1" in row["reason"]  # cut off indeed
        assert redelivered(cluster) >= 1
        relay.release()
        rows = wait_rows(cluster, lambda r: r[job]["state"] == "printed", 90, "printed")
    finally:
        relay.close()
    assert rows[job]["printer"] == "cut1"
    assert done_here(holder) == [job]
    assert_printed_once(holder, [job])
    assert done_here(other) == []


def test_the_fleet_view_shows_the_farm_queue_beside_the_printers(printers: Printers) -> None:
    from support.waiting import until

    from hostd.farm.feed import FarmFeed
    from tui.fleet import FleetApp
    from tui.fleet_farm import FarmPanel
    from tui.fleet_table import FleetTable
    from tui.sources import MqttSource

    cluster = printers.cluster
    node = cluster.nodes[2]
    printers.start("view1", time_scale=0.02,
                   extra=f"[mqtt]\nenabled = true\nhost = \"{HOST}\"\nport = {node.mqtt_port}\n")
    [waits] = submit(cluster, DATA / "cube20_xyz.stl", "--needs", "material=ABS")
    [prints] = submit(cluster, DATA / "dogbone_100x30x5.stl")
    feed = FarmFeed(FarmConfig(servers=tuple(servers(cluster))))

    def panel(app: FleetApp) -> str:
        return str(app.screen.query_one(FarmPanel).render())

    def job_cell(app: FleetApp) -> str:
        table = app.screen.query_one("#fleet", FleetTable)
        return table.row_at(0)[2] if table.row_count else ""

    async def scenario() -> None:
        app = FleetApp(MqttSource(HOST, node.mqtt_port), refresh_s=0.05, farm=feed)
        async with app.run_test(size=(120, 30)):
            await until(lambda: prints[:10] in job_cell(app), timeout=60,
                        what=lambda: job_cell(app))  # the printer's row names the farm job
            await until(lambda: f"{prints}  dogbone_100x30x5.stl on view1" in panel(app),
                        timeout=30, what=lambda: panel(app))
            text = panel(app)
            assert f"{waits}  cube20_xyz.stl: needs ABS: no printer has it loaded" in text
            assert text.index(prints) < text.index(waits)  # who prints what, then what waits
            assert "printing 1" in text
            assert "waiting 1" in text
        assert feed.queue is not None
        await feed.queue.close()

    asyncio.run(scenario())


def test_another_tool_submits_over_nats_as_the_readme_says(printers: Printers) -> None:
    """A job put in the queue with nats-py alone (no hostd code), in the wire format the
    README gives, is taken and printed like one from `hostd farm submit`."""
    import hashlib

    import nats

    cluster = printers.cluster
    daemon = printers.start("tool1")  # its daemon made the stream, buckets and store
    model = (DATA / "cube20_xyz.stl").read_bytes()
    digest = hashlib.sha256(model).hexdigest()
    job_id = "fj-00c0ffee42"

    async def put_in() -> None:
        client = await nats.connect(servers=servers(cluster), connect_timeout=2)
        js = client.jetstream(timeout=10)
        await (await js.object_store("hostd_farm_models")).put(digest, model)
        await (await js.key_value("hostd_farm_jobs")).put(job_id, json.dumps({
            "id": job_id, "name": "from_a_tool.stl", "model": digest, "size": len(model),
            "settings": {"infill.density": 0.1}, "needs": {"material": "PLA", "nozzle": 0.4,
                                                           "bed": [220, 220]},
            "state": "waiting", "generation": 1}).encode())
        await js.publish("hostd.farm.jobs", json.dumps({"id": job_id, "generation": 1}).encode(),
                         headers={"Nats-Msg-Id": f"{job_id}.1"})
        await client.close()

    asyncio.run(put_in())
    rows = wait_rows(cluster, lambda r: r.get(job_id, {}).get("state") == "printed", 60,
                     "the tool's job printed")
    assert rows[job_id]["printer"] == "tool1"
    assert (daemon.jobs / "done" / f"{job_id}.stl").read_bytes() == model
    assert "; infill = linear 0.1\n" in (daemon.jobs / "done" / f"{job_id}.gcode").read_text()
    assert_printed_once(daemon, [job_id])
