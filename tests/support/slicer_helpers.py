"""Helpers shared by the slicer tests: small generated STL files and G-code parsing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from slicer.output.annotate import is_annotation

DATA = Path(__file__).resolve().parents[1] / "data"


def write_mesh(mesh: trimesh.Trimesh, path: Path) -> Path:
    """Write ``mesh`` as a binary STL and return the path."""
    path.write_bytes(trimesh.exchange.stl.export_stl(mesh))
    return path


def box_stl(path: Path, extents=(20.0, 20.0, 10.0)) -> Path:
    """A closed box STL of the given extents, mm."""
    return write_mesh(trimesh.creation.box(extents=extents), path)


def layer_blocks(lines: list[str]) -> dict[int, list[str]]:
    """Split a whole program into its layers by ``;LAYER:N`` lines (up to ``;END``); the
    lines written for other hosts (M73, object labels) are left out."""
    blocks: dict[int, list[str]] = {}
    current: list[str] | None = None
    for line in lines:
        if line.startswith(";LAYER:"):
            current = blocks.setdefault(int(line[7:]), [])
        elif line.startswith(";END"):
            current = None
        if current is not None and not is_annotation(line):
            current.append(line)
    return blocks


def extrusions(lines: list[str], kind: str) -> list[np.ndarray]:
    """The polylines extruded under ``;TYPE:kind`` (each (k, 2) mm, starting at its travel end)."""
    paths: list[np.ndarray] = []
    current_kind = None
    pos = None
    run: list[tuple[float, float]] = []
    for line in lines:
        if line.startswith(";TYPE:"):
            current_kind = line[6:]
            continue
        words = line.split(";")[0].split()
        if not words or words[0] not in ("G0", "G1"):
            continue
        vals = {w[0]: float(w[1:]) for w in words[1:]}
        new = (vals.get("X", pos[0] if pos else 0.0), vals.get("Y", pos[1] if pos else 0.0))
        extruding = words[0] == "G1" and vals.get("E", 0.0) > 0 and ("X" in vals or "Y" in vals)
        if extruding and current_kind == kind:
            if not run:
                run = [pos]
            run.append(new)
        elif "X" in vals or "Y" in vals or words[0] == "G0":
            if run:
                paths.append(np.array(run))
            run = []
        pos = new
    if run:
        paths.append(np.array(run))
    return paths
