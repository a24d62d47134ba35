"""Metrics on hand-computable polygons, and against an independent shapely computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from shapely import Polygon, box
from shapely.affinity import translate

from rooftrace.evaluate.geometry import closest_on_segments
from rooftrace.evaluate.metrics import (
    area_scores,
    hausdorff,
    polis,
    ridge_scores,
    ring_segments,
    ring_vertices,
    rmse_xyz,
    vertex_residuals,
)


def _setz(geom, z):
    parts = []
    for p in shapely.get_parts(geom):
        ext = np.asarray(p.exterior.coords)[:, :2]
        holes = [np.asarray(h.coords)[:, :2] for h in p.interiors]
        parts.append(Polygon(np.c_[ext, z(ext[:, 0], ext[:, 1])],
                             [np.c_[h, z(h[:, 0], h[:, 1])] for h in holes]))
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def _polis_bruteforce(a, b):
    """Eq. 3.15 one vertex at a time with shapely's distance (the independent oracle)."""
    def directed(p, q):
        d = []
        for part in shapely.get_parts(p):
            for ring in [part.exterior, *part.interiors]:
                for xy in list(ring.coords)[:-1]:
                    d.append(shapely.Point(xy[:2]).distance(q.boundary))
        return sum(d) / len(d)
    return 0.5 * directed(a, b) + 0.5 * directed(b, a)


def _random_polygon(rng, centre=(0.0, 0.0), n=12):
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = rng.uniform(4, 10, n)
    return Polygon(np.c_[centre[0] + rad * np.cos(ang), centre[1] + rad * np.sin(ang)])


def test_identical_squares_are_perfect():
    a = box(0, 0, 10, 10)
    s = area_scores(a, a)
    assert (s["completeness"], s["correctness"], s["f_score"], s["quality"]) == (1.0, 1.0, 1.0, 1.0)
    assert polis(a, a) == 0.0 and hausdorff(a, a) == 0.0
    assert rmse_xyz(a, a)[:2] == (0.0, 0.0)
    az = _setz(a, lambda x, y: 5 + 0.1 * x)
    assert polis(az, az, dim=3) == 0.0
    assert rmse_xyz(az, az) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("s,d", [(10.0, 2.0), (7.5, 0.3), (3.0, 2.9)])
@pytest.mark.parametrize("axis", [0, 1])
def test_shifted_square(s, d, axis):
    a = box(0, 0, s, s)
    b = shapely.affinity.translate(a, *(d, 0) if axis == 0 else (0, d))
    assert polis(a, b) == pytest.approx(d / 2, abs=1e-12)
    assert polis(b, a) == pytest.approx(d / 2, abs=1e-12)
    assert hausdorff(a, b) == pytest.approx(d, abs=1e-12)
    sc = area_scores(b, a)
    assert sc["completeness"] == pytest.approx((s - d) / s, abs=1e-12)
    assert sc["correctness"] == pytest.approx((s - d) / s, abs=1e-12)
    assert sc["quality"] == pytest.approx((s - d) / (s + d), abs=1e-12)
    assert sc["f_score"] == pytest.approx((s - d) / s, abs=1e-12)
    # two of the four reference vertices are d off along the axis, the others lie on the outline
    r = rmse_xyz(a, b)
    assert r[axis] == pytest.approx(d / math.sqrt(2), abs=1e-12)
    assert r[1 - axis] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(r[2])


def test_polygon_with_hole():
    outer = [(0, 0), (10, 0), (10, 10), (0, 10)]
    ref = Polygon(outer, [[(4, 4), (6, 4), (6, 6), (4, 6)]])
    ext = Polygon(outer, [[(5, 4), (7, 4), (7, 6), (5, 6)]])
    # hole vertices (4,4) and (4,6) are 1 m off, the other six of eight vertices lie on the boundary
    assert polis(ref, ext) == pytest.approx(0.25, abs=1e-12)
    assert hausdorff(ref, ext) == pytest.approx(1.0, abs=1e-12)
    sc = area_scores(ext, ref)
    assert sc["tp"] == pytest.approx(94.0) and sc["completeness"] == pytest.approx(94 / 96)
    assert sc["quality"] == pytest.approx(94 / 98)
    assert len(ring_vertices(ref)) == 8


def test_no_overlap():
    a, b = box(0, 0, 1, 1), box(3, 0, 4, 1)
    sc = area_scores(a, b)
    assert (sc["completeness"], sc["correctness"], sc["f_score"], sc["quality"]) == (0.0, 0.0, 0.0, 0.0)
    assert sc["fn"] == 1.0 and sc["fp"] == 1.0
    assert polis(a, b) == pytest.approx(_polis_bruteforce(a, b), abs=1e-12)
    assert hausdorff(a, b) == pytest.approx(3.0)


def test_empty_inputs():
    a = box(0, 0, 1, 1)
    for empty in (None, Polygon(), []):
        assert math.isnan(polis(a, empty)) and math.isnan(hausdorff(empty, a))
        assert all(math.isnan(v) for v in rmse_xyz(empty, a))
        s = area_scores(empty, a)  # nothing extracted
        assert s["completeness"] == 0.0 and math.isnan(s["correctness"])
        assert s["f_score"] == 0.0 and s["quality"] == 0.0
        s = area_scores(a, empty)  # nothing to find
        assert math.isnan(s["completeness"]) and s["correctness"] == 0.0
        s = area_scores(empty, empty)
        assert all(math.isnan(s[k]) for k in ("completeness", "correctness", "f_score", "quality"))
    assert vertex_residuals(None, a).shape == (0, 3)


def test_lists_are_unioned():
    parts = [box(0, 0, 5, 10), box(5, 0, 10, 10)]
    s = area_scores(parts, box(0, 0, 10, 10))
    assert s["completeness"] == pytest.approx(1.0) and s["correctness"] == pytest.approx(1.0)


def test_against_independent_computation(rng):
    for _ in range(20):
        a = _random_polygon(rng)
        b = _random_polygon(rng, centre=rng.uniform(-3, 3, 2))
        assert polis(a, b) == pytest.approx(_polis_bruteforce(a, b), abs=1e-9)
        inter = a.intersection(b).area
        s = area_scores(a, b)
        assert s["completeness"] == pytest.approx(inter / b.area, abs=1e-9)
        assert s["correctness"] == pytest.approx(inter / a.area, abs=1e-9)
        assert s["quality"] == pytest.approx(inter / a.union(b).area, abs=1e-9)
        # closest points of the residuals lie on the boundary at the shapely distance
        res = vertex_residuals(b, a)
        verts = ring_vertices(b)
        d = shapely.distance(shapely.points(verts[:, :2]), a.boundary)
        np.testing.assert_allclose(np.hypot(res[:, 0], res[:, 1]), d, atol=1e-9)
        # 3D PoLiS on flat polygons equals 2D PoLiS
        a3, b3 = _setz(a, lambda x, y: 0 * x), _setz(b, lambda x, y: 0 * x)
        assert polis(a3, b3, dim=3) == pytest.approx(polis(a, b), abs=1e-9)


def test_invariant_to_start_vertex_and_orientation(rng):
    a, b = _random_polygon(rng), _random_polygon(rng, centre=(1.0, 0.5))
    coords = np.asarray(a.exterior.coords)[:-1]
    rolled = Polygon(np.roll(coords, 5, axis=0)[::-1])
    assert polis(rolled, b) == pytest.approx(polis(a, b), abs=1e-12)
    assert hausdorff(rolled, b) == pytest.approx(hausdorff(a, b), abs=1e-12)


def test_3d_distances():
    a = box(0, 0, 10, 10)
    flat = _setz(a, lambda x, y: 0 * x + 3.0)
    lifted = _setz(a, lambda x, y: 0 * x + 3.5)
    assert polis(flat, lifted, dim=3) == pytest.approx(0.5, abs=1e-12)
    assert polis(flat, lifted, dim=2) == 0.0
    assert rmse_xyz(flat, lifted) == pytest.approx((0.0, 0.0, 0.5), abs=1e-12)
    # a reference vertex mid-side: z interpolated along the extracted segment
    ref = Polygon([(0, 0, 0), (5, 0, 1), (10, 0, 0), (10, 10, 0), (0, 10, 0)])
    ext = Polygon([(0, 0, 0), (10, 0, 4), (10, 10, 0), (0, 10, 0)])
    res = vertex_residuals(ref, ext)
    assert res[1].tolist() == pytest.approx([0.0, 0.0, 2.0 - 1.0])
    # 3D: the raised mid-side vertex is 1 m above the flat outline, the other vertices lie on it
    flat_ext = _setz(box(0, 0, 10, 10), lambda x, y: 0 * x)
    assert polis(ref, flat_ext, dim=3) == pytest.approx(0.5 * 1.0 / 5, abs=1e-12)
    assert polis(ref, flat_ext, dim=2) == 0.0
    with pytest.raises(ValueError, match="z coordinates"):
        polis(a, flat, dim=3)
    with pytest.raises(ValueError, match="dim"):
        polis(a, a, dim=4)
    with pytest.raises(TypeError, match="Polygon"):
        polis(shapely.LineString([(0, 0), (1, 1)]), a)


# an annex (eave z = 3) meets the main roof (z = 8) at x = 4: a vertical step
_STEP = [(0, 0, 3), (4, 0, 3), (4, 0, 8), (10, 0, 8), (10, 5, 8), (4, 5, 8), (4, 5, 3), (0, 5, 3)]


def _first_segment_residuals(ref, ext):
    """The choice before the step rule: z on the first plan-closest segment."""
    verts = ring_vertices(ref)
    return closest_on_segments(verts, *ring_segments(ext), 2) - verts


def test_vertical_step_takes_the_height_of_its_own_side():
    ref = ext = Polygon(_STEP)
    # the main-roof corner (4, 0, 8) and the annex corner (4, 5, 3) meet the other side's segment first
    old = _first_segment_residuals(ref, ext)
    np.testing.assert_array_equal(old[:, 2], [0, 0, -5, 0, 0, 0, 5, 0])
    res = vertex_residuals(ref, ext)
    np.testing.assert_array_equal(res, np.zeros((8, 3)))
    assert rmse_xyz(ref, ext) == (0.0, 0.0, 0.0)
    # the extracted outline 0.3 m off across the step and 0.1 m higher: each side keeps its own height
    moved = Polygon([(x, y + 0.3, z + 0.1) for x, y, z in _STEP])
    res = vertex_residuals(ref, moved)
    np.testing.assert_array_equal(res[:, :2], _first_segment_residuals(ref, moved)[:, :2])
    np.testing.assert_allclose(res[:, 2], 0.1, atol=1e-12)
    # off along the side instead, the step is 0.3 m from the corner in plan, no tie: the annex decides
    along = Polygon([(x + 0.3, y, z) for x, y, z in _STEP])
    np.testing.assert_array_equal(vertex_residuals(ref, along), _first_segment_residuals(ref, along))
    assert vertex_residuals(ref, along)[2, 2] == pytest.approx(-5.0)


def test_near_vertical_step_within_the_tolerance():
    ref = Polygon(_STEP)
    # the step's two vertices written 3 mm apart in plan
    ext = Polygon([(x + 0.003 if (x, z) == (4, 8) else x, y, z) for x, y, z in _STEP])
    res = vertex_residuals(ref, ext)
    np.testing.assert_array_equal(res[:, :2], _first_segment_residuals(ref, ext)[:, :2])
    assert np.abs(res[:, 2]).max() < 0.01
    # beyond the tolerance the plan-closest point decides alone, as before
    np.testing.assert_array_equal(vertex_residuals(ref, ext, step_tolerance=0.001),
                                  _first_segment_residuals(ref, ext))


def test_ring_without_steps_is_unchanged(rng):
    slope = lambda x, y: 5 + 0.3 * x - 0.2 * y + 0.1 * np.sin(x)  # noqa: E731
    for _ in range(20):
        ref = _setz(_random_polygon(rng), slope)
        ext = _setz(_random_polygon(rng, centre=rng.uniform(-1, 1, 2)), lambda x, y: slope(x, y) + 0.05)
        np.testing.assert_array_equal(vertex_residuals(ref, ext), _first_segment_residuals(ref, ext))
    box_z = _setz(box(0, 0, 10, 10), lambda x, y: 3 + 0.1 * x)
    shifted = _setz(box(0.4, 0.2, 10.4, 10.2), lambda x, y: 3 + 0.1 * x)
    np.testing.assert_array_equal(vertex_residuals(box_z, shifted), _first_segment_residuals(box_z, shifted))


def test_step_tolerance_is_checked():
    a = box(0, 0, 1, 1)
    with pytest.raises(ValueError, match="step_tolerance"):
        vertex_residuals(a, a, step_tolerance=-0.01)
    with pytest.raises(TypeError, match="step_tolerance"):
        rmse_xyz(a, a, step_tolerance="5 mm")


def test_multipolygon_vertices_and_distances():
    a = shapely.MultiPolygon([box(0, 0, 2, 2), box(5, 0, 7, 2)])
    b = shapely.MultiPolygon([box(0, 0, 2, 2), box(6, 0, 8, 2)])
    # only the second part differs: 2 of 8 vertices 1 m away each direction
    assert polis(a, b) == pytest.approx(0.25, abs=1e-12)
    assert polis(a, b) == pytest.approx(_polis_bruteforce(a, b), abs=1e-12)


def test_ridge_scores():
    ref = [shapely.LineString([(0, 0, 5), (10, 0, 5)])]
    ext = [shapely.LineString([(0, 0.2, 5), (10, 0.2, 5)])]
    r = ridge_scores(ext, ref, buffer=0.5)
    assert r["ridge_completeness"] == pytest.approx(1.0) and r["ridge_correctness"] == pytest.approx(1.0)
    assert r["ridge_position_error"] == pytest.approx(0.2, abs=1e-12)
    assert (r["n_ridges_reference"], r["n_ridges_extracted"]) == (1, 1)
    # half overlapping: reference covered from x = 4.5 (the buffer cap) to 10
    r = ridge_scores([shapely.LineString([(5, 0), (15, 0)])], ref, buffer=0.5)
    assert r["ridge_completeness"] == pytest.approx(0.55, abs=1e-9)
    assert r["ridge_correctness"] == pytest.approx(0.55, abs=1e-9)
    r = ridge_scores([shapely.LineString([(0, 3), (10, 3)])], ref, buffer=0.5)
    assert r["ridge_completeness"] == 0.0 and math.isnan(r["ridge_position_error"])
    r = ridge_scores(None, ref)
    assert r["ridge_completeness"] == 0.0 and math.isnan(r["ridge_correctness"])
    with pytest.raises(ValueError, match="buffer"):
        ridge_scores(ext, ref, buffer=0)


_SEEN: list = []


def test_properties_hold_for_random_polygons():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    coords = st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=3, max_size=12)

    @settings(max_examples=60, deadline=None, derandomize=True)
    @given(coords, coords, st.floats(-100, 100), st.floats(-100, 100))
    def check(ca, cb, dx, dy):
        a, b = shapely.convex_hull(shapely.MultiPoint(ca)), shapely.convex_hull(shapely.MultiPoint(cb))
        if not (isinstance(a, Polygon) and isinstance(b, Polygon)) or a.area < 1e-3 or b.area < 1e-3:
            return
        p = polis(a, b)
        _SEEN.append(p)
        assert p == pytest.approx(polis(b, a), abs=1e-9)  # symmetric
        assert 0.0 <= p <= hausdorff(a, b) + 1e-9  # a mean of vertex distances never exceeds their maximum
        moved = polis(translate(a, dx, dy), translate(b, dx, dy))
        assert moved == pytest.approx(p, abs=1e-6 * (1 + abs(dx) + abs(dy)))
        s = area_scores(a, b)
        for key in ("completeness", "correctness", "f_score", "quality"):
            assert -1e-12 <= s[key] <= 1 + 1e-12
        assert s["quality"] <= s["f_score"] + 1e-12
        assert min(s["completeness"], s["correctness"]) - 1e-12 <= s["f_score"]
        assert s["f_score"] <= max(s["completeness"], s["correctness"]) + 1e-12

    _SEEN.clear()
    check()
    assert len(_SEEN) >= 30  # most examples are real polygons, not skipped
