import numpy as np
import pytest
import shapely

from rooftrace.contour.outline import (
    OutlineOptions,
    RoofOutline,
    connected_buildings,
    outline_buildings,
    outlines_layer,
    trace_outline,
)
from rooftrace.errors import GeometryError, InputError
from rooftrace.evaluate.metrics import area_scores, polis
from tests.contour.shapes import CIRCLE, COURTYARD, L_SHAPE, RECT, STADIUM, sample


@pytest.mark.parametrize("truth", [RECT, L_SHAPE, COURTYARD], ids=["rect", "L", "courtyard"])
def test_straight_shapes(truth):
    xyz = sample(truth, 10, seed=1)
    out = trace_outline(xyz)
    poly = out.polygon
    assert out.status == "ok" and poly.is_valid and poly.has_z
    assert poly.exterior.is_ccw
    assert all(not r.is_ccw for r in poly.interiors)
    assert len(poly.interiors) == len(truth.interiors)
    assert len(out.degrees[0]) == len(truth.exterior.coords) - 1  # one segment per true side
    assert polis(poly, truth) < 0.2
    assert area_scores(poly, truth)["f_score"] > 0.97
    # corners index the ring's vertices and sit near true corners
    ring = np.asarray(poly.exterior.coords)[:-1]
    true_corners = np.asarray(truth.exterior.coords)[:-1]
    d = np.min(np.linalg.norm(ring[out.corners[0], None, :2] - true_corners[None], axis=2), axis=1)
    assert d.max() < 0.5
    np.testing.assert_allclose(ring[:, 2], 10.0, atol=0.2)
    assert out.z_min < out.z_mean < out.z_max


@pytest.mark.parametrize("truth,name", [(CIRCLE, "circle"), (STADIUM, "stadium")])
def test_curved_shapes_get_curved_segments(truth, name):
    # the thesis path: every arc piece longer than 2 m curved (the 'lines' default keeps a short
    # piece straight when its curvature is within the noise: tests/contour/test_lines.py)
    xyz = sample(truth, 10, seed=2)
    out = trace_outline(xyz, OutlineOptions.from_config({}, method="cdspline"))
    assert polis(out.polygon, truth) < 0.2
    ring = np.asarray(out.polygon.exterior.coords)[:-1, :2]
    corners = out.corners[0]
    degrees = np.asarray(out.degrees[0])
    ends = np.append(corners[1:], len(ring))
    for k, d in enumerate(degrees):
        mid = ring[(corners[k] + ends[k]) // 2] if d > 1 else 0.5 * (ring[corners[k]] + ring[ends[k] % len(ring)])
        length = np.linalg.norm(ring[ends[k] % len(ring)] - ring[corners[k]])
        on_arc = np.hypot(*(mid - (0, 0))) > 7.5 if name == "circle" else mid[0] > 14.3
        if length > 2.0 and on_arc:
            assert d >= 2, (k, degrees)
        if name == "stadium" and mid[0] < 12 and length > 2.0:  # the straight walls
            assert d == 1, (k, degrees)
    assert degrees.max() >= 2


def test_shuffle_and_translation_invariance():
    xyz = sample(L_SHAPE, 10, seed=4)
    a = trace_outline(xyz)
    perm = np.random.default_rng(0).permutation(len(xyz))
    b = trace_outline(xyz[perm])
    shift = np.array([85000.0, 447000.0, 0.0])
    c = trace_outline(xyz + shift)
    assert shapely.equals_exact(shapely.normalize(a.polygon), shapely.normalize(b.polygon), 1e-9)
    moved = shapely.affinity.translate(c.polygon, -shift[0], -shift[1])
    assert shapely.hausdorff_distance(moved, a.polygon) < 1e-5
    assert a.degrees == c.degrees


def test_outward_correction_measures_better():
    xyz = sample(RECT, 10, seed=5)
    inner = trace_outline(xyz, OutlineOptions.from_config({}, method="cdspline", offset_factor=0.0)).polygon
    outer = trace_outline(xyz, OutlineOptions.from_config({}, method="cdspline")).polygon
    assert outer.area > inner.area
    assert area_scores(outer, RECT)["f_score"] > area_scores(inner, RECT)["f_score"]


def test_snapping_makes_sides_orthogonal():
    rot = shapely.affinity.rotate(RECT, 17, origin=(0, 0))
    xyz = sample(rot, 10, seed=6)
    out = trace_outline(xyz, OutlineOptions.from_config({}, snap=True))
    ring = np.asarray(out.polygon.exterior.coords)[:-1, :2][out.corners[0]]
    d = np.roll(ring, -1, axis=0) - ring
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    dev = (ang - 17 + 45) % 90 - 45
    assert np.abs(dev).max() < 1.0


def test_outline_buildings_records_status_and_sorts_ids():
    a = sample(RECT, 10, seed=7)
    b = sample(shapely.affinity.translate(L_SHAPE, 40, 0), 10, seed=8)
    line = np.column_stack([np.linspace(80, 90, 20), np.full(20, 3.0), np.full(20, 5.0)])
    two = np.array([[100.0, 0, 5], [101, 0, 5]])
    xyz = np.concatenate([b, a, line, two, [[0.0, 0, 0]]])
    ids = np.concatenate([np.full(len(b), 7), np.full(len(a), 3), np.full(20, 9), [11, 11], [0]])
    outs = outline_buildings(xyz, ids)
    assert [o.building_id for o in outs] == [3, 7, 9, 11]
    assert [o.status for o in outs] == ["ok", "ok", "collinear", "too_few_points"]
    assert outs[2].polygon is None and outs[2].n_points == 20
    layer = outlines_layer(outs, {"source": ["a", "b", "c", "d"]})
    assert layer.geometry_type == "PolygonZ" and len(layer) == 4
    for key in ("building_id", "n_points", "alpha_strategy", "area", "z_min", "z_mean", "z_max", "degrees", "status"):
        assert key in layer.attributes
    assert layer.attributes["degrees"][0].count(",") == 3
    assert layer.attributes["area"][2] == 0.0


def test_degrees_attribute_joins_rings():
    out = RoofOutline(1, None, degrees=[[1, 1, 2, 1], [1, 1, 1]])
    assert outlines_layer([out]).attributes["degrees"] == ["1,1,2,1;1,1,1"]


def test_trace_outline_raises_for_degenerate_input():
    with pytest.raises(GeometryError, match="too_few_points"):
        trace_outline(np.array([[0.0, 0, 0], [1, 1, 1]]))
    with pytest.raises(ValueError, match="shape"):
        trace_outline(np.zeros((5, 2)))


def test_options_from_config_and_overrides():
    cfg = {"alpha": {"strategy": "global", "radius": 2.0}, "cdspline": {"max_degree": 3}}
    o = OutlineOptions.from_config(cfg, strategy="building", snap=None, offset_factor=0.5, t_dist=0.4)
    assert o.alpha.strategy == "building" and o.alpha.radius == 2.0
    assert o.cdspline.max_degree == 3 and o.corners.t_dist == 0.4 and o.regularize.snap is True
    assert o.regularize.offset_factor == 0.5
    with pytest.raises(InputError, match="unknown"):
        OutlineOptions.from_config({"alpha": {"radiuss": 1}})
    with pytest.raises(InputError, match="unknown option"):
        OutlineOptions.from_config({}, nonsense=1)
    with pytest.raises(InputError, match="strategy"):
        OutlineOptions.from_config({}, strategy="nope")


def test_connected_buildings():
    a = sample(RECT, 10)[:, :2]
    b = a + (30, 0)
    ids = connected_buildings(np.concatenate([a, b, [[100.0, 100.0]]]), radius=0.8)
    assert set(ids[: len(a)]) == {1} and set(ids[len(a):-1]) == {2} and ids[-1] == 0


def test_a_ring_pinched_at_a_point_keeps_both_wings():
    from rooftrace.contour.repair import make_valid_outline as _make_valid

    # two 10 m squares touching at (10, 10), traced as one ring through the pinch
    ring = np.array([[0, 0, 5], [10, 0, 5], [10, 10, 5], [20, 10, 6], [20, 20, 6], [10, 20, 6], [10, 10, 6],
                     [0, 10, 5]], float)
    polygon = shapely.Polygon(ring)
    assert not polygon.is_valid
    fixed, corners = _make_valid(polygon, [ring], [np.arange(len(ring))])
    assert fixed.is_valid and fixed.geom_type == "Polygon" and fixed.has_z
    assert fixed.area == pytest.approx(200, abs=0.5)  # both wings and a bridge of a few cm²
    assert set(np.round(np.asarray(fixed.exterior.coords)[:, 2])) == {5, 6}


def _scan_lines(seed: int, line_gap: float = 0.65, step: float = 0.15, width: float = 16.0, height: float = 9.5):
    """A flat 16 x 9.5 m roof scanned in oblique lines ``line_gap`` apart, two returns per pulse (the demo's pattern).

    The many short along-line edges keep the mean spacing (hence alpha) small while the
    lines stay far apart: the alpha disk only just fits between them.
    """
    rng = np.random.default_rng(seed)
    d = np.array([np.cos(-0.12), np.sin(-0.12)])
    n = np.array([-d[1], d[0]])
    parts = []
    for off in np.arange(-15, 15, line_gap):
        t = np.arange(-20, 20, step) + rng.uniform(0, step)
        p = off * n + t[:, None] * d + rng.normal(0, 0.03, (len(t), 2))
        parts += [p, p + rng.normal(0, 0.03, p.shape)]
    p = np.concatenate(parts)
    p = p[(p[:, 0] > 0) & (p[:, 0] < width) & (p[:, 1] > 0) & (p[:, 1] < height)]
    return np.column_stack([p, np.full(len(p), 10.0)])


@pytest.mark.parametrize("seed", range(4))
def test_alpha_is_enlarged_until_it_bridges_the_scan_lines(seed):
    from rooftrace.contour.alpha_shape import alpha_shape

    xyz = _scan_lines(seed)
    # at scale 1 the ring closes, but through bays between the scan lines (0.86-0.93 at alpha x 1.25)
    assert alpha_shape(xyz[:, :2]).gap_fill > 0.75
    out = trace_outline(xyz)
    assert out.status == "alpha_enlarged"
    # before: closed at the first alpha with 11-19 corners, PoLiS 0.21-0.41 m
    assert len(out.corners[0]) == 4
    truth = shapely.box(0, 0, 16, 9.5)
    assert polis(out.polygon, truth) < 0.25
    # dropping a dozen points at an edge (the demo's wall points) leaves the outline as it is
    edge = np.flatnonzero(xyz[:, 0] < 0.3)
    again = trace_outline(np.delete(xyz, edge[:: len(edge) // 13][:13], axis=0))
    assert len(again.corners[0]) == 4
    assert polis(again.polygon, out.polygon) < 0.1


def test_even_sampling_bridges_at_the_first_alpha():
    from rooftrace.contour.alpha_shape import alpha_shape

    g = np.mgrid[0:10:0.3, 0:6:0.3].reshape(2, -1).T
    assert alpha_shape(g).gap_fill < 0.6
    assert trace_outline(np.column_stack([g, np.full(len(g), 5.0)])).status == "ok"


def _roof_with_light_well(seed=0):
    """A 20 x 12 m flat roof 8 m up with a 1.1 x 6 m light well, on a jittered 0.45 m grid; the well's points are ground."""
    rng = np.random.default_rng(seed)
    g = np.mgrid[0:20:0.45, 0:12:0.45].reshape(2, -1).T + rng.uniform(-0.08, 0.08, (1, 2))
    g = g + rng.normal(0, 0.05, g.shape)
    well = shapely.box(9.45, 3.0, 10.55, 9.0)
    in_well = shapely.contains_xy(well, g[:, 0], g[:, 1])
    roof = np.column_stack([g[~in_well], np.full((~in_well).sum(), 8.0)])
    ground = np.column_stack([g[in_well], np.zeros(in_well.sum())])
    return roof, ground, well


def test_a_light_well_where_the_ground_was_seen_is_not_bridged():
    roof, ground, well = _roof_with_light_well()
    centre = well.centroid
    # without the heights around (or without the rule) the enlarged alpha (0.78 m) bridges the 1.1 m well
    bridged = trace_outline(roof, context_xy=ground[:, :2])
    assert bridged.polygon.contains(centre)
    off = OutlineOptions.from_config({"alpha": {"seen_through": False}})
    assert trace_outline(roof, off, context_xy=ground).polygon.contains(centre)
    # the ground seen in it keeps it open, and the outline still holds the roof's points
    out = trace_outline(roof, context_xy=ground)
    assert out.status == "ok" and out.coverage >= 0.99
    assert not shapely.force_2d(out.polygon).contains(centre)
    assert shapely.force_2d(out.polygon).area < shapely.force_2d(bridged.polygon).area - 0.5 * well.area


@pytest.mark.parametrize("gap", [0.45, 0.6])
def test_a_well_beside_the_wall_that_would_pinch_the_outline_is_bridged(gap):
    # half a metre from the wall the kept well's ring was repaired onto the outer one (a pinch no closed solid
    # can stand on: a Delft shed lost every level of detail); then the shape without the cut is traced
    rng = np.random.default_rng(2)
    g = np.mgrid[0:20:0.45, 0:12:0.45].reshape(2, -1).T + rng.uniform(-0.08, 0.08, (1, 2))
    g = g + rng.normal(0, 0.05, g.shape)
    well = shapely.contains_xy(shapely.box(9.45, gap, 10.55, 6.0), g[:, 0], g[:, 1])
    roof = np.column_stack([g[~well], np.full((~well).sum(), 8.0)])
    out = trace_outline(roof, context_xy=np.column_stack([g[well], np.zeros(well.sum())]))
    assert out.status == "ok" and out.coverage >= 0.99
    assert out.polygon.is_valid and out.polygon.exterior.is_simple


def test_two_roofs_joined_across_a_passage_stay_one_outline():
    # the building's points fall apart where the ground was seen: rather than lose a part, the passage is bridged
    roof, ground, _ = _roof_with_light_well()
    passage = shapely.box(9.45, -1.0, 10.55, 13.0)
    g = np.concatenate([roof, ground])
    cut = shapely.contains_xy(passage, g[:, 0], g[:, 1])
    roof = g[~cut]
    ground = np.column_stack([g[cut, :2], np.zeros(cut.sum())])
    out = trace_outline(roof, context_xy=ground)
    assert out.coverage >= 0.99 and out.status in ("ok", "alpha_enlarged")
    assert shapely.force_2d(out.polygon).area > 0.9 * 20 * 12 - passage.intersection(shapely.box(0, 0, 20, 12)).area


def test_regularisation_that_repairs_to_nothing_keeps_the_traced_rings(monkeypatch):
    # regularised rings whose repair leaves nothing polygonal (seen on Delft thinned to 3 pts/m² when the
    # spacings moved by 5e-15 m): the building still gets the alpha shape's rings, not 'degenerate_outline'
    # and no outline at all
    import rooftrace.contour.outline as outline_module

    regularise = outline_module._ring_outline
    shell = {}

    def hole_over_shell(xyz, spacing, options, *, outer=True, **kw):
        result = regularise(xyz, spacing, options, outer=outer, **kw)
        if outer:
            shell["ring"] = result
            return result
        return shell["ring"]

    monkeypatch.setattr(outline_module, "_ring_outline", hole_over_shell)
    monkeypatch.setattr(outline_module, "make_valid_outline", lambda polygon, rings, corners: (None, []))
    xyz = sample(COURTYARD, 10, seed=1)
    out = trace_outline(xyz)
    assert out.status == "unregularised"
    assert out.polygon.is_valid and len(out.polygon.interiors) == 1
    assert out.coverage >= 0.99
    assert area_scores(out.polygon, COURTYARD)["f_score"] > 0.95
