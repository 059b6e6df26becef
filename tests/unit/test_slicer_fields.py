"""Infill fields: paths stay inside the region, density means spacing, contours keep apart."""

from __future__ import annotations

from functools import reduce
from pathlib import Path

import meshio
import numpy as np
import pytest
import shapely
import trimesh
from scipy.spatial import cKDTree

from slicer.fields.base import FIELDS, LayerContext, get_field
from slicer.fields.draw import draw_field
from slicer.fields.stress_data import load_stress
from slicer.settings import SettingsError, SliceSettings

DATA = Path(__file__).resolve().parents[1] / "data"
CURVED_FIELDS = ("wave", "eggcrate", "concentric", "random", "poisson", "expression", "stress")
LENGTH_TOLERANCE = 0.12  # path length per area within 12 % of 1 / spacing


def layer_outline(mesh: trimesh.Trimesh, z: float) -> shapely.Geometry:
    """The mesh's cross-section at height ``z`` as polygons (even-odd nesting)."""
    segments, _, _ = trimesh.intersections.mesh_multiplane(mesh, [0, 0, 0], [0, 0, 1], [z])
    lines = shapely.linestrings(np.round(np.asarray(segments[0])[:, :, :2], 6))
    faces = shapely.get_parts(shapely.polygonize(lines))
    return reduce(shapely.symmetric_difference, faces, shapely.Polygon())


@pytest.fixture(scope="module")
def dogbone() -> shapely.Geometry:
    return layer_outline(trimesh.load(DATA / "dogbone_100x30x5.stl"), 2.5)


@pytest.fixture(scope="module")
def stress_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A stress-like field over a 100 x 40 x 5 mm box, peaking in the middle of x."""
    xs, ys, zs = np.meshgrid(
        np.linspace(0, 100, 26), np.linspace(0, 40, 9), np.linspace(0, 5, 2), indexing="ij"
    )
    value = 1.0 / (0.3 + (np.abs(xs - 50.0) / 30.0) ** 2)
    path = tmp_path_factory.mktemp("stress") / "stress.csv"
    table = np.column_stack((xs.ravel(), ys.ravel(), zs.ravel(), value.ravel()))
    np.savetxt(path, table, delimiter=",", header="x,y,z,von_mises")
    return path


def settings_for(name: str, density: float, stress_file: Path | None = None) -> SliceSettings:
    values: dict[str, object] = {"infill.field": name, "infill.density": density}
    if name == "expression":
        values["infill.expression"] = "sin(x / 4) * 3 + y + 0.3 * d"
    if name == "stress":
        values["infill.file"] = str(stress_file)
    return SliceSettings.from_mapping(values)


def layer(domain: shapely.Geometry, settings: SliceSettings, index: int = 3) -> LayerContext:
    return LayerContext(
        index=index, z=0.2 * (index + 1), domain=domain, bounds=domain.bounds, settings=settings
    )


def contracted(domain: shapely.Geometry, settings: SliceSettings) -> shapely.Geometry:
    """The region inside two walls, with the usual overlap."""
    w = settings.line_width
    return domain.buffer(-w * (settings.perimeters - settings.infill_overlap))


def closest_distinct(paths: shapely.Geometry, step: float, radius: float) -> int:
    """How many sample-point pairs on different paths lie within ``radius`` mm."""
    parts = shapely.get_parts(paths)
    coords, owner = shapely.get_coordinates(shapely.segmentize(parts, step), return_index=True)
    pairs = cKDTree(coords).query_pairs(radius, output_type="ndarray")
    return int(np.count_nonzero(owner[pairs[:, 0]] != owner[pairs[:, 1]]))


@pytest.mark.parametrize("density", [0.2, 0.4])
@pytest.mark.parametrize("shape", ["square", "dogbone"])
@pytest.mark.parametrize("name", CURVED_FIELDS)
def test_density_is_mean_spacing_and_contours_keep_a_line_width_apart(
    name: str, shape: str, density: float, dogbone: shapely.Geometry, stress_csv: Path
) -> None:
    domain = shapely.box(0, 0, 40, 40) if shape == "square" else dogbone
    settings = settings_for(name, density, stress_csv)
    region = contracted(domain, settings)
    spacing = settings.line_width / density
    paths = get_field(settings).paths(region, layer(domain, settings), spacing)

    assert not paths.is_empty
    assert region.buffer(1e-6).covers(paths)
    ratio = paths.length / region.area * spacing
    assert abs(ratio - 1.0) <= LENGTH_TOLERANCE, f"length per area x spacing = {ratio:.3f}"
    w = settings.line_width
    assert closest_distinct(paths, w / 5.0, 0.9 * w) == 0


@pytest.mark.parametrize("name", CURVED_FIELDS)
def test_paths_avoid_a_hole_and_never_cross_the_walls(name: str, stress_csv: Path) -> None:
    domain = shapely.box(0, 0, 40, 30).difference(shapely.Point(20, 15).buffer(6))
    settings = settings_for(name, 0.25, stress_csv)
    region = contracted(domain, settings)
    walls = shapely.boundary(domain.buffer(-0.5 * settings.line_width))
    paths = get_field(settings).paths(region, layer(domain, settings), settings.line_width / 0.25)

    assert not paths.is_empty
    assert region.buffer(1e-6).covers(paths)
    assert not paths.intersects(walls)
    assert paths.distance(shapely.Point(20, 15)) > 6.0 + settings.line_width


def test_wave_level_sets_are_the_arc_waves_of_the_field() -> None:
    domain = shapely.box(0, 0, 40, 40)
    settings = settings_for("wave", 0.2)
    ctx = layer(domain, settings, index=2)
    field = get_field(settings)
    paths = field.paths(contracted(domain, settings), ctx, settings.line_width / 0.2)
    dense = shapely.segmentize(shapely.get_parts(paths), 0.5)
    points, owner = shapely.get_coordinates(dense, return_index=True)
    values = field.sample(points[:, 0], points[:, 1], ctx)
    # each path is one level set: the field is constant along it (up to chord error)
    spread = np.array([np.ptp(values[owner == k]) for k in np.unique(owner)])
    assert spread.max() < 0.05  # mm, against 2.25 mm between levels


def test_concentric_paths_are_offsets_of_the_region() -> None:
    domain = shapely.box(0, 0, 30, 20)
    settings = settings_for("concentric", 0.3)
    region = contracted(domain, settings)
    spacing = settings.line_width / 0.3
    paths = get_field(settings).paths(region, layer(domain, settings), spacing)
    points = shapely.get_coordinates(paths)
    depth = shapely.distance(shapely.boundary(region), shapely.points(points))
    # every vertex sits half a spacing plus a whole number of spacings inside the region
    k = (depth - 0.5 * spacing) / spacing
    assert np.allclose(k, np.round(k), atol=0.02)


def test_random_points_depend_only_on_seed_and_layer() -> None:
    domain = shapely.box(0, 0, 40, 40)

    def run(seed: int, index: int) -> bytes:
        settings = SliceSettings.from_mapping({"infill.field": "random", "infill.seed": seed})
        region = contracted(domain, settings)
        paths = get_field(settings).paths(region, layer(domain, settings, index), 2.25)
        return shapely.to_wkb(paths)

    assert run(7, 4) == run(7, 4)
    assert run(7, 4) != run(7, 5)
    assert run(7, 4) != run(8, 4)


def test_poisson_field_is_zero_on_the_outline_and_peaks_inside() -> None:
    domain = shapely.box(0, 0, 20, 20)
    settings = settings_for("poisson", 0.2)
    ctx = layer(domain, settings)
    field = get_field(settings)
    centre = field.sample(np.array([10.0]), np.array([10.0]), ctx)[0]
    edge = field.sample(np.array([0.05, 10.0]), np.array([10.0, 19.95]), ctx)
    # -laplacian(H) = 1 on a square of side a peaks at about 0.0737 a^2
    assert centre == pytest.approx(0.0737 * 20**2, rel=0.05)
    assert np.all(np.abs(edge) < 0.05 * centre)


def test_eggcrate_samples_the_formula() -> None:
    domain = shapely.box(0, 0, 20, 20)
    settings = SliceSettings.from_mapping(
        {"infill.field": "eggcrate", "infill.angle": 0, "infill.scale": 12}
    )
    ctx = layer(domain, settings)
    x = np.array([10.0, 12.0, 14.0])
    y = np.array([10.0, 10.0, 13.0])
    a = np.pi / 12
    expected = np.sin(a * (x - 10)) ** 2 + np.sin(a * (y - 10)) ** 2
    assert np.allclose(get_field(settings).sample(x, y, ctx), expected)


def test_expression_field_uses_model_coordinates_and_wall_distance() -> None:
    domain = shapely.box(100, 50, 140, 80)
    settings = SliceSettings.from_mapping(
        {"infill.field": "expression", "infill.expression": "x + 10 * y + 100 * layer + d"}
    )
    ctx = layer(domain, settings, index=2)
    value = get_field(settings).sample(np.array([103.0]), np.array([60.0]), ctx)
    assert value[0] == pytest.approx(3.0 + 100.0 + 200.0 + 3.0, abs=0.01)


def test_a_bad_expression_is_refused_when_the_field_is_built() -> None:
    settings = SliceSettings.from_mapping(
        {"infill.field": "expression", "infill.expression": "__import__('os').system('x')"}
    )
    with pytest.raises(SettingsError) as err:
        get_field(settings)
    assert err.value.key == "infill.expression"


def test_stress_without_a_file_is_refused() -> None:
    with pytest.raises(SettingsError, match=r"infill\.file"):
        get_field(SliceSettings.from_mapping({"infill.field": "stress"}))


def linear_samples() -> tuple[np.ndarray, np.ndarray]:
    xs, ys, zs = np.meshgrid(
        np.linspace(0, 10, 6), np.linspace(0, 8, 5), np.linspace(0, 4, 3), indexing="ij"
    )
    points = np.column_stack((xs.ravel(), ys.ravel(), zs.ravel()))
    return points, 2.0 * points[:, 0] + 3.0 * points[:, 1] + 0.5 * points[:, 2] + 1.0


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".vtu"])
def test_stress_file_interpolates_known_points(tmp_path: Path, suffix: str) -> None:
    points, values = linear_samples()
    path = tmp_path / f"field{suffix}"
    if suffix == ".csv":
        np.savetxt(path, np.column_stack((points, values)), delimiter=",", header="x,y,z,value")
    elif suffix == ".npz":
        np.savez(path, points=points, values=values)
    else:
        cells = [("vertex", np.arange(len(points)).reshape(-1, 1))]
        meshio.write_points_cells(path, points, cells, point_data={"von_mises": values})
    data = load_stress(path)
    query = np.array([[1.3, 2.2, 0.7], [7.9, 5.5, 3.1], [5.0, 4.0, 2.0]])
    expected = 2.0 * query[:, 0] + 3.0 * query[:, 1] + 0.5 * query[:, 2] + 1.0
    for (x, y, z), want in zip(query, expected, strict=True):
        assert data.at(np.array([x]), np.array([y]), z)[0] == pytest.approx(want, abs=1e-6)
    # outside the samples' hull the nearest sample answers
    assert data.at(np.array([-5.0]), np.array([0.0]), 0.0)[0] == pytest.approx(1.0)


def test_stress_field_lines_up_the_file_with_the_placed_model(tmp_path: Path) -> None:
    points, values = linear_samples()
    path = tmp_path / "field.npz"
    np.savez(path, points=points, values=values)
    settings = SliceSettings.from_mapping(
        {"infill.field": "stress", "infill.file": str(path), "layer_height": 0.2}
    )
    domain = shapely.box(100, 50, 110, 58)  # the model, placed on the bed
    ctx = LayerContext(index=4, z=1.0, domain=domain, bounds=domain.bounds, settings=settings)
    field = get_field(settings)
    got = field.stress(np.array([103.0]), np.array([52.0]), ctx)[0]
    assert got == pytest.approx(2.0 * 3.0 + 3.0 * 2.0 + 0.5 * 0.9 + 1.0, abs=1e-6)


@pytest.mark.parametrize("problem", ["missing.csv", "field.txt", "bad.csv"])
def test_bad_stress_files_are_refused_with_the_key(tmp_path: Path, problem: str) -> None:
    path = tmp_path / problem
    if problem != "missing.csv":
        path.write_text("1,2\n3,4\n")
    with pytest.raises(SettingsError) as err:
        load_stress(path)
    assert err.value.key == "infill.file"


def test_stress_lines_crowd_where_the_stress_is_high(stress_csv: Path) -> None:
    domain = shapely.box(0, 0, 100, 40)
    settings = settings_for("stress", 0.2, stress_csv)
    region = contracted(domain, settings)
    paths = get_field(settings).paths(region, layer(domain, settings), settings.line_width / 0.2)
    middle = paths.intersection(shapely.box(40, 0, 60, 40)).length
    end = paths.intersection(shapely.box(0, 0, 20, 40)).length
    assert middle > 2.0 * end


def test_every_registered_field_is_available_by_name() -> None:
    import slicer.fields.library  # noqa: F401  (registers every built-in field)

    assert set(CURVED_FIELDS) | {"linear"} <= set(FIELDS)


def test_draw_field_writes_a_colour_map_with_level_sets(tmp_path: Path) -> None:
    from PIL import Image

    domain = shapely.box(0, 0, 40, 20)
    settings = settings_for("poisson", 0.2)
    ctx = layer(domain, settings)
    walls = domain.buffer(-0.5 * settings.line_width)
    out = draw_field(
        ctx, get_field(settings), contracted(domain, settings), walls, tmp_path / "f.png"
    )
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape[1] > image.shape[0] > 100
    body = image[image.shape[0] // 2, : image.shape[0]]
    assert len({tuple(p) for p in body}) > 20  # a colour ramp, not a flat fill
    assert np.any(np.all(image == 0, axis=2))  # black level sets drawn
    assert np.any(np.all(image == (220, 40, 40), axis=2))  # red walls drawn


def test_eggcrate_paths_stack_from_layer_to_layer_whatever_the_outline() -> None:
    settings = settings_for("eggcrate", 0.2)
    field = get_field(settings)
    bounds = (0.0, 0.0, 40.0, 40.0)
    big, small = (
        shapely.box(*bounds),
        shapely.box(5, 5, 35, 35).difference(shapely.Point(30, 30).buffer(3)),
    )
    spacing = settings.line_width / 0.2

    def paths(domain: shapely.Geometry, index: int) -> shapely.Geometry:
        ctx = LayerContext(
            index=index, z=0.2 * index, domain=domain, bounds=bounds, settings=settings
        )
        return field.paths(contracted(domain, settings), ctx, spacing)

    core = shapely.box(10, 10, 25, 25)  # away from both outlines
    lower, upper = paths(big, 3).intersection(core), paths(small, 4).intersection(core)
    assert lower.length > 50.0
    assert upper.length == pytest.approx(lower.length, rel=0.02)
    # the same curves (cuts where lines cross may end a grid node apart)
    assert upper.difference(lower.buffer(0.02)).length < 0.01 * lower.length


def test_scattered_stress_samples_interpolate_linearly_inside_their_hull(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    corners = np.array([[x, y, z] for x in (0, 10) for y in (0, 8) for z in (0, 4)], float)
    points = np.vstack((corners, rng.uniform((0, 0, 0), (10, 8, 4), size=(200, 3))))
    values = 2.0 * points[:, 0] - points[:, 1] + 3.0 * points[:, 2]
    path = tmp_path / "scattered.csv"
    np.savetxt(path, np.column_stack((points, values)), delimiter=",")
    data = load_stress(path)
    x, y = np.array([2.5, 7.1, 9.0]), np.array([1.0, 6.6, 4.0])
    assert np.allclose(data.at(x, y, 1.5), 2.0 * x - y + 4.5, atol=1e-6)
