"""Fleet benchmark: broker messages/s, fleet-view lag and CPU, daemons' MQTT CPU.

Scenarios (``--scenarios``, comma-separated):

- ``pubN``: a light publisher emulates N printers (real status payloads, 1 Hz
  each) on a mosquitto; the fleet view runs in a pseudo-terminal.
- ``natsN``: the same on a three-node nats-server cluster (publisher on the
  first node, fleet view on the third).
- ``daemonsN``: N real ``hostd run`` daemons printing on simulated printers,
  bridged to a mosquitto, each under a CPU sampler (``bench/fleet_daemon.py``).
- ``failover``: one daemon printing on a three-node nats-server cluster; its node
  is stopped (SIGTERM, then SIGKILL, ``--repeats`` times each) and the seconds
  until its status is back in the fleet view through another node are measured
  (``bench/fleet_failover.py``).

Every scenario is bounded: start-up waits time out, the window is ``--window`` s.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import aiomqtt

from bench import proctree

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from support.brokers import HOST, start_broker, start_nats_cluster  # noqa: E402

from bench.fleet_term import Terminal  # noqa: E402
from tui.mqtt_wire import WireClient  # noqa: E402

MODEL = ROOT / "tests" / "data" / "cube20_xyz.stl"
PYTHON_ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


@dataclass
class Figures:
    """What one scenario measured."""

    name: str
    broker: str
    printers: int
    msgs_per_s: float = 0.0
    lag_p50: float | None = None
    lag_p95: float | None = None
    lag_n: int = 0
    direct_p95: float | None = None  # a bare subscriber's lag p95, s
    dash_cpu: float = 0.0  # % of one core
    daemon_cpu: list[float] = field(default_factory=list)  # % of one core, each daemon
    daemon_mqtt: list[float] = field(default_factory=list)  # % of one core, each daemon

    def row(self) -> str:
        """One Markdown table row."""
        lag = (f"{self.lag_p50:.3f} / {self.lag_p95:.3f} s ({self.lag_n})"
               if self.lag_p50 is not None else "-")
        cpu = (f"{statistics.mean(self.daemon_cpu):.1f} % (max {max(self.daemon_cpu):.1f})"
               if self.daemon_cpu else "-")
        mqtt = (f"{statistics.mean(self.daemon_mqtt):.2f} % (max {max(self.daemon_mqtt):.2f})"
                if self.daemon_mqtt else "-")
        direct = f"{self.direct_p95:.3f} s" if self.direct_p95 is not None else "-"
        return (f"| {self.name} | {self.broker} | {self.printers} | {self.msgs_per_s:.0f} | "
                f"{direct} | {lag} | {self.dash_cpu:.1f} % | {cpu} | {mqtt} |")


HEADER = ("| scenario | broker | printers | status msgs/s | bare subscriber lag p95 | "
          "fleet lag p50 / p95 (samples) | fleet view CPU | daemon CPU (mean) | "
          "daemon MQTT CPU (mean) |\n"
          "|---|---|---|---|---|---|---|---|---|")


async def _count(port: int, window: float) -> tuple[float, list[float]]:
    """Status messages per second reaching a subscriber of ``hostd/+/status``, and the
    lag of each from its timestamp (the broker's own delivery lag, for comparison)."""
    count = 0
    lags: list[float] = []
    async with WireClient(HOST, port, client_id="bench-counter") as client:
        client.subscribe("hostd/+/status", qos=0)
        start = time.monotonic()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(window):
                async for message in client.messages():
                    if not message.retain:
                        count += 1
                        if count % 10 == 0:
                            lags.append(time.time() - json.loads(message.payload)["ts"])
        return count / (time.monotonic() - start), lags


async def wait_states(port: int, ids: set[str], state: str, timeout: float) -> None:
    """Wait until every printer of ``ids`` published ``state``."""
    pending = set(ids)
    async with aiomqtt.Client(HOST, port) as client:
        await client.subscribe("hostd/+/status", qos=0)
        async with asyncio.timeout(timeout):
            async for message in client.messages:
                printer = str(message.topic).split("/")[1]
                if json.loads(message.payload).get("state") == state:
                    pending.discard(printer)
                if not pending:
                    return


def _lags(path: Path, since: int) -> list[float]:
    lines = path.read_text().split() if path.exists() else []
    return [float(v) for v in lines[since:]]


def _lines(path: Path) -> int:
    return len(path.read_text().split()) if path.exists() else 0


def measure_window(figures: Figures, count_port: int, dash: Terminal, lags: Path,
                   window: float, daemons: list[subprocess.Popen[bytes]] | None = None,
                   samples: list[Path] | None = None) -> None:
    """Measure one window: message rate, lag percentiles, CPU of the view and the daemons."""
    daemons, samples = daemons or [], samples or []
    start_lags = _lines(lags)
    for proc in daemons:
        proc.send_signal(signal.SIGUSR1)
    cpu0 = [proctree.cpu_seconds(p.pid) for p in daemons]
    dash0, t0 = proctree.cpu_seconds(dash.pid), time.monotonic()
    figures.msgs_per_s, direct = asyncio.run(_count(count_port, window))
    direct.sort()
    if direct:
        figures.direct_p95 = direct[min(len(direct) - 1, int(len(direct) * 0.95))]
    elapsed = time.monotonic() - t0
    figures.dash_cpu = 100 * (proctree.cpu_seconds(dash.pid) - dash0) / elapsed
    figures.daemon_cpu = [100 * (proctree.cpu_seconds(p.pid) - c) / elapsed
                          for p, c in zip(daemons, cpu0, strict=True)]
    for proc in daemons:
        proc.send_signal(signal.SIGUSR1)
    time.sleep(1.5)  # the last lags and sampler lines are written
    for path in samples:
        first, last = (json.loads(line) for line in path.read_text().splitlines()[-2:])
        cpu = last["cpu_s"] - first["cpu_s"]
        share = (last["mqtt"] - first["mqtt"]) / max(1, last["samples"] - first["samples"])
        figures.daemon_mqtt.append(100 * cpu * share / (last["t"] - first["t"]))
    found = sorted(_lags(lags, start_lags))
    if found:
        figures.lag_n = len(found)
        figures.lag_p50 = found[len(found) // 2]
        figures.lag_p95 = found[min(len(found) - 1, int(len(found) * 0.95))]


def start_publisher(broker: str, count: int, duration: float) -> subprocess.Popen[bytes]:
    """The light publisher (`bench.fleetpub`): ``count`` printers at 1 Hz for ``duration`` s."""
    return subprocess.Popen(
        [sys.executable, "-m", "bench.fleetpub", "--broker", broker, "--count", str(count),
         "--rate", "1", "--duration", str(duration)],
        cwd=ROOT, env=PYTHON_ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def stop_process(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL after 15 s."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def publisher_scenario(tmp: Path, count: int, window: float, nats: bool) -> Figures:
    """``count`` emulated printers at 1 Hz; the fleet view's lag and CPU."""
    if nats:
        cluster = start_nats_cluster(tmp / "nats")
        pub_port, view_port = cluster.nodes[0].mqtt_port, cluster.nodes[2].mqtt_port
        stop, name = cluster.stop, "nats cluster (3 nodes)"
    else:
        broker = start_broker(tmp / "mosquitto")
        pub_port = view_port = broker.port
        stop, name = broker.stop, "mosquitto"
    figures = Figures(f"{'nats' if nats else 'pub'}{count}", name, count)
    lags = tmp / "lags.txt"
    publisher = start_publisher(f"{HOST}:{pub_port}", count, window + 30)
    dash = Terminal([sys.executable, "-m", "bench.fleet_dash", "--broker",
                     f"{HOST}:{view_port}", "--lags", str(lags)], cwd=ROOT, env=PYTHON_ENV)
    try:
        time.sleep(8.0)  # start-up, first retained statuses, table filled
        measure_window(figures, view_port, dash, lags, window)
    finally:
        dash.close()
        stop_process(publisher)
        stop()
    return figures


def _daemon_config(folder: Path, printer: str, port: int) -> Path:
    folder.mkdir(parents=True)
    config = folder / "hostd.toml"
    config.write_text(
        f'[jobs]\nfolder = "{folder / "jobs"}"\nsettle_s = 0.2\n'
        f'[state]\nfolder = "{folder / "var"}"\n'
        f'[printer]\nid = "{printer}"\nbed = [200, 200, 200]\n'
        "[simulator]\ntime_scale = 1.0\nbaud = 250000\n"
        "[runner]\nlookahead = 2\nworkers = 1\n"
        f'[mqtt]\nenabled = true\nhost = "{HOST}"\nport = {port}\n'
        "[slicing]\nskip_heating = true\n"
    )
    (folder / "jobs").mkdir()
    return config


def daemons_scenario(tmp: Path, count: int, window: float) -> Figures:
    """``count`` real daemons printing, bridged to a mosquitto, under CPU samplers."""
    broker = start_broker(tmp / "mosquitto")
    figures = Figures(f"daemons{count}", "mosquitto", count)
    lags = tmp / "lags.txt"
    daemons: list[subprocess.Popen[bytes]] = []
    samples: list[Path] = []
    ids = {f"d{n:03d}" for n in range(count)}
    dash: Terminal | None = None
    try:
        for printer in sorted(ids):
            config = _daemon_config(tmp / printer, printer, broker.port)
            samples.append(tmp / printer / "samples.jsonl")
            log = (tmp / printer / "daemon.log").open("wb")
            daemons.append(subprocess.Popen(
                [sys.executable, "-m", "bench.fleet_daemon", str(samples[-1]), "--",
                 "run", "--config", str(config)],
                cwd=tmp / printer, env=PYTHON_ENV, stdout=log, stderr=log))
            log.close()
        dash = Terminal([sys.executable, "-m", "bench.fleet_dash", "--broker",
                         f"{HOST}:{broker.port}", "--lags", str(lags)], cwd=ROOT, env=PYTHON_ENV)
        asyncio.run(wait_states(broker.port, ids, "idle", 240))
        for printer in sorted(ids):
            (tmp / printer / "jobs" / MODEL.name).write_bytes(MODEL.read_bytes())
        asyncio.run(wait_states(broker.port, ids, "printing", 300))
        time.sleep(3.0)
        measure_window(figures, broker.port, dash, lags, window, daemons, samples)
    finally:
        if dash is not None:
            dash.close()
        for proc in daemons:
            proc.send_signal(signal.SIGTERM)
        for proc in daemons:
            stop_process(proc)
        broker.stop()
    return figures


def main() -> int:
    """Run the chosen scenarios and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios",
                        default="daemons10,daemons25,pub100,pub1000,nats100,nats1000")
    parser.add_argument("--window", type=float, default=20.0, help="measured seconds")
    parser.add_argument("--repeats", type=int, default=3,
                        help="failover: stops of the daemon's node per signal (1-5)")
    args = parser.parse_args()
    rows = []
    for scenario in args.scenarios.split(","):
        with tempfile.TemporaryDirectory(prefix="hostd-fleet-") as folder:
            tmp = Path(folder)
            if scenario == "failover":
                from bench.fleet_failover import failover_scenario

                print("running failover ...", file=sys.stderr, flush=True)
                print(failover_scenario(tmp, args.repeats).table())
                continue
            kind = scenario.rstrip("0123456789")
            count = int(scenario[len(kind):])
            print(f"running {scenario} ...", file=sys.stderr, flush=True)
            if kind == "daemons":
                figures = daemons_scenario(tmp, count, args.window)
            else:
                figures = publisher_scenario(tmp, count, args.window, nats=kind == "nats")
        rows.append(figures.row())
        print(figures.row(), file=sys.stderr, flush=True)
    if rows:
        print(HEADER)
        print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
