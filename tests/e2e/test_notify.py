"""Notifications from a real daemon to local HTTP endpoints: one good, one failing, one hung."""

from __future__ import annotations

import base64
import io
import json
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
import trimesh
from PIL import Image
from support.daemon_helpers import command, printing_layer, small_box
from support.daemon_process import sim_config
from support.waiting import wait_until

from hostd.config import NotifyConfig
from hostd.publishing.notify import Message, Notifier


class Endpoint:
    """An HTTP server on 127.0.0.1 that records the JSON bodies POSTed to it."""

    def __init__(self, status: int = 200) -> None:
        self.received: list[dict[str, Any]] = []
        received, code = self.received, status

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length", 0))
                received.append(json.loads(self.rfile.read(length)))
                self.send_response(code)
                self.end_headers()

            def log_message(self, *args: object) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def titles(self) -> list[str]:
        return [item.get("title", "") for item in self.received]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


class Hung:
    """A port that accepts connections (the kernel's backlog) and never answers."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.port = self.sock.getsockname()[1]

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def endpoints():
    good, failing, hung = Endpoint(), Endpoint(status=500), Hung()
    yield good, failing, hung
    good.close()
    failing.close()
    hung.close()


def png_of(item: dict[str, Any]) -> Image.Image:
    (attachment,) = item["attachments"]
    assert attachment["mimetype"] == "image/png"
    image = Image.open(io.BytesIO(base64.b64decode(attachment["base64"])))
    image.load()
    assert image.format == "PNG"
    return image


def notify_section(*ports: int, timeout: float = 1.0, events: str = "") -> str:
    urls = ", ".join(f'"json://127.0.0.1:{port}/"' for port in ports)
    return f"[notify]\nurls = [{urls}]\ntimeout_s = {timeout}\n{events}"


def test_a_print_and_a_bad_model_notify_with_pictures_despite_bad_endpoints(
    daemon, tmp_path: Path, endpoints
) -> None:
    good, failing, hung = endpoints
    hostd = daemon(sim_config(extra=notify_section(hung.port, failing.port, good.port)))
    box = trimesh.creation.box((20.0, 20.0, 5.0))
    box.export(tmp_path / "cube.stl")
    hostd.drop(tmp_path / "cube.stl", "cube.stl")
    hostd.wait_for(lambda: (hostd.jobs / "done" / "cube.gcode").exists(), 120, "cube printed")
    hostd.drop(b"\x00" * 40, "junk.stl")
    hostd.wait_for(lambda: (hostd.jobs / "failed" / "junk.error.txt").exists(), 30, "junk failed")
    hostd.wait_for(lambda: any("junk" in title for title in good.titles()), 30,
                   "the failure's notification")
    titles = good.titles()
    assert titles == ["cube.stl: first layer done", "cube.stl printed", "junk.stl failed"]
    first, done, failed = good.received
    assert "job 1" in first["message"]
    assert "25 layers" in first["message"]
    assert png_of(first).size[0] > 100
    header = (hostd.jobs / "done" / "cube.gcode").read_text().splitlines()
    slicer_mm = float(next(line for line in header if "filament used [mm]" in line).split()[-1])
    metres = float(done["message"].split("filament ")[1].split(" m")[0])
    assert "cube.stl (job 1) is done. 25 layers, filament" in done["message"]
    assert abs(metres * 1000 - slicer_mm) <= 6  # the same moves, but not the end's retraction
    assert done["type"] == "success"
    png_of(done)
    reason = (hostd.jobs / "failed" / "junk.error.txt").read_text().strip()
    assert failed["message"] == f"junk.stl (job 2) failed: {reason}"
    assert failed["attachments"] == []  # no layer was ever made
    assert failing.titles() == titles  # it was asked each time, and its refusals did no harm
    assert "not delivered" in hostd.log()
    assert hostd.stop() == 0


def test_pause_and_cancel_are_notified_with_the_layer_in_progress(
    daemon, tmp_path: Path, endpoints
) -> None:
    good, _failing, _hung = endpoints
    hostd = daemon(sim_config(time_scale=0.01, extra=notify_section(good.port)))
    socket_path = hostd.state / "hostd.sock"
    hostd.wait_for(socket_path.exists, 10, "the control socket")
    hostd.drop(small_box(tmp_path / "box.stl"), "box.stl")
    hostd.wait_for(printing_layer(socket_path, 2), 60, "layer 2 printing")
    command(socket_path, "pause")
    hostd.wait_for(lambda: "box.stl paused" in good.titles(), 20, "the pause notification")
    command(socket_path, "cancel")
    hostd.wait_for(lambda: "box.stl was cancelled" in good.titles(), 20, "the cancel one")
    paused = good.received[good.titles().index("box.stl paused")]
    layer = int(paused["message"].split("paused at layer ")[1].split()[0])
    assert layer >= 3
    assert png_of(paused).size[0] > 100
    cancelled = good.received[-1]
    assert "cancelled at layer" in cancelled["message"]
    png_of(cancelled)
    assert hostd.stop() == 0


def test_a_hung_endpoint_never_blocks_the_caller_and_the_queue_is_bounded() -> None:
    hung = Hung()
    try:
        settings = NotifyConfig(urls=(f"json://127.0.0.1:{hung.port}/",), timeout_s=1.0)
        notifier = Notifier(settings, queue_size=2)
        for number in range(6):
            notifier.on_event({"event": "failed", "id": str(number), "name": "x.stl",
                               "reason": "bad"})
        # all six were queued or dropped while the first send still waits for its timeout
        assert notifier.failed == 0
        assert notifier.dropped >= 3
        wait_until(lambda: notifier.failed + notifier.dropped >= 6, 20,
                   lambda: (notifier.failed, notifier.dropped))
        assert notifier.failed + notifier.dropped == 6
        assert notifier.sent == 0
        notifier.close()
    finally:
        hung.close()


def test_messages_name_the_job_and_skip_what_is_not_wanted() -> None:
    notifier = Notifier(NotifyConfig(urls=("json://127.0.0.1:9/",)))
    assert notifier.compose({"event": "layer", "id": "3", "name": "a.stl", "layer": 5}) is None
    assert notifier.compose({"event": "error", "cmd": "pause", "reason": "no job"}) is None
    message = notifier.compose({"event": "error", "source": "printer", "message": "MINTEMP"})
    assert message == Message("error", "hostd: printer error", "printer: MINTEMP", "failure")
    paused = notifier.compose({"event": "paused", "id": "3", "name": "a.stl", "layer": 7})
    assert paused is not None
    assert "a.stl (job 3) is paused at layer 9" in paused.body
