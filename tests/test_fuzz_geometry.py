"""Hypothesis fuzz of the geometry stages on tiny, random and degenerate clouds (issue 10).

Each stage either gives a result or raises the one exception its contract
names (GeometryError for a building that has no shape, InputError for a
cloud that is no LiDAR scene); anything else (QhullError, IndexError,
LinAlgError ...) is a bug that would abort a city-wide run.  Example counts
and sizes are small so the file runs in seconds.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rooftrace.cloud import PointCloud
from rooftrace.contour.alpha_shape import AlphaOptions, alpha_shape
from rooftrace.contour.outline import OutlineOptions, outline_buildings, outlines_layer, trace_outline
from rooftrace.errors import GeometryError, InputError
from rooftrace.roof import roof_structure

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
KINDS = ["uniform", "grid", "line", "identical", "two_clusters", "tiny", "duplicates", "vertical_wall"]


def _cloud(kind: str, n: int, seed: int, offset: float) -> np.ndarray:
    """A small cloud of a degenerate or ordinary kind, metres, shifted by ``offset`` (map-sized coordinates)."""
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        xyz = np.column_stack([rng.uniform(0, 8, (n, 2)), rng.uniform(5, 6, n)])
    elif kind == "grid":  # exact lattice: cocircular Delaunay quadruples
        k = max(1, int(np.sqrt(n)))
        g = np.mgrid[0:k, 0:k].reshape(2, -1).T * 0.5
        xyz = np.column_stack([g, np.full(len(g), 4.0)])
    elif kind == "line":
        t = rng.uniform(0, 10, n)
        xyz = np.column_stack([t, 0.3 * t + 1.0, rng.uniform(3, 4, n)])
    elif kind == "identical":
        xyz = np.tile([2.0, 3.0, 4.0], (n, 1))
    elif kind == "two_clusters":  # one building falling apart in two far pieces
        a = rng.uniform(0, 2, (n // 2 + 1, 2))
        b = rng.uniform(0, 2, (n - n // 2 - 1, 2)) + 30.0
        xy = np.concatenate([a, b])
        xyz = np.column_stack([xy, rng.uniform(5, 7, len(xy))])
    elif kind == "tiny":  # a building of a few millimetres
        xyz = np.column_stack([rng.uniform(0, 1e-3, (n, 2)), rng.uniform(5, 5.001, n)])
    elif kind == "duplicates":  # overlapping strips: every point twice
        base = np.column_stack([rng.uniform(0, 6, (max(1, n // 2), 2)), rng.uniform(5, 6, max(1, n // 2))])
        xyz = np.concatenate([base, base])
    else:  # vertical_wall: collinear in plan, spread in height
        t = rng.uniform(0, 5, n)
        xyz = np.column_stack([t, np.full(n, 2.0), rng.uniform(0, 8, n)])
    return xyz + [offset, offset, 0.0]


clouds = st.builds(_cloud, st.sampled_from(KINDS), st.integers(1, 60), st.integers(0, 10_000),
                   st.sampled_from([0.0, 85000.0]))


@SETTINGS
@given(clouds, st.sampled_from(["global", "building", "point"]))
def test_alpha_shape_gives_rings_or_geometry_error(xyz, strategy):
    try:
        shape = alpha_shape(xyz[:, :2], AlphaOptions(strategy=strategy), mean_spacing=0.5)
    except GeometryError:
        return
    assert shape.rings and all(len(r) >= 3 for r in shape.rings)


@SETTINGS
@given(clouds, st.sampled_from(["global", "building", "point"]))
def test_trace_outline_gives_a_valid_polygon_or_geometry_error(xyz, strategy):
    try:
        out = trace_outline(xyz, OutlineOptions.from_config({}, strategy=strategy), mean_spacing=0.5)
    except GeometryError as exc:
        assert str(exc)  # the message is the status written to roof_outlines
        return
    assert out.polygon is not None and out.polygon.is_valid and not out.polygon.is_empty
    assert shapely.has_z(out.polygon)
    assert np.isfinite(shapely.get_coordinates(out.polygon, include_z=True)).all()


@SETTINGS
@given(st.lists(clouds, min_size=1, max_size=4))
def test_outline_buildings_never_raises_and_gives_each_building_a_status(parts):
    xyz = np.concatenate(parts)
    ids = np.concatenate([np.full(len(p), i + 1) for i, p in enumerate(parts)])
    outlines = outline_buildings(xyz, ids, mean_spacing=0.5)
    assert [o.building_id for o in outlines] == list(range(1, len(parts) + 1))
    for o in outlines:
        assert o.status
        assert (o.polygon is None) == (o.status not in _WITH_POLYGON), (o.status, o.polygon)
    layer = outlines_layer(outlines)
    assert layer.attributes["status"] == [o.status for o in outlines]


_WITH_POLYGON = {"ok", "alpha_enlarged", "repaired", "multipart", "unregularised"}


def test_degenerate_buildings_get_a_status_saying_why():
    """One-point, two-point, identical and collinear buildings beside a good one (issue 10)."""
    rng = np.random.default_rng(3)
    good = np.column_stack([rng.uniform(0, 10, (300, 2)), np.full(300, 6.0)])
    one = np.array([[50.0, 50.0, 6.0]])
    two = np.array([[60.0, 60.0, 6.0], [61.0, 60.0, 6.0]])
    same = np.tile([70.0, 70.0, 6.0], (20, 1))
    line = np.column_stack([np.linspace(80, 90, 30), np.linspace(80, 85, 30), np.full(30, 6.0)])
    xyz = np.concatenate([good, one, two, same, line])
    ids = np.repeat([1, 2, 3, 4, 5], [len(good), 1, 2, len(same), len(line)])
    status = {o.building_id: o.status for o in outline_buildings(xyz, ids)}
    assert status[1] == "ok"
    assert status[2] == status[3] == status[4] == "too_few_points"
    assert status[5] == "collinear"


@SETTINGS
@given(clouds)
def test_roof_structure_never_raises_on_degenerate_roofs(xyz):
    try:
        roof = roof_structure(xyz, building_id=7)
    except GeometryError:
        return
    assert roof.building_id == 7 and roof.status
    assert len(roof.labels) == len(xyz)


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(clouds, st.integers(0, 3))
def test_detect_buildings_gives_classes_or_input_error(xyz, n_ground):
    from rooftrace.lidar.detect import detect_buildings

    rng = np.random.default_rng(n_ground)
    # some flat ground under the fuzzed points, or none at all
    ground = np.column_stack([rng.uniform(-5, 15, (40 * n_ground, 2)) + xyz[0, :2], np.zeros(40 * n_ground)])
    cloud = PointCloud(np.concatenate([xyz, ground]), sources=["fuzz.las"])
    try:
        det = detect_buildings(cloud)
    except InputError as exc:
        assert "fuzz.las" in str(exc)
        return
    assert len(det.classification) == len(cloud)
    assert set(np.unique(det.classification)) <= {1, 2, 5, 6, 7}
    assert (det.building_id[det.classification != 6] == 0).all()


@pytest.mark.parametrize("kind", KINDS)
def test_run_pipeline_never_aborts_on_a_degenerate_building(kind):
    """A degenerate object on a good scene: the run finishes, whatever the object is."""
    from rooftrace.pipeline import run_pipeline
    from tests.cli.badfiles import scene_xyz

    xyz = scene_xyz()
    extra = _cloud(kind, 30, 1, 0.0) + [xyz[:, 0].min() + 2.0, xyz[:, 1].min() + 2.0, 6.0]
    result = run_pipeline(PointCloud(np.concatenate([xyz, extra]), sources=["scene.las"]))
    assert len(result.layers["roof_outlines"]) == len(result.outlines) >= 1
    assert all(result.layers["roof_outlines"].attributes["status"])


def test_an_unexpected_stage_error_in_one_building_does_not_stop_the_others(monkeypatch):
    """Qhull or LAPACK failing on one building gives it status 'failed: ...'; the others are outlined."""
    from scipy.spatial import QhullError

    import rooftrace.contour.outline as outline_mod
    import rooftrace.roof as roof_mod
    from rooftrace.pipeline import run_pipeline
    from tests.cli.badfiles import scene_xyz

    real = outline_mod.trace_outline

    def flaky(xyz, *args, **kwargs):
        if xyz[:, 0].min() > 50:
            raise QhullError("QH6154 Qhull precision error: initial simplex is flat")
        return real(xyz, *args, **kwargs)

    monkeypatch.setattr(outline_mod, "trace_outline", flaky)
    rng = np.random.default_rng(2)
    a = np.column_stack([rng.uniform(0, 10, (300, 2)), np.full(300, 6.0)])
    b = a + [60.0, 0.0, 0.0]
    outlines = outline_buildings(np.concatenate([a, b]), np.repeat([1, 2], 300))
    assert [o.status for o in outlines] == ["ok", "failed: QhullError"]
    assert outlines[0].polygon is not None and outlines[1].polygon is None

    monkeypatch.setattr(outline_mod, "trace_outline", real)

    def broken(*args, **kwargs):
        raise RuntimeError("QH6271 qhull topology error")

    monkeypatch.setattr(roof_mod, "roof_structure", broken)
    result = run_pipeline(PointCloud(scene_xyz(), sources=["scene.las"]))
    assert [o.status for o in result.outlines] == ["ok"] and len(result.layers["ridges"]) == 0
