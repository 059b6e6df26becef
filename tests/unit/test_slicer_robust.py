"""No internal error on any input: meshes of every broken kind thrown at the slicer.

Each case either slices (every layer's G-code made) or is refused with a
:class:`~slicer.errors.ModelError` of one line; any other exception is a defect.
The number of examples per property is small in the suite (a few seconds each);
``--hypothesis-profile long`` (registered in ``conftest.py``) runs many more.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import trimesh
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from slicer.errors import ModelError
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

BED = (200.0, 200.0, 200.0)
# the suite's examples per property; the long profile sets its own count
LONG = settings().max_examples > 100
EXAMPLES = settings().max_examples if LONG else 12
SETTINGS = SliceSettings()
ROBUST = settings(max_examples=EXAMPLES, deadline=None, derandomize=not LONG,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

_BASES = {
    "box": trimesh.creation.box((6.0, 4.0, 2.0)),
    "sphere": trimesh.creation.icosphere(1, radius=2.5),
    "cylinder": trimesh.creation.cylinder(radius=2.0, height=2.0, sections=12),
}


def write_stl(path: str, triangles: np.ndarray) -> None:
    """``triangles`` (n, 3, 3) mm as a binary STL."""
    tri = np.asarray(triangles, dtype="<f4").reshape(-1, 3, 3)
    rec = np.zeros(len(tri), dtype=[("n", "<f4", (3,)), ("c", "<f4", (3, 3)), ("a", "<u2")])
    rec["c"] = tri
    with open(path, "wb") as fh:
        fh.write(b"\0" * 80 + np.uint32(len(tri)).tobytes() + rec.tobytes())


def slices_or_refuses(triangles: np.ndarray) -> None:
    """Slice ``triangles`` from a file, every layer; only a one-line ModelError may stop it."""
    fd, path = tempfile.mkstemp(suffix=".stl")
    os.close(fd)
    try:
        write_stl(path, triangles)
        try:
            plan = SlicePlan.from_file(path, SETTINGS, BED)
            for i in range(plan.layer_count):
                plan.layer_gcode(i)
            plan.warnings  # noqa: B018 - the whole-model repairs are summed here
            event("sliced")
        except ModelError as err:
            text = str(err)
            assert text, "a refusal without a reason"
            assert "\n" not in text, text
            event("refused: " + text.split(":")[0])
    finally:
        os.unlink(path)


coordinate = st.floats(-8.0, 8.0, allow_nan=False, width=32)


@st.composite
def soups(draw) -> np.ndarray:
    """Random triangles, some sharing corners, some degenerate."""
    n = draw(st.integers(1, 40))
    corners = np.array(draw(st.lists(st.tuples(coordinate, coordinate, coordinate),
                                     min_size=3, max_size=30)))
    picks = draw(st.lists(st.integers(0, len(corners) - 1), min_size=3 * n, max_size=3 * n))
    return corners[np.array(picks)].reshape(n, 3, 3)


@st.composite
def damaged(draw) -> np.ndarray:
    """A closed solid with damage: faces dropped, doubled, reversed, corners moved a
    little or far, slivers and zero-area triangles added, a second copy touching or
    crossing it, scaled huge or tiny."""
    base = _BASES[draw(st.sampled_from(sorted(_BASES)))]
    tri = np.array(base.triangles, dtype=np.float64)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = len(tri)
    kinds = draw(st.sets(st.sampled_from(
        ["drop", "double", "reverse", "jitter", "spike", "sliver", "zero_area", "reversed_copy",
         "touch_edge", "touch_point", "cross", "scale"]), min_size=1, max_size=4))
    parts = [tri]
    if "drop" in kinds:
        parts[0] = tri = tri[rng.random(n) > draw(st.floats(0.01, 0.5))]
    if "double" in kinds and len(tri):
        parts.append(tri[rng.random(len(tri)) < 0.3])
    if "reverse" in kinds and len(tri):
        flip = rng.random(len(tri)) < draw(st.floats(0.05, 0.6))
        tri[flip] = tri[flip][:, ::-1]
    if "jitter" in kinds:
        tri += rng.normal(0.0, draw(st.sampled_from([1e-6, 1e-4, 1e-2])), tri.shape)
    if "spike" in kinds and len(tri):
        tri[rng.integers(len(tri)), rng.integers(3)] += rng.normal(0.0, 3.0, 3)
    if "sliver" in kinds:
        a = rng.uniform(-3, 3, 3)
        parts.append(np.array([[a, a + np.array([5.0, 0, 2.0]), a + np.array([5.0, 1e-4, 2.0])]]))
    if "zero_area" in kinds:
        a = rng.uniform(-3, 3, 3)
        parts.append(np.array([[a, a + 1.0, a + 2.0]]))
    if "reversed_copy" in kinds:
        parts.append(tri[:, ::-1].copy())
    span = np.ptp(tri.reshape(-1, 3), axis=0) if len(tri) else np.ones(3)
    if "touch_edge" in kinds:
        parts.append(tri + np.array([span[0], 0.0, 0.0]))
    if "touch_point" in kinds:
        parts.append(tri + span)
    if "cross" in kinds:
        angle = draw(st.floats(0.1, 1.5))
        c, s = np.cos(angle), np.sin(angle)
        parts.append(tri @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]).T + [0.5, 0.3, 0.2])
    out = np.concatenate(parts)
    if "scale" in kinds:
        out = out * draw(st.sampled_from([1e-4, 1e-2, 30.0, 1e4]))
    return out


@ROBUST
@given(soups())
def test_random_soups_slice_or_are_refused(triangles):
    slices_or_refuses(triangles)


@ROBUST
@given(damaged())
def test_damaged_solids_slice_or_are_refused(triangles):
    slices_or_refuses(triangles)


@ROBUST
@given(st.sampled_from(sorted(_BASES)), st.floats(-1e6, 1e6, allow_nan=False),
       st.sampled_from([1e-6, 1e-3, 1.0, 60.0]))
def test_far_away_huge_and_tiny_solids(name, offset, scale):
    slices_or_refuses(np.array(_BASES[name].triangles) * scale + offset)
