"""Synthetic printers on MQTT: real status payloads for many printers, at a steady rate.

Run as ``python -m bench.fleetpub --broker HOST:PORT --count N``. With ``--will``
each printer has its own connection with a last will on ``hostd/<id>/online``
(as a daemon has); otherwise the printers share a few connections (a light
load generator for the fleet benchmark).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import time
from typing import Any

import aiomqtt

from hostd.api import JobStatus, PrinterInfo, Snapshot, Temperature, Temps

STATES = ("printing",) * 16 + ("idle", "idle", "paused", "error")
CONNECTIONS = 8  # without wills: printers spread over this many connections


def printer_id(prefix: str, index: int) -> str:
    """The id of synthetic printer ``index``."""
    return f"{prefix}{index:04d}"


def snapshot(index: int, now: float, state: str, started: float) -> Snapshot:
    """A plausible status of synthetic printer ``index`` at unix time ``now``."""
    if state in ("idle", "offline"):
        return Snapshot(state=state, printer=PrinterInfo(id=str(index), connected=True),
                        temps=Temps(Temperature(24.0 + index % 3, 0.0),
                                    Temperature(23.0, 0.0)), ts=now)
    total = 200 + index % 300
    elapsed = (now - started) + 60.0 * (index % 97)
    layer = int(elapsed / 6.0) % total
    wobble = math.sin(now + index)
    job = JobStatus(id=str(1000 + index), name=f"part-{index % 41:02d}", layer=layer,
                    layers=total, progress=layer / total, lines_acked=int(elapsed * 40),
                    elapsed_s=elapsed, eta_s=(total - layer) * 6.0, layers_ready_ahead=4)
    return Snapshot(
        state=state, printer=PrinterInfo(id=str(index), connected=True),
        temps=Temps(Temperature(209.5 + wobble, 210.0), Temperature(59.8 + wobble / 4, 60.0)),
        job=job, queue=("bracket", "gear")[: index % 3],
        error="thermal runaway on the hotend" if state == "error" else None, ts=now,
    )


def advance(body: dict[str, Any], index: int, now: float, started: float) -> None:
    """Move a status (``Snapshot.to_dict`` data) to time ``now``: layer, times, temperatures."""
    body["ts"] = now
    job = body.get("job")
    if job:
        elapsed = (now - started) + 60.0 * (index % 97)
        job["layer"] = int(elapsed / 6.0) % job["layers"]
        job["progress"] = job["layer"] / job["layers"]
        job["elapsed_s"] = elapsed
        job["eta_s"] = (job["layers"] - job["layer"]) * 6.0
        job["lines_acked"] = int(elapsed * 40)
        wobble = math.sin(now + index)
        body["temps"]["hotend"]["actual"] = round(209.5 + wobble, 2)
        body["temps"]["bed"]["actual"] = round(59.8 + wobble / 4, 2)


async def _connection(
    host: str, port: int, indexes: list[int], args: argparse.Namespace, deadline: float,
) -> int:
    """Publish the status of ``indexes`` every 1/rate s until ``deadline``; messages sent."""
    states = args.states.split(",") if args.states else list(STATES)
    will = None
    if args.will:
        topic = f"hostd/{printer_id(args.prefix, indexes[0])}/online"
        will = aiomqtt.Will(topic, "offline", qos=1, retain=True)
    sent = 0
    started = time.time()
    # each printer's status as plain data, built once from a Snapshot; then only the
    # changing fields are set before each publish (building dataclasses costs more)
    bodies = {index: snapshot(index, started, states[index % len(states)], started).to_dict()
              for index in indexes}
    topics = {index: f"hostd/{printer_id(args.prefix, index)}/status" for index in indexes}
    async with aiomqtt.Client(host, port, will=will, keepalive=10,
                              username=args.username or None,
                              password=args.password or None) as client:
        for index in indexes:
            await client.publish(f"hostd/{printer_id(args.prefix, index)}/online", "online",
                                 qos=1, retain=True)
        period = 1.0 / args.rate if args.rate > 0 else 0.0
        tick = time.monotonic()
        while True:
            for n, index in enumerate(indexes):
                body = bodies[index]
                now = time.time()
                advance(body, index, now, started)
                await client.publish(topics[index], json.dumps(body, separators=(",", ":")),
                                     qos=0, retain=True)
                sent += 1
                if period and n % 50 == 49:  # spread a connection's printers over the second
                    await asyncio.sleep(0)
            if not period or time.monotonic() >= deadline:
                break
            tick += period
            await asyncio.sleep(max(0.0, tick - time.monotonic()))
        if not period:
            await asyncio.sleep(args.hold)  # keep the connection (and its will) alive
    return sent


async def main_async(args: argparse.Namespace) -> int:
    """Run every connection; print the number of status messages published."""
    host, _, port = args.broker.partition(":")
    indexes = list(range(args.first, args.first + args.count))
    groups = [indexes] if args.will else [indexes[i::CONNECTIONS] for i in range(CONNECTIONS)]
    deadline = time.monotonic() + args.duration
    sent = await asyncio.gather(*(
        _connection(host, int(port or 1883), group, args, deadline) for group in groups if group
    ))
    print(f"published {sum(sent)}", flush=True)
    return 0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options of the publisher."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--broker", required=True, metavar="HOST:PORT")
    parser.add_argument("--count", type=int, default=1)
    parser.add_argument("--first", type=int, default=0, help="index of the first printer")
    parser.add_argument("--prefix", default="sim")
    parser.add_argument("--rate", type=float, default=1.0, help="statuses per printer per s "
                        "(0: publish once, then hold the connection --hold s)")
    parser.add_argument("--duration", type=float, default=10.0, metavar="S")
    parser.add_argument("--hold", type=float, default=3600.0, metavar="S")
    parser.add_argument("--states", default="", help="comma-separated states, by index")
    parser.add_argument("--will", action="store_true", help="one printer with a last will")
    parser.add_argument("--username", default="")
    parser.add_argument("--password", default="")
    return parser.parse_args(argv)


if __name__ == "__main__":
    raise SystemExit(asyncio.run(main_async(parse_args())))
