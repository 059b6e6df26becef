"""Bad input never stops the service: a corpus of malformed drops, each failed with its reason."""

from __future__ import annotations

import asyncio
import os
import struct
import threading
from pathlib import Path

import numpy as np
import trimesh
from support.daemon_process import sim_config
from support.gcode_lines import commands_of, executed_job_lines
from support.paths import DATA

from hostd.api import ControlClient

CUBE = trimesh.creation.box((20.0, 20.0, 20.0))


def binary_stl(triangles: np.ndarray, count: int | None = None) -> bytes:
    """A binary STL of ``triangles`` (n, 3, 3) float mm, with an optional lying count."""
    tris = np.asarray(triangles, dtype="<f4").reshape(-1, 3, 3)
    out = bytearray(80) + struct.pack("<I", len(tris) if count is None else count)
    for triangle in tris:
        out += struct.pack("<3f", 0.0, 0.0, 0.0) + triangle.tobytes() + b"\0\0"
    return bytes(out)


def stl_corpus() -> dict[str, tuple[bytes, str]]:
    """name -> (file content, words the failure reason must contain; ``|`` separates choices)."""
    tris = CUBE.triangles
    nan, inf = tris.copy(), tris.copy()
    nan[2, 1, 0] = np.nan
    inf[5, 0, 2] = np.inf
    square = [[[0, 0, 0], [10, 0, 0], [10, 10, 0]], [[0, 0, 0], [10, 10, 0], [0, 10, 0]]]
    return {
        "zero_bytes": (b"", "empty"),
        "blank": (b"   \n\n", "empty"),
        "truncated": (binary_stl(tris)[: 84 + 50 * 5 + 17], "truncated"),
        "count_too_high": (binary_stl(tris, count=500), "truncated"),
        "count_too_low": (binary_stl(tris, count=3), "not an STL|extra bytes|trailing"),
        "huge_count": (binary_stl(np.zeros((0, 3, 3)), count=4_000_000_000),
                       "truncated|not an STL"),
        "no_triangles": (binary_stl(np.zeros((0, 3, 3))), "not an STL"),
        "nan_vertex": (binary_stl(nan), "non-finite"),
        "inf_vertex": (binary_stl(inf), "non-finite"),
        "ascii_garbage": (b"solid x\n facet normal banana\n vertex 1 2\nendsolid\n",
                          "line 3 does not have three coordinates"),
        "ascii_empty": (b"solid empty\nendsolid empty\n", "no triangles"),
        "random_bytes": (np.random.default_rng(5).bytes(4096), "not an STL|truncated"),
        "html_page": (b"<!DOCTYPE html><html><body>404 Not Found</body></html>\n", "not an STL"),
        "utf16_text": ("solid x\nendsolid x\n".encode("utf-16"), "not an STL"),
        # two sides missing (+x and +y): a hole of six edges, more than a small hole
        "open_box": (binary_stl(CUBE.triangles[(CUBE.face_normals[:, :2] < 0.5).all(axis=1)]),
                     "not watertight"),
        "zero_volume": (binary_stl(np.array(square, dtype=float)), "zero volume"),
        "degenerate": (binary_stl(np.ones((12, 3, 3))), "degenerate"),
        "bigger_than_bed": (binary_stl(trimesh.creation.box((500, 20, 20)).triangles),
                            "bigger than the bed"),
        "thinner_than_a_layer": (binary_stl(trimesh.creation.box((5, 5, 0.05)).triangles),
                                 "closed outline"),
        "triangle_soup": ((DATA / "bad_triangle_soup.stl").read_bytes(), "not watertight"),
    }


def collect_failures(socket: Path, expected: int, out: list[dict], ready: threading.Event) -> None:
    async def run() -> None:
        async with ControlClient(str(socket)) as client:
            ready.set()
            async for item in client.subscribe():
                event = item.get("event")
                if event and event.get("event") == "failed":
                    out.append(event)
                    if len(out) >= expected:
                        return

    asyncio.run(asyncio.wait_for(run(), 90))


def test_malformed_corpus_fails_each_with_a_reason_and_the_next_job_prints(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.0, jobs_extra="max_bytes = 1_000_000"))
    jobs = hostd.jobs
    outside = tmp_path / "elsewhere.stl"
    outside.write_bytes((DATA / "cube20_xyz.stl").read_bytes())
    corpus = stl_corpus()
    folder_cases = {
        "directory": "is a directory",
        "escaping_link": "outside the job folder",
        "fifo": "not a regular file",
        "oversized": "over the limit",
        "bad_override_key": "infill.densty",
        "bad_override_value": "infill.density",
        "bad_override_syntax": "not valid TOML",
        "missing_field_file": "infill.file: no such file: nowhere.csv",
        "binary_gcode": "binary data",
        "comment_only_gcode": "no commands",
    }
    expected = len(corpus) + len(folder_cases)
    assert expected >= 20
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    failures: list[dict] = []
    ready = threading.Event()
    listener = threading.Thread(target=collect_failures,
                                args=(socket, expected, failures, ready), daemon=True)
    listener.start()
    assert ready.wait(10)

    names = list(corpus)
    for name in names[:10]:
        hostd.drop(corpus[name][0], f"{name}.stl")
    hostd.drop(DATA / "cube20_xyz.stl", "good.stl")  # prints in the middle of the bad ones
    for name in names[10:]:
        hostd.drop(corpus[name][0], f"{name}.stl")
    (jobs / "directory.stl").mkdir()
    os.symlink(outside, jobs / "escaping_link.stl")
    os.mkfifo(jobs / "fifo.stl")
    hostd.drop(b"solid x\n" + b" " * 1_000_001, "oversized.stl")
    for stem, text in (("bad_override_key", "infill.densty = 0.3\n"),
                       ("bad_override_value", "[infill]\ndensity = 7\n"),
                       ("bad_override_syntax", "nozzle_temp = = 3\n"),
                       ("missing_field_file",
                        '[infill]\nfield = "stress"\nfile = "nowhere.csv"\n')):
        hostd.drop(text.encode(), f"{stem}.toml")
        hostd.drop(DATA / "cube20_xyz.stl", f"{stem}.stl")
    hostd.drop(b"G28\nG1 X10\x00\x01\x02\nG1 Y5\n", "binary_gcode.gcode")
    hostd.drop(b"; only a comment\n\n", "comment_only_gcode.gcode")

    failed = jobs / "failed"
    hostd.wait_for(lambda: len(list(failed.glob("*.error.txt"))) >= expected, 90,
                   f"{expected} failures")
    hostd.wait_for(lambda: (jobs / "done" / "good.summary.txt").exists(), 60, "the good job")
    reasons = {p.name.removesuffix(".error.txt"): p.read_text() for p in failed.glob("*.error.txt")}
    assert len(reasons) == expected
    for name, (_data, words) in corpus.items():
        assert any(choice in reasons[name] for choice in words.split("|")), (name, reasons[name])
    for name, words in folder_cases.items():
        assert words in reasons[name], (name, reasons[name])
    assert outside.exists()
    assert (failed / "escaping_link.stl").is_symlink()

    listener.join(30)
    assert len(failures) == expected
    assert all(event["reason"] for event in failures)

    # only the good job reached the printer, whole and in order
    executed = executed_job_lines(hostd.state / "simulator-executed.log")
    assert executed == commands_of(jobs / "done" / "good.gcode")
    assert hostd.stop() == 0
