"""Fleet failover: how soon a printer's status is back in the fleet view after its node stops.

One real ``hostd run`` daemon prints on its simulated printer, bridged to a
three-node nats-server cluster with ``mqtt.hosts`` listing every node. The fleet
view's own MQTT client (``tui.mqtt_wire.WireClient``, subscribed to the printer's
status as the view is) sits on another node. The daemon's node is stopped
(SIGTERM, as ``systemctl stop`` does, or SIGKILL); measured: the seconds from the
signal until a status the daemon made after it reaches the view through another
node. The daemon's log says where the time went: when the bridge saw the
connection lost, and when it was connected again. The node is then started again
and the cluster waited for before the next repeat; the daemon prints on.

``python -m bench.fleet --scenarios failover --repeats 5`` (at most 5 repeats of
each signal; each waits at most ``WAIT_S`` for the status).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import random
import re
import signal
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from bench.fleet import MODEL, PYTHON_ENV, ROOT, wait_states
from tui.mqtt_wire import WireClient, WireError

sys.path.insert(0, str(ROOT / "tests"))  # the tests' broker helpers (bench.fleet does too)
from support.brokers import (
    HOST,
    NatsCluster,
    NatsNode,
    start_nats_cluster,
    wait_cluster_ready,
)

WAIT_S = 30.0  # the longest a repeat waits for the status to come back
MAX_REPEATS = 5
PRINTER = "fo1"
_LOG_LINE = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) \w+ hostd\.mqtt\w*: (.*)$")


@dataclass
class Repeat:
    """One stop of the daemon's node."""

    signal: str
    back_s: float | None = None  # signal -> a newer status seen through another node
    lost_s: float | None = None  # signal -> the bridge logged the connection lost
    connected_s: float | None = None  # signal -> the session was up again (its log)
    states: set[str] = field(default_factory=set)  # states seen meanwhile (printing only)
    wills: int = 0  # ``offline`` wills the view saw meanwhile
    drops: int = 0  # times the view's own node closed its connection meanwhile
    log: list[str] = field(default_factory=list)  # the bridge's log lines meanwhile


@dataclass
class Failover:
    """Every repeat of one run."""

    repeats: list[Repeat] = field(default_factory=list)

    def table(self) -> str:
        """A Markdown table: min / median / max of each figure, per signal."""
        lines = ["| signal | repeats | status back in the view (min / median / max) | "
                 "session lost (daemon's log) | session back (daemon's log) | states seen | "
                 "wills seen | view's own drops |",
                 "|---|---|---|---|---|---|---|---|"]
        for name in ("SIGTERM", "SIGKILL"):
            runs = [r for r in self.repeats if r.signal == name]
            if not runs:
                continue
            states = sorted(set().union(*(r.states for r in runs)))
            lines.append(f"| {name} | {len(runs)} | {_spread([r.back_s for r in runs])} | "
                         f"{_spread([r.lost_s for r in runs])} | "
                         f"{_spread([r.connected_s for r in runs])} | {', '.join(states)} | "
                         f"{sum(r.wills for r in runs)} | {sum(r.drops for r in runs)} |")
        return "\n".join(lines)


def _spread(values: list[float | None]) -> str:
    """``min / median / max s``, and how many did not happen within ``WAIT_S``."""
    found = sorted(v for v in values if v is not None)
    missing = len(values) - len(found)
    if not found:
        return "-"
    text = f"{found[0]:.2f} / {statistics.median(found):.2f} / {found[-1]:.2f} s"
    return text + (f" ({missing} not within {WAIT_S:.0f} s)" if missing else "")


def _log_events(log: Path) -> list[tuple[float, str]]:
    """(Unix time, message) of each line of the bridge in the daemon's log."""
    out = []
    for line in log.read_text(errors="replace").splitlines():
        match = _LOG_LINE.match(line)
        if match:
            stamp = datetime.strptime(match[1], "%Y-%m-%d %H:%M:%S").timestamp()
            out.append((stamp + int(match[2]) / 1000, match[3]))
    return out


def _session_node(log: Path, cluster: NatsCluster) -> NatsNode | None:
    """The node the daemon's session is on, from its log (None: the session is down)."""
    for _at, message in reversed(_log_events(log)):
        if message.startswith("MQTT connection to "):
            return None
        if message.startswith("MQTT connected to "):
            address = message.removeprefix("MQTT connected to ")
            return next(n for n in cluster.nodes if f"{HOST}:{n.mqtt_port}" == address)
    return None


async def _session_up(log: Path, cluster: NatsCluster, timeout: float) -> NatsNode:
    """Wait until the daemon's session is up; its node."""
    async with asyncio.timeout(timeout):
        while (node := _session_node(log, cluster)) is None:
            await asyncio.sleep(0.1)  # the daemon's log, read again
    return node


def daemon_config(folder: Path, cluster: NatsCluster) -> Path:
    """A daemon printing on its simulated printer in real time, MQTT on every node."""
    folder.mkdir(parents=True)
    hosts = ", ".join(f'"{host}"' for host in cluster.hosts())
    config = folder / "hostd.toml"
    config.write_text(
        f'[jobs]\nfolder = "{folder / "jobs"}"\nsettle_s = 0.2\n'
        f'[state]\nfolder = "{folder / "var"}"\n'
        f'[printer]\nid = "{PRINTER}"\nbed = [200, 200, 200]\n'
        "[simulator]\ntime_scale = 1.0\nbaud = 250000\n"
        "[runner]\nlookahead = 2\nworkers = 1\n"
        f"[mqtt]\nenabled = true\nhosts = [{hosts}]\n"
        "[slicing]\nskip_heating = true\n"
    )
    (folder / "jobs").mkdir()
    return config


class View:
    """What the fleet view knows of the printer, read as the view reads it: status (QoS 0),
    ``online`` and events (QoS 1) over one connection to one node, kept open across the
    stop (reconnected only when the node itself closes it, as the view does). A last
    will ``offline`` shows the printer offline until ``online`` comes again.

    Use ``async with``; :meth:`fresh` waits for what the view would show.
    """

    def __init__(self, port: int) -> None:
        self.port = port
        self.online: bool | None = None
        self.newest = 0.0  # the ``ts`` of the newest status shown
        self.states: set[str] = set()  # states of the statuses seen since the last reset
        self.wills = 0  # ``offline`` messages seen
        self.drops = 0  # times the node closed the view's connection
        self._changed = asyncio.Event()
        self._reader: asyncio.Task[None] | None = None

    async def __aenter__(self) -> View:
        self._reader = asyncio.create_task(self._read())
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._reader is not None
        self._reader.cancel()
        await asyncio.gather(self._reader, return_exceptions=True)

    async def _read(self) -> None:
        while True:
            name = f"bench-view-{random.getrandbits(32):08x}"
            try:
                async with WireClient(HOST, self.port, client_id=name) as client:
                    client.subscribe(f"hostd/{PRINTER}/status", qos=0)
                    client.subscribe(f"hostd/{PRINTER}/online", qos=1)
                    client.subscribe(f"hostd/{PRINTER}/event", qos=1)
                    async for message in client.messages():
                        if message.topic.endswith("/online"):
                            self.online = message.payload == b"online"
                            self.wills += 0 if self.online else 1
                        elif message.topic.endswith("/status"):
                            status = json.loads(message.payload)
                            self.newest = max(self.newest, float(status.get("ts", 0.0)))
                            self.states.add(str(status.get("state")))
                        self._changed.set()
            except WireError:
                self.drops += 1
                await asyncio.sleep(0.2)  # the fleet view's pause before it reconnects

    async def fresh(self, after: float, timeout: float) -> float | None:
        """Wait until a status made after ``after`` is shown (online); when it was, or None."""
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout):
                while not (self.newest > after and self.online is not False):
                    self._changed.clear()
                    await self._changed.wait()
                return time.time()
        return None


async def _one_stop(cluster: NatsCluster, log: Path, name: str) -> tuple[Repeat, NatsNode]:
    node = await _session_up(log, cluster, 60.0)
    watcher = next(n for n in cluster.nodes if n is not node)
    repeat = Repeat(name)
    async with View(watcher.mqtt_port) as view:
        if await view.fresh(time.time(), 20.0) is None:
            raise RuntimeError("no status flowing before the stop")
        if _session_node(log, cluster) is not node:  # the session moved meanwhile
            return await _one_stop(cluster, log, name)
        view.wills = view.drops = 0
        view.states.clear()
        assert node.process is not None
        stopped = time.time()
        node.process.send_signal(signal.SIGTERM if name == "SIGTERM" else signal.SIGKILL)
        seen = await view.fresh(stopped, WAIT_S)
        repeat.wills, repeat.drops, repeat.states = view.wills, view.drops, set(view.states)
    repeat.back_s = None if seen is None else seen - stopped
    with contextlib.suppress(TimeoutError):
        await _session_up(log, cluster, WAIT_S)  # the figures below need its reconnection
    for at, message in _log_events(log):
        if at < stopped - 0.5:  # the log's times are to the millisecond
            continue
        repeat.log.append(f"{at - stopped:+.2f} s {message[:90]}")
        if repeat.lost_s is None and message.startswith("MQTT connection to"):
            repeat.lost_s = max(0.0, at - stopped)
        elif repeat.lost_s is not None and message.startswith("MQTT connected to "):
            repeat.connected_s = max(0.0, at - stopped)
            break
    return repeat, node


def failover_scenario(tmp: Path, repeats: int) -> Failover:
    """Stop the daemon's node ``repeats`` times with each signal; the figures."""
    repeats = max(1, min(repeats, MAX_REPEATS))
    cluster = start_nats_cluster(tmp / "nats")
    daemon: subprocess.Popen[bytes] | None = None
    results = Failover()
    try:
        config = daemon_config(tmp / PRINTER, cluster)
        log = tmp / PRINTER / "daemon.log"
        with log.open("wb") as out:
            daemon = subprocess.Popen(
                [sys.executable, "-m", "hostd", "run", "--config", str(config)],
                cwd=tmp / PRINTER, env=PYTHON_ENV, stdout=out, stderr=out)
        view_port = cluster.nodes[2].mqtt_port
        asyncio.run(wait_states(view_port, {PRINTER}, "idle", 120))
        (tmp / PRINTER / "jobs" / MODEL.name).write_bytes(MODEL.read_bytes())
        asyncio.run(wait_states(view_port, {PRINTER}, "printing", 180))
        for name in ("SIGTERM", "SIGKILL"):
            done = 0
            for _ in range(repeats + 3):  # a stop the session had just left is done again
                if done == repeats:
                    break
                repeat, node = asyncio.run(_one_stop(cluster, log, name))
                if repeat.lost_s is not None:
                    results.repeats.append(repeat)
                    done += 1
                print(f"  {name}: back after {repeat.back_s} s (lost {repeat.lost_s}, "
                      f"connected {repeat.connected_s}), states {repeat.states}, "
                      f"wills {repeat.wills}, view drops {repeat.drops}", file=sys.stderr)
                for line in repeat.log:
                    print(f"    {line}", file=sys.stderr, flush=True)
                node.stop()  # waits for it to be gone, then it starts again
                node.start()
                wait_cluster_ready(cluster, 60.0)
                if daemon.poll() is not None:
                    raise RuntimeError("the daemon exited")
    finally:
        if daemon is not None and daemon.poll() is None:
            daemon.send_signal(signal.SIGTERM)
            try:
                daemon.wait(timeout=20)
            except subprocess.TimeoutExpired:
                daemon.kill()
                daemon.wait()
        cluster.stop()
    return results
