"""STL files for the benchmarks: binary and ASCII writers, and the 3.03M-triangle memory case."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.peers import CACHE

Mesh = tuple[np.ndarray, np.ndarray]  # vertices (v, 3) float64 mm, faces (f, 3) int64


def write_binary(path: Path, mesh: Mesh) -> None:
    """Binary STL of (vertices, faces); normals from the corners."""
    v, f = mesh
    tri = v[f].astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    rec = np.zeros(len(f), dtype=[("n", "<f4", (3,)), ("c", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"], rec["c"] = n, tri
    with open(path, "wb") as fh:
        fh.write(b"hostd corpus".ljust(80, b" "))
        fh.write(np.uint32(len(f)).tobytes())
        fh.write(rec.tobytes())


def write_ascii(path: Path, mesh: Mesh, endsolid: bool = True) -> None:
    """ASCII STL of (vertices, faces), optionally without its closing ``endsolid``."""
    v, f = mesh
    lines = ["solid corpus"]
    for tri in v[f]:
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += [f"      vertex {x:.6f} {y:.6f} {z:.6f}" for x, y, z in tri]
        lines += ["    endloop", "  endfacet"]
    if endsolid:
        lines.append("endsolid corpus")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def large_sphere(faces: int = 3_030_000) -> Mesh:
    """An 80 mm UV sphere of about ``faces`` triangles (the memory case: ~151.6 MB as STL)."""
    rings = int(np.sqrt(faces / 4.0))
    seg = faces // (2 * (rings - 1))
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.arange(seg) * (2 * np.pi / seg)
    r = 40.0
    ring_pts = np.stack([
        (r * np.sin(theta)[:, None] * np.cos(phi)[None, :]).ravel(),
        (r * np.sin(theta)[:, None] * np.sin(phi)[None, :]).ravel(),
        np.repeat(r * np.cos(theta), seg)], axis=1)
    v = np.concatenate([[[0, 0, r]], ring_pts, [[0, 0, -r]]])
    idx = 1 + np.arange((rings - 1) * seg).reshape(rings - 1, seg)
    nxt = np.roll(idx, -1, axis=1)
    top = np.stack([np.zeros(seg, np.int64), idx[0], nxt[0]], axis=1)
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    quads = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                            np.stack([b, c, d], -1).reshape(-1, 3)])
    bottom = np.stack([np.full(seg, len(v) - 1), nxt[-1], idx[-1]], axis=1)
    return v + np.array([0.0, 0.0, r]), np.concatenate([top, quads, bottom]).astype(np.int64)


def large_model(out: Path = CACHE) -> Path:
    """The memory case written once into the cache (never committed): its path."""
    path = out / "large_sphere_3m.stl"
    if not path.exists():
        out.mkdir(parents=True, exist_ok=True)
        write_binary(path.with_suffix(".tmp"), large_sphere())
        path.with_suffix(".tmp").replace(path)
    return path
