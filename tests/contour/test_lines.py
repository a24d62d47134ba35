"""Building shapes by model selection (contour.lines) and the edge between roof and non-roof points (contour.edge)."""

import numpy as np
import pytest
import shapely
import shapely.affinity

from rooftrace.contour.alpha_shape import AlphaOptions, alpha_shape
from rooftrace.contour.edge import EdgeContext, edge_shift
from rooftrace.contour.lines import (
    Line,
    _turning_runs,
    boundary_step,
    bridge_inlets,
    chord_curve,
    constrain_directions,
    curved_runs,
    fit_line,
    line_corners,
    segment_bic,
    simplify_lines,
)
from rooftrace.contour.outline import OutlineOptions, trace_outline
from rooftrace.evaluate.metrics import polis
from tests.contour.shapes import CIRCLE, COURTYARD, L_SHAPE, RECT, sample

U_SHAPE = shapely.Polygon([(0, 0), (20, 0), (20, 14), (14, 14), (14, 5), (6, 5), (6, 14), (0, 14)])
#: a hall with a gently curved front: an arc of radius 30 m rising 1.7 m over its 20 m chord
ARC = shapely.Point(10, -20).buffer(30, quad_segs=512).intersection(shapely.box(0, 0, 20, 12))


def scene(polygon, density=10.0, seed=0, jitter=0.25, margin=4.0):
    """Jittered-grid points over the polygon and a margin around it: (roof xyz, the others' xy)."""
    rng = np.random.default_rng(seed)
    s = 1 / np.sqrt(density)
    x0, y0, x1, y1 = polygon.bounds
    g = np.mgrid[x0 - margin:x1 + margin:s, y0 - margin:y1 + margin:s].reshape(2, -1).T + rng.uniform(0, s, (1, 2))
    g = g + rng.uniform(-jitter * s, jitter * s, g.shape)
    inside = shapely.contains_xy(polygon, g[:, 0], g[:, 1])
    roof = np.column_stack([g[inside], 10 + 0.05 * rng.normal(size=inside.sum())])
    return roof, g[~inside]


def plan_corners(polygon):
    simple = shapely.simplify(shapely.force_2d(polygon), 0.02)
    return sum(len(r.coords) - 1 for r in (simple.exterior, *simple.interiors))


@pytest.mark.parametrize("truth, corners", [(RECT, 4), (L_SHAPE, 6), (U_SHAPE, 8), (COURTYARD, 8)])
@pytest.mark.parametrize("angle", [0.0, 17.0])
def test_straight_walled_shapes_get_their_corners_and_straight_walls(truth, corners, angle):
    truth = shapely.affinity.rotate(truth, angle, origin=(0, 0))
    for seed in range(2):
        roof, others = scene(truth, seed=seed)
        out = trace_outline(roof, context_xy=others)
        assert plan_corners(out.polygon) == corners
        assert all(d == 1 for ring in out.degrees for d in ring)
        assert polis(out.polygon, truth) < 0.08
        # corners where the walls meet, not on points: each within a fraction of a spacing of the truth
        for ring, true_ring in zip((out.polygon.exterior, *out.polygon.interiors),
                                   (truth.exterior, *truth.interiors)):
            c = np.asarray(shapely.simplify(ring, 0.02).coords)[:-1, :2]
            t = np.asarray(true_ring.coords)[:-1]
            assert np.linalg.norm(c[:, None] - t[None], axis=2).min(axis=1).max() < 0.3  # a spacing


def test_lines_beat_the_thesis_cdspline_on_a_noisy_rotated_rectangle():
    truth = shapely.affinity.rotate(RECT, 33, origin=(0, 0))
    roof, others = scene(truth, density=6.0, seed=4, jitter=0.45)
    lines = trace_outline(roof, context_xy=others)
    spline = trace_outline(roof, OutlineOptions.from_config({}, method="cdspline"))
    assert plan_corners(lines.polygon) == 4 <= plan_corners(spline.polygon)
    assert polis(lines.polygon, truth) < polis(spline.polygon, truth)


@pytest.mark.parametrize("truth", [CIRCLE, ARC])
def test_curved_walls_stay_curved(truth):
    for seed in range(2):
        out = trace_outline(sample(truth, 10, seed=seed))
        degrees = np.asarray(out.degrees[0])
        # the arcs are made of segments of degree >= 2, the straight walls of lines
        assert (degrees >= 2).sum() >= (3 if truth is CIRCLE else 1)
        assert polis(out.polygon, truth) < 0.1


def test_the_edge_lies_between_the_last_roof_point_and_the_first_other_point():
    truth = shapely.box(0, 0, 20, 12)
    errors_ctx, errors_none = [], []
    for seed in range(4):
        roof, others = scene(truth, density=4.0, seed=seed, jitter=0.0)  # a grid: the edge falls anywhere between
        with_ctx = trace_outline(roof, context_xy=others).polygon
        without = trace_outline(roof, OutlineOptions.from_config({}, edge_factor=0.0)).polygon
        errors_ctx.append(with_ctx.area - truth.area)
        errors_none.append(without.area - truth.area)
    # through the outermost points the outline lies inside (area short by ~ perimeter x half a spacing);
    # between it and at most one step beyond (or the first outside point) it is unbiased
    perimeter_x_half_gap = truth.length * 0.5 / np.sqrt(4.0)
    assert np.mean(errors_none) < -0.6 * perimeter_x_half_gap
    assert abs(np.mean(errors_ctx)) < 0.25 * perimeter_x_half_gap


def test_the_edge_does_not_follow_the_ground_into_a_wall_s_scan_shadow():
    truth = shapely.box(0, 0, 20, 12)
    errors = []
    for seed in range(4):
        roof, others = scene(truth, density=4.0, seed=seed, jitter=0.0)
        # no ground returns within 1 m of the south wall: the first non-roof point there is 1-1.5 m out
        shadow = (others[:, 1] < 0) & (others[:, 1] > -1.0)
        south = trace_outline(roof, context_xy=others[~shadow]).polygon
        errors.append(-south.bounds[1])  # how far the south wall lies beyond the true one, metres
    # the outermost roof points lie 0-0.5 m inside: beyond the edge by at most one step, not half the gap
    assert abs(np.mean(errors)) < 0.1


def test_edge_shift_measures_the_gap_and_falls_back_without_points():
    xy = np.column_stack([np.arange(0, 10, 0.5), np.zeros(20)])
    normal = np.array([0.0, -1.0])  # outwards: the roof lies at y > 0
    near = np.column_stack([np.arange(0.1, 10, 0.5), np.full(20, -0.3)])
    shift, measured = edge_shift(xy, np.zeros(20), normal, 0.5, EdgeContext(near), fallback=0.4)
    assert measured and shift == pytest.approx(0.15)
    shift, measured = edge_shift(xy, np.zeros(20), normal, 0.5, EdgeContext(None), fallback=0.4)
    assert not measured and shift == pytest.approx(0.2)
    # ground in a wall's scan shadow: beyond one sampling step (2 x 0.4 x 0.5 m) it does not move the edge out
    for shadow in (0.6, 5.0):
        far = near - [0, shadow - 0.3]
        assert edge_shift(xy, np.zeros(20), normal, 0.5, EdgeContext(far), fallback=0.4) == (pytest.approx(0.2), False)
    # the residuals carry over: points scattered about the fitted line keep their own depth
    residual = np.tile([-0.05, 0.05], 10)
    assert edge_shift(xy, residual, normal, 0.5, EdgeContext(near), fallback=0.4)[0] == pytest.approx(0.15)


def test_fit_line_is_exact_on_a_line_and_robust_to_an_outlier():
    t = np.linspace(0, 10, 30)
    xy = np.column_stack([t, 0.5 * t + 1])
    point, direction, rss = fit_line(xy, 0.05)
    assert rss == pytest.approx(0, abs=1e-18)
    assert direction == pytest.approx(np.array([2, 1]) / np.sqrt(5))
    xy[15, 1] += 3.0
    _, robust, _ = fit_line(xy, 0.05)
    assert abs(np.cross(robust, direction)) < 0.01


def _lines_of(xy, breaks, sigma0):
    from rooftrace.contour.lines import _fit

    return [_fit(xy, np.arange(a, b), sigma0, 1) for a, b in zip(breaks[:-1], breaks[1:])]


def test_model_selection_drops_a_notch_within_the_noise_and_keeps_a_real_step():
    rng = np.random.default_rng(0)
    for depth, kept in ((0.08, False), (1.0, True)):
        # a 30 x 10 m ring, counter-clockwise, with a 3 m wide notch in its first wall
        x = np.arange(0, 30, 0.3)
        bottom = np.column_stack([x, np.where((x > 12) & (x < 15), depth, 0.0)])
        y = np.linspace(0, 10, 34)[:-1]
        right = np.column_stack([np.full(33, 30.0), y])
        top = np.column_stack([30 - x, np.full(len(x), 10.0)])
        left = np.column_stack([np.zeros(33), 10 - y])
        xy = np.concatenate([bottom, right, top, left])
        xy = xy + rng.normal(0, 0.03, xy.shape)
        n = len(x)
        breaks = [0, 40, 41, 50, 51, n, n + 33, 2 * n + 33, len(xy)]
        lines = simplify_lines(xy, _lines_of(xy, breaks, 0.1), 0.1)
        assert (len(lines) > 4) == kept
        if not kept:
            assert all(abs(np.cross(a.direction, b.direction)) > 0.99 for a, b in zip(lines, lines[1:] + lines[:1]))


def test_dominant_direction_is_taken_only_where_the_data_allows():
    rng = np.random.default_rng(1)
    sigma0 = 0.1

    def wall(angle_deg, length, offset):
        t = np.arange(0, length, 0.3)
        a = np.radians(angle_deg)
        return np.column_stack([t * np.cos(a), t * np.sin(a) + offset]) + rng.normal(0, 0.03, (len(t), 2))

    # three long walls on 0/90 degrees, one 0.3 degrees off (within the noise), one 4 degrees off over 25 m
    walls = [wall(0, 30, 0), wall(90, 20, 40), wall(0.3, 30, 80), wall(90, 20, 120), wall(4.0, 25, 160)]
    xy = np.concatenate(walls)
    bounds = np.cumsum([0] + [len(w) for w in walls])
    lines = _lines_of(xy, bounds, sigma0)
    out, theta = constrain_directions(xy, lines, sigma0)
    assert theta == pytest.approx(0, abs=np.radians(0.2)) or theta == pytest.approx(np.pi / 2, abs=np.radians(0.2))
    assert [ln.free for ln in out] == [False, False, False, False, True]


def test_bic_floor_makes_fits_below_the_sampling_noise_worth_nothing():
    assert segment_bic(0.001, 100, 2, 0.1) == segment_bic(0.5, 100, 2, 0.1)
    assert segment_bic(0.001, 100, 2, 0.1) < segment_bic(0.001, 100, 3, 0.1)
    assert segment_bic(10.0, 100, 3, 0.1) < segment_bic(20.0, 100, 2, 0.1)


def test_parallel_lines_are_joined_by_a_step_not_intersected():
    a = Line(np.arange(3), np.array([0.0, 0.0]), np.array([1.0, 0.0]), 0.0)
    b = Line(np.arange(3), np.array([5.0, 1.0]), np.array([1.0, 0.0]), 0.0)
    step = line_corners(a, b, np.array([4.0, 0.5]), 3.0)
    assert step.tolist() == [[4.0, 0.0], [4.0, 1.0]]
    c = Line(np.arange(3), np.array([4.0, 0.0]), np.array([0.0, 1.0]), 0.0)
    assert line_corners(a, c, np.array([3.8, 0.2]), 3.0).tolist() == [[4.0, 0.0]]


def test_a_narrow_inlet_without_points_is_bridged_a_wide_one_kept():
    for width, bridged in ((1.0, True), (4.0, False)):
        poly = shapely.box(0, 0, 20, 10).difference(shapely.box(8, 5, 8 + width, 10))
        ring = np.asarray(shapely.segmentize(poly.exterior, 0.3).coords)[:-1]
        keep = bridge_inlets(ring, 2.0)
        inner = (ring[:, 0] > 7.99) & (ring[:, 0] < 8 + width + 0.01) & (ring[:, 1] > 4.99) & (ring[:, 1] < 9.99)
        assert (not keep[inner].any()) == bridged
        assert keep[~inner & (ring[:, 1] < 4.9)].all()


def test_cdspline_method_is_the_thesis_path():
    roof, _ = scene(L_SHAPE, seed=2)
    spline = trace_outline(roof, OutlineOptions.from_config({}, method="cdspline"))
    lines = trace_outline(roof)
    assert spline.polygon.exterior.coords[:] != lines.polygon.exterior.coords[:]
    with pytest.raises(ValueError, match="method"):
        OutlineOptions.from_config({}, method="splines")


def _slanted_rows(box, angle, row_step, gap, seed=0):
    """Points on parallel rows (scan lines) at ``angle`` degrees to the x axis, clipped to ``box``."""
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = box.bounds
    r = np.hypot(x1 - x0, y1 - y0)
    u, v = np.meshgrid(np.arange(-r, r, gap), np.arange(-r, r, row_step) + rng.uniform(0, row_step))
    u = u + rng.uniform(0, gap, (u.shape[0], 1))
    a = np.radians(angle)
    xy = np.column_stack([u.ravel() * np.cos(a) - v.ravel() * np.sin(a), u.ravel() * np.sin(a) + v.ravel() * np.cos(a)])
    xy = xy + [(x0 + x1) / 2, (y0 + y1) / 2]
    return xy[shapely.contains_xy(box, xy[:, 0], xy[:, 1])]


def test_the_noise_across_a_wall_is_the_step_to_the_next_row_not_the_gap_along_the_ring():
    # scan lines 0.6 m apart run at 8 degrees to the long walls, 0.1 m between their points: along
    # those walls the ring follows one line until the next reaches the wall (a saw-tooth)
    box = shapely.box(0, 0, 30, 10)
    roof = _slanted_rows(box, 8.0, 0.6, 0.1)
    shape = alpha_shape(roof, AlphaOptions(strategy="building"))
    ring = roof[shape.rings[0]]
    spacing = float(np.median(shape.spacing))
    south = (ring[:, 1] < 1.0) & (ring[:, 0] > 4) & (ring[:, 0] < 26)
    across = boundary_step(ring, spacing, roof)[south]
    along = boundary_step(ring, spacing)[south]  # without the roof points: the gaps along the ring
    row = 0.6 / np.cos(np.radians(8.0))  # the next line behind a wall point, straight across the wall
    assert np.median(across) == pytest.approx(row, rel=0.25)
    # the gaps along the ring are short there: they add nothing to the mean spacing (0.44 m)
    assert np.median(along) < 1.05 * spacing < 0.8 * row


@pytest.mark.parametrize("seed", [1, 3])
def test_simulated_straight_walled_buildings_get_their_corner_count(seed):
    # 70 m scenes at 12 pts/m²: an L, a hip roof and a courtyard, the scanner's zigzag lines slanted to
    # their walls (with the gaps along the ring as the noise, 2 of these 6 had the right count)
    from rooftrace.evaluate.metrics import corner_metrics
    from rooftrace.synth import SceneOptions, simulate_scene

    scene = simulate_scene(SceneOptions(seed=seed, size=70.0, density=12.0, image=False))
    xyz, cls = scene.cloud.xyz, np.asarray(scene.cloud.fields["truth_class"])
    bid = np.asarray(scene.cloud.fields["truth_building_id"])
    truth = scene.truth["roof_outlines"]
    kinds = {b.building_id: b.kind for b in scene.buildings}
    straight = [(p, b) for p, b in zip(truth.geometries, truth.attributes["building_id"])
                if kinds[b] not in ("round", "stadium", "arc") and ((bid == b) & (cls == 6)).sum() >= 10]
    assert len(straight) == 3
    for polygon, b in straight:
        own = (bid == b) & (cls == 6)
        # the other points around it (not noise), as `rooftrace run` passes them
        near = ~own & (cls != 7) & (np.abs(xyz[:, :2] - xyz[own, :2].mean(axis=0)).max(axis=1) < 40.0)
        out = trace_outline(xyz[own], context_xy=xyz[near, :2])
        c = corner_metrics(out.polygon, polygon)
        assert c["n_corners"] == c["n_corners_reference"], (b, c["n_corners"], c["n_corners_reference"])
        assert polis(out.polygon, polygon) < 0.08


def _pieces(ring, n_pieces):
    """Lines fitted to ``n_pieces`` equal runs of a ring's points."""
    out = []
    for idx in np.array_split(np.arange(len(ring)), n_pieces):
        point, direction, rss = fit_line(ring[idx, :2], 0.03)
        out.append(Line(idx, point, direction, rss, span=1.0, noise2=0.03**2))
    return out


def test_short_lines_along_an_arc_become_curves_and_a_wobbly_wall_stays_straight():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 2 * np.pi, 170, endpoint=False)  # a round building, r 8 m, 0.3 m between ring points
    ring = np.column_stack([8 * np.cos(t), 8 * np.sin(t), np.full_like(t, 10.0)])
    ring[:, :2] += rng.normal(0, 0.03, (len(t), 2))
    lines = _pieces(ring, 24)  # 2.1 m pieces: each within a line's noise
    out = curved_runs(ring, lines, 0.5)
    assert len(out) < 8 and all(not isinstance(s, Line) and s.degree >= 2 for s in out)
    # a wall bent to and fro (0.3 m over 5 m pieces): its breaks turn both ways, so it is no arc
    zigzag = shapely.LineString([(0, 0), (5, -0.3), (10, 0), (15, -0.3), (20, 0), (20, 10), (0, 10), (0, 0)])
    box = np.asarray(shapely.segmentize(zigzag, 0.3).coords)[:-1]
    box = np.column_stack([box + rng.normal(0, 0.03, box.shape), np.full(len(box), 10.0)])
    corners = [0] + [int(np.argmin(np.linalg.norm(box[:, :2] - c, axis=1))) for c in
                     [(5, -0.3), (10, 0), (15, -0.3), (20, 0), (20, 10), (0, 10)]] + [len(box)]
    lines = [_pieces(box[a:b], 1)[0] for a, b in zip(corners[:-1], corners[1:])]
    for ln, a in zip(lines, corners):
        ln.idx = ln.idx + a
    out = curved_runs(box, lines, 0.5)
    assert out == lines


def test_a_chord_curve_runs_through_the_middle_of_a_stepped_arc():
    # the ring along a gently curved wall where scan lines end in steps (a staircase 0.35 m high): the
    # curve across the chord has no parameter for the steps to stretch, it passes between them
    x = np.arange(-10.0, 10.0, 0.25)
    arc = 1.7 * (1 - (x / 10) ** 2)
    stairs = np.floor(arc / 0.35) * 0.35 + 0.175  # each point on the scan line just inside the arc, centred
    points = np.column_stack([x, stairs, np.full_like(x, 6.0)])
    curve = chord_curve(points, ((-10.0, 0.175), (10.0, 0.175)), 2, 0.5)
    assert curve[0, :2] == pytest.approx([-10.0, 0.175], abs=0.2) and curve[-1, :2] == pytest.approx([10.0, 0.175], abs=0.2)
    res = shapely.distance(shapely.points(points[:, :2]), shapely.LineString(curve[:, :2]))
    assert np.sqrt(np.mean(res**2)) < 0.35 / np.sqrt(12) * 1.3  # the staircase's own scatter about its middle
    assert np.abs(np.interp(x, curve[:, 0], curve[:, 1]) - arc).max() < 0.15  # the arc itself
    assert np.allclose(curve[:, 2], 6.0)


@pytest.mark.parametrize("seed", [6, 16])
def test_simulated_round_buildings_get_a_curve(seed):
    # the 70 m scenes' round building: the CD-spline fitted to its runs of short lines (chord-length knots
    # dragged by the ring's steps) lost to the lines on these two seeds; the chord curve does not
    from rooftrace.synth import SceneOptions, simulate_scene

    scene = simulate_scene(SceneOptions(seed=seed, size=70.0, density=12.0, image=False))
    xyz, cls = scene.cloud.xyz, np.asarray(scene.cloud.fields["truth_class"])
    bid = np.asarray(scene.cloud.fields["truth_building_id"])
    (b,) = [b.building_id for b in scene.buildings if b.kind == "round"]
    own = (bid == b) & (cls == 6)
    near = ~own & (cls != 7) & (np.abs(xyz[:, :2] - xyz[own, :2].mean(axis=0)).max(axis=1) < 40.0)
    out = trace_outline(xyz[own], context_xy=xyz[near, :2])
    assert max(out.degrees[0]) >= 2, out.degrees
    (truth,) = [p for p, i in zip(scene.truth["roof_outlines"].geometries,
                                  scene.truth["roof_outlines"].attributes["building_id"]) if i == b]
    assert polis(out.polygon, truth) < 0.12


def test_a_run_of_lines_turning_one_way_starts_with_the_line_before_its_first_turn():
    # a corner, a short piece turning back by 5 degrees, then two turns of 10 degrees the other way: the arc
    # is lines 2-4 (line 2 ends the piece that turned back and starts the arc), not lines 3-4 alone
    def line(deg):
        a = np.radians(deg)
        return Line(np.arange(3), np.zeros(2), np.array([np.cos(a), np.sin(a)]), 0.0)

    segments = [line(d) for d in (0, 90, 85, 95, 105, 195, 270)]
    assert _turning_runs(segments) == [[2, 3, 4]]
