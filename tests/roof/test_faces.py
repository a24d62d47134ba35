"""Faces tile the outline, sit on their planes; step edges between roof levels."""

import numpy as np
import pytest
import shapely
import shapely.affinity
from shapely.geometry import Polygon

from rooftrace.roof import models, roof_structure
from rooftrace.roof.faces import lift_to_plane, points_in_faces, step_edges
from rooftrace.roof.planes import plane_height


@pytest.mark.parametrize(
    "model", [models.gable(angle=10), models.hip(), models.l_hip(angle=-25), models.flat_annex(), models.gable_dormer()],
    ids=lambda m: m.name,
)
def test_faces_tile_the_outline(model):
    xyz, _ = models.sample_roof(model, 12, 0.04, seed=2)
    roof = roof_structure(xyz, model.outline)
    assert roof.status == "ok"
    faces2d = [shapely.force_2d(f) for f in roof.faces]
    assert all(f.is_valid for f in faces2d)
    total = sum(f.area for f in faces2d)
    union = shapely.union_all(faces2d)
    # No overlaps (sum of areas = area of the union), no gaps (= outline).
    assert total == pytest.approx(model.outline.area, rel=1e-6)
    assert union.area == pytest.approx(model.outline.area, rel=1e-6)
    assert shapely.symmetric_difference(union, model.outline).area < 1e-6 * model.outline.area
    # Every vertex of a face is on its plane.
    for f, k in zip(roof.faces, roof.face_plane):
        c = np.asarray(f.exterior.coords)
        assert np.allclose(plane_height(roof.planes[k][None], c[:, :2])[:, 0], c[:, 2], atol=1e-9)


def test_faces_follow_the_ridges():
    """Face boundaries between two planes run along their intersection line."""
    model = models.hip(angle=30)
    xyz, _ = models.sample_roof(model, 12, 0.04, seed=4)
    roof = roof_structure(xyz, model.outline)
    for g, (a, b) in zip(roof.ridges, roof.ridge_planes):
        fa = shapely.union_all([shapely.force_2d(f) for f, k in zip(roof.faces, roof.face_plane) if k == a])
        fb = shapely.union_all([shapely.force_2d(f) for f, k in zip(roof.faces, roof.face_plane) if k == b])
        shared = fa.boundary.intersection(fb.boundary)
        assert shared.length > 0.8 * shapely.force_2d(g).length
        assert shapely.hausdorff_distance(shared, shapely.force_2d(g)) < 0.5
        # Face vertices along the line (off the outline) were snapped onto it.
        on = [c for c in shapely.get_coordinates(shared) if shapely.distance(shapely.force_2d(g), shapely.Point(c)) < 0.3
              and shapely.distance(model.outline.boundary, shapely.Point(c)) > 1e-9]
        assert on and max(shapely.distance(shapely.force_2d(g), shapely.Point(c)) for c in on) < 1e-6


def test_step_edges_on_constructed_faces():
    low = Polygon([(0, 0), (4, 0), (4, 4), (0, 4)])
    high = Polygon([(4, 0), (10, 0), (10, 4), (4, 4)])
    planes = np.array([[0, 0, 1, -3.0], [0, 0, 1, -7.0]])
    lines, pairs = step_edges([low, high], [0, 1], planes, step_height=0.5, min_length=1.0)
    assert pairs == [(1, 0)]
    c = np.asarray(lines[0].coords)
    assert np.allclose(c[:, 0], 4) and np.allclose(sorted(c[[0, -1], 1]), [0, 4]) and np.allclose(c[:, 2], 7)
    # Same height: no step.
    lines, _ = step_edges([low, high], [0, 1], planes[[0, 0]], step_height=0.5, min_length=1.0)
    assert lines == []


def test_flat_annex_step_edge():
    model = models.flat_annex(angle=12)
    xyz, _ = models.sample_roof(model, 12, 0.03, seed=1)
    roof = roof_structure(xyz, model.outline)
    assert roof.ridge_kind == ["step"]
    g = roof.ridges[0]
    truth = model.ridges[0]
    assert shapely.hausdorff_distance(shapely.force_2d(g), shapely.force_2d(truth)) < 0.5
    assert np.allclose(np.asarray(g.coords)[:, 2], 9.0, atol=0.05)


def test_lift_to_plane():
    g = lift_to_plane(Polygon([(0, 0), (1, 0), (1, 1)]), np.array([-0.6, 0, 0.8, -1.6]))
    assert np.allclose(np.asarray(g.exterior.coords)[:, 2], [2, 2.75, 2.75, 2])


def test_outline_with_z_and_courtyard(rng):
    """A 3D outline with a hole (courtyard), as the outline stage gives it."""
    ring = [(0, 0, 6.0), (20, 0, 6.0), (20, 16, 6.0), (0, 16, 6.0)]
    hole = [(7, 5, 6.0), (13, 5, 6.0), (13, 11, 6.0), (7, 11, 6.0)]
    outline = Polygon(ring, [hole])
    g = 1 / np.sqrt(12)
    xy = np.mgrid[g / 2:20:g, g / 2:16:g].reshape(2, -1).T + rng.uniform(-g / 2, g / 2, (1, 2))
    xy = xy[shapely.contains_xy(shapely.force_2d(outline), xy[:, 0], xy[:, 1])]
    # Two shed halves falling away from a ridge at x = 10.
    z = 9.0 - 0.4 * np.abs(xy[:, 0] - 10) + rng.normal(0, 0.03, len(xy))
    roof = roof_structure(np.column_stack([xy, z]), outline)
    assert roof.status == "ok" and len(roof.planes) == 2
    faces2d = [shapely.force_2d(f) for f in roof.faces]
    assert sum(f.area for f in faces2d) == pytest.approx(outline.area, rel=1e-6)
    assert all(f.intersection(Polygon(hole)).area < 1e-6 for f in faces2d)
    # The ridge crosses the courtyard: two pieces, each ending on the outline.
    assert roof.ridge_kind.count("ridge") == 2
    for r in roof.ridges:
        for c in (r.coords[0], r.coords[-1]):
            assert shapely.distance(shapely.force_2d(outline).boundary, shapely.Point(c[:2])) < 1e-6


def test_outline_away_from_points_gives_no_faces():
    m = models.gable()
    xyz, _ = models.sample_roof(m, 12, 0.03, seed=1)
    far = shapely.affinity.translate(m.outline, 500, 0)
    roof = roof_structure(xyz, far)
    assert roof.status in ("no_faces", "ok") and len(roof.planes) == 2
    assert all(shapely.force_2d(f).within(far.buffer(1e-6)) for f in roof.faces)


def test_cell_choice_equals_the_pairwise_vote():
    """The compiled candidate choice of partition_outline equals the (cells, k, k)
    numpy form it replaced: fewest line violations, then most votes, then nearest."""
    from rooftrace.roof.face_kernels import cell_choice, cell_lines

    rng = np.random.default_rng(4)
    K, k, n = 9, 8, 3000
    segidx = np.full((K, K), -1, dtype=np.int64)
    for s, (a, b) in enumerate([(0, 1), (1, 2), (2, 5), (3, 4), (6, 8), (0, 7)]):
        segidx[a, b] = segidx[b, a] = s
    sign = rng.choice([-1, 1], 6).astype(np.int64)
    cm = rng.integers(0, K, (n, k)).astype(np.int64)
    heights = rng.normal(size=(n, K))
    z = np.take_along_axis(heights, cm, axis=1)  # one height per cell and plane, as plane_height gives
    ptr, line = cell_lines(cm, segidx)
    near_cell_line = rng.random((n, 6)) < 0.6
    near = near_cell_line[np.repeat(np.arange(n), np.diff(ptr)), line]

    votes = (cm[:, :, None] == cm[:, None, :]).sum(axis=2)
    S = segidx[cm[:, :, None], cm[:, None, :]]
    m, i, j = np.nonzero(S >= 0)
    sv = S[m, i, j]
    keep = near_cell_line[m, sv]
    m, i, j, sv = m[keep], i[keep], j[keep], sv[keep]
    zi, zj = z[m, i], z[m, j]
    wrong = ((sign[sv] > 0) & (zi > zj)) | ((sign[sv] < 0) & (zi < zj))
    viol = np.zeros(cm.shape, dtype=np.int64)
    np.add.at(viol, (m[wrong], i[wrong]), 1)
    score = viol * (k + 1) ** 2 - votes * (k + 1) + np.arange(k)
    assert np.array_equal(cell_choice(cm, segidx, ptr, line, near, sign, z), np.argmin(score, axis=1))
    nearest = viol * (k + 1) ** 2 + np.arange(k)  # without the vote: fewest violations, then the nearest
    assert np.array_equal(cell_choice(cm, segidx, ptr, line, near, sign, z, False), np.argmin(nearest, axis=1))


def test_labelled_points_lie_under_their_own_plane_at_steps():
    """Nearest-point faces with the simplification held back where it would misplace points: at the
    height steps of a terraced row almost no labelled point lies under another plane's face more
    than 0.1 m off (the k-nearest majority with free simplification misplaced ten times more)."""
    from rooftrace.roof.faces import partition_outline

    model = models.terraced(angle=17)
    xyz, face = models.sample_roof(model, 10, 0.03, seed=3)
    roof = roof_structure(xyz, model.outline)
    lab = roof.labels >= 0
    own = plane_height(roof.planes[roof.labels[lab]], xyz[lab, :2])

    def misplaced(**kw):
        polys, pids = partition_outline(roof.outline, xyz, roof.labels, roof.planes, cell=roof.spacing / 2,
                                        line_tolerance=1.0, **kw)
        at, f = shapely.STRtree(polys).query(shapely.points(xyz[lab, :2]), predicate="within")
        z = plane_height(roof.planes[np.asarray(pids)[f]], xyz[lab][at, :2])
        return np.mean(np.abs(z - own[at]) > 0.1)

    now, before = misplaced(), misplaced(vote=True, max_dz=None)
    assert now < 0.003 and before > 5 * now  # measured: 0.08 % against 0.9 %


def test_a_line_across_a_step_is_not_trusted():
    """The line rule (the lower plane across a convex line) is checked against the points near the
    line: a true ridge keeps it, a step whose planes' line the adjacency put there loses it."""
    from rooftrace.roof.faces import _line_misplaces

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 8, (4000, 2))
    east = xy[:, 0] > 4
    lab = east.astype(np.int64)
    ends = np.array([[4.0, 0.0], [4.0, 8.0]])
    # a gable ridge along x = 4: both planes meet there (z = 8 on the line)
    ridge = np.array([[-0.5, 0, 1, -6.0], [0.5, 0, 1, -10.0]]) / np.hypot(0.5, 1)
    assert not _line_misplaces(ends, 0, 1, +1, xy, lab, ridge, 1.0, 0.1)
    # a slope rising to 7 m at x = 4 beside a flat roof at 8 m: a 1 m step, the extended planes cross at x = 6
    step = np.array([[-0.5, 0, 1, -5.0], [0, 0, 1, -8.0]]) / [[np.hypot(0.5, 1)], [1.0]]
    assert _line_misplaces(ends, 0, 1, +1, xy, lab, step, 1.0, 0.1)


def test_close_face_vertices_are_merged_and_the_faces_still_tile():
    """A face boundary with a 2 mm kink and a vertex 0.4 mm short of the outline: both gone, shared
    vertices still shared, the outline's corners kept, the faces still tile it."""
    from rooftrace.roof.faces import merge_close_vertices

    outline = Polygon([(0, 0), (10, 0), (10, 6), (0, 6)])
    line = [(5.0, 0.0), (5.0, 3.0), (5.002, 3.0), (5.002, 5.9996), (5.002, 6.0)]
    left = Polygon([(0, 0), *line, (0, 6)])
    right = Polygon([*line[::-1], (10, 0), (10, 6)])
    faces = merge_close_vertices([left, right], outline, 0.01)
    xy = np.unique(np.vstack([shapely.get_coordinates(f) for f in faces]), axis=0)
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    assert d[d > 0].min() > 0.01 and len(xy) == 7  # four corners, the line's two ends and its bend
    assert all(f.is_valid for f in faces) and sum(f.area for f in faces) == pytest.approx(60.0)
    assert shapely.union_all(faces).equals(outline)
    assert {(0.0, 0.0), (10.0, 0.0), (10.0, 6.0), (0.0, 6.0)} <= set(map(tuple, xy))


def _shared_boundaries(polys, pids):
    """Plane pairs and the merged shared boundary of each pair of faces that share a line."""
    out = []
    for i in range(len(polys)):
        for j in range(i + 1, len(polys)):
            shared = shapely.line_merge(shapely.intersection(polys[i].boundary, polys[j].boundary))
            if shared.length > 0:
                out.append(((pids[i], pids[j]), shared))
    return out


def test_ridges_run_straight_from_node_to_node():
    """Each shared boundary by its own rule: on a hip roof every boundary is a ridge or hip (the planes
    meet along it), so each comes out as one straight segment between its nodes, before any snapping
    to the lines (one tolerance for the whole roof left bends in four of the five)."""
    from types import SimpleNamespace

    from rooftrace.roof.faces import partition_outline

    model = models.hip(angle=30)
    xyz, _ = models.sample_roof(model, 12, 0.04, seed=4)
    roof = roof_structure(xyz, model.outline)
    lines = SimpleNamespace(lines=roof.ridges, pairs=roof.ridge_planes,
                            convex=[-1 if k == "valley" else 1 for k in roof.ridge_kind])
    polys, pids = partition_outline(roof.outline, xyz, roof.labels, roof.planes, lines, cell=roof.spacing / 2,
                                    line_tolerance=1.0, plane_sigma=roof.plane_sigma)
    shared = _shared_boundaries(polys, pids)
    assert len(shared) == 5 and all(isinstance(p, int) for p in pids)
    assert all(g.geom_type == "LineString" and len(g.coords) == 2 for _, g in shared)
    assert sum(f.area for f in polys) == pytest.approx(model.outline.area, rel=1e-9)


def _misplaced_points_and_vertices(roof, xyz: np.ndarray, area: float, **kw) -> tuple[int, int]:
    """The roof's faces by ``partition_outline(**kw)``, checked to tile an outline of ``area``: the labelled
    points under a face more than 0.1 m off their own plane, and the faces' vertices."""
    from rooftrace.roof.faces import partition_outline

    lab = roof.labels >= 0
    own = plane_height(roof.planes[roof.labels[lab]], xyz[lab, :2])
    polys, pids = partition_outline(roof.outline, xyz, roof.labels, roof.planes, cell=roof.spacing / 2,
                                    line_tolerance=1.0, **kw)
    assert sum(f.area for f in polys) == pytest.approx(area, rel=1e-9)
    assert shapely.union_all(polys).area == pytest.approx(area, rel=1e-9)
    at, f = shapely.STRtree(polys).query(shapely.points(xyz[lab, :2]), predicate="within")
    z = plane_height(roof.planes[np.asarray(pids)[f]], xyz[lab][at, :2])
    return int(np.count_nonzero(np.abs(z - own[at]) > 0.1)), sum(len(shapely.get_coordinates(p)) for p in polys)


@pytest.mark.parametrize("model", [models.terraced(angle=17), models.gable_dormer()], ids=lambda m: m.name)
def test_each_boundary_by_its_rule_holds_steps_with_fewer_vertices(model):
    """Steps held, ridges free: no more labelled points under a face more than 0.1 m off their plane
    than one held-back tolerance for the roof gives, with at most half its vertices."""

    xyz, _ = models.sample_roof(model, 10, 0.03, seed=3)
    roof = roof_structure(xyz, model.outline)

    def measure(boundaries):
        return _misplaced_points_and_vertices(roof, xyz, model.outline.area, boundaries=boundaries)

    (each, n_each), (held, n_held), (free, _) = measure("each"), measure("held"), measure("free")
    assert each <= held < free and n_each <= n_held / 2  # measured: terraced 1 / 3 / 15 points, 154 / 384 vertices


def test_a_step_boundary_is_straightened_only_where_no_point_crosses():
    """The compiled arc simplification on a staircase between two roof levels 1 m apart: without points
    near it the staircase goes straight; a point the chord would put under the other level keeps a
    vertex; a point of a third face in the way keeps the staircase; along a crease it goes straight
    whatever the points."""
    from rooftrace.roof.face_kernels import simplify_arcs

    x = np.arange(11.0)
    V = np.column_stack([x, np.where(np.arange(11) % 2, 0.3, 0.0)])  # a zigzag 0.3 m deep
    vptr = np.array([0, 11])

    def kept(pts, delta, foreign, crease=False):
        return simplify_arcs(V, vptr, np.full(11, crease), np.asarray(pts, float).reshape(-1, 2),
                             np.array([0, len(delta)]), np.asarray(delta, np.int64), np.asarray(foreign, bool),
                             np.array([True]), 0.1, 1.0, 0)

    assert np.flatnonzero(kept([], [], [])).tolist() == [0, 10]
    # a point just under vertex 5 (y = 0.3), between the zigzag and the chord y = 0: moving it misplaces it
    k = kept([[5.0, 0.2]], [1], [False])
    assert k[0] and k[10] and 2 < k.sum() < 11
    assert np.flatnonzero(kept([[5.0, 0.2]], [-1], [False])).tolist() == [0, 10]  # the move mends it
    assert np.flatnonzero(kept([[5.0, 0.2]], [1], [False], crease=True)).tolist() == [0, 10]
    assert kept([[5.0, 0.2]], [0], [True], crease=True).sum() > 2
    # a point beyond the zigzag is never moved
    assert np.flatnonzero(kept([[5.0, 0.5]], [1], [False])).tolist() == [0, 10]


def test_an_unknown_boundary_rule_is_refused():
    from rooftrace.roof import RoofOptions
    from rooftrace.roof.faces import partition_outline

    with pytest.raises(ValueError, match="face_boundaries"):
        RoofOptions(face_boundaries="straight")
    m = models.gable()
    xyz, _ = models.sample_roof(m, 12, 0.03, seed=1)
    with pytest.raises(ValueError, match="boundaries"):
        partition_outline(m.outline, xyz, np.zeros(len(xyz), np.int64), np.array([[0, 0, 1, -5.0]]), cell=0.15,
                          line_tolerance=1.0, boundaries="straight")


def test_two_boundaries_simplified_onto_one_chord_are_caught():
    """Two arcs between the same two nodes that simplify to the same chord would drop the face between them
    from the polygonised faces (on Delft a 23 m² roof face went to the outside this way).  Together with a
    T-junction elsewhere, noding keeps the count of pieces (one piece fewer, one more), so the overlap must
    be found by the pieces' length too."""
    from shapely.geometry import LineString

    from rooftrace.roof.faces import _meets_only_at_ends

    arcs = np.array([LineString([(0, 0), (1, 0)]), LineString([(0, 0), (1, 0)]),  # one chord, twice
                     LineString([(5, -1), (5, 1)]), LineString([(5, 0), (6, 0)])], dtype=object)  # a T
    assert len(shapely.get_parts(shapely.node(shapely.multilinestrings(arcs)))) == len(arcs)
    assert _meets_only_at_ends(arcs).tolist() == [False, False, False, False]
    apart = np.array([LineString([(0, 0), (1, 0)]), LineString([(0, 0), (0.5, 0.5), (1, 0)])], dtype=object)
    assert _meets_only_at_ends(apart).all()


def test_points_in_boxes_are_the_str_tree_pairs():
    """The compiled box scan of the face boundaries finds the (arc, point) pairs an STR tree of the arcs
    queried with the points finds, by arc then point, points on a box's edge included."""
    from rooftrace.roof.face_kernels import points_in_boxes

    rng = np.random.default_rng(5)
    xy = np.round(rng.uniform(0, 20, (3000, 2)) + [85000.0, 447000.0], 2)  # cm grid: ties and points on edges
    ends = np.round(rng.uniform(0, 20, (60, 2, 2)) + [85000.0, 447000.0], 2)
    ends[:5, :, 1] = ends[:5, :1, 1]  # horizontal arcs: boxes of zero height
    ends[5:8] = xy[rng.integers(0, len(xy), (3, 2))]  # arcs from point to point
    arcs = shapely.linestrings(ends)
    pi, ri = shapely.STRtree(arcs).query(shapely.points(xy))
    o = np.lexsort((pi, ri))
    ptr, pts = points_in_boxes(xy[:, 0], xy[:, 1], np.argsort(xy[:, 0], kind="stable"), shapely.bounds(arcs))
    assert np.array_equal(pts, pi[o]) and np.array_equal(ptr, np.r_[0, np.cumsum(np.bincount(ri, minlength=60))])
    assert np.diff(ptr)[5:8].min() >= 2  # the arcs' own end points are in their boxes


@pytest.mark.parametrize("k", [1, 8, 40])
def test_nearest_labels_are_the_kd_tree_query(k):
    """The compiled nearest-point search of the face raster gives each cell the labels, in order, that
    ``cKDTree.query`` gives it, also where ties (duplicated points, a lattice queried at its cell
    centres) and far cells (outside the points) could order them otherwise."""
    from scipy.spatial import cKDTree

    from rooftrace.roof.faces import _nearest

    rng = np.random.default_rng(6)
    lattice = np.mgrid[0:30, 0:20].reshape(2, -1).T * 0.5
    scattered = np.round(rng.uniform(0, 15, (1500, 2)), 2)
    xy = np.concatenate([lattice, scattered, scattered[:300]]) + [85000.0, 447000.0]  # RD offsets, duplicates
    lab = rng.integers(0, 4, len(xy))
    cells = np.concatenate([np.mgrid[-10:70, -10:50].reshape(2, -1).T * 0.25 + 0.125,  # lattice ties, far cells
                            rng.uniform(-5, 20, (2000, 2))]) + [85000.0, 447000.0]
    got = lab[_nearest(xy, lab, cells, k)]
    want = lab[cKDTree(xy).query(cells, k=k)[1].reshape(len(cells), k)]
    assert np.array_equal(got, want)


def test_arcs_meeting_inside_are_found_among_all_pairs():
    """Only pairs with an arc the noding split or dissolved are tested; the verdicts are those of every pair
    tested: crossings, a T, an overlap, a duplicate and a self-crossing arc beside arcs meeting at ends."""
    from rooftrace.roof.faces import _meets_only_at_ends

    rng = np.random.default_rng(7)
    corners = rng.uniform(0, 10, (30, 2))
    arcs = [shapely.LineString(corners[[a, a + 1]]) for a in range(0, 28, 2)]  # loose segments, some crossing
    arcs += [shapely.LineString([(20, 0), (22, 1), (24, 0)]), shapely.LineString([(24, 0), (26, 2)]),  # end to end
             shapely.LineString([(22, 1), (22, 5)]),  # a T on the first one's vertex: meets it inside
             shapely.LineString([(30, 0), (34, 0)]), shapely.LineString([(32, 0), (36, 0)]),  # overlap
             shapely.LineString([(40, 0), (44, 4)]), shapely.LineString([(40, 0), (44, 4)]),  # duplicate
             shapely.LineString([(50, 0), (54, 4), (54, 0), (50, 4)])]  # crosses itself
    arcs = np.array(arcs, dtype=object)
    ok = shapely.is_simple(arcs)
    for i in range(len(arcs)):
        for j in range(i + 1, len(arcs)):
            ends = [shapely.MultiPoint([arcs[n].coords[0], arcs[n].coords[-1]]) for n in (i, j)]
            if not shapely.difference(shapely.intersection(arcs[i], arcs[j]), shapely.intersection(*ends)).is_empty:
                ok[i] = ok[j] = False
    got = _meets_only_at_ends(arcs)
    assert np.array_equal(got, ok)
    assert not got[14:].all() and got[15] and not got[16]  # the T's stem meets the first arc inside


def test_nearest_labels_far_from_the_points_are_the_kd_tree_query():
    """Cells far from every labelled point (an outline part without planes) are left to the k-d tree,
    not searched ring by ring across empty buckets."""
    from scipy.spatial import cKDTree

    from rooftrace.roof.faces import _nearest

    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 5, (400, 2))
    lab = rng.integers(0, 3, len(xy))
    cells = np.concatenate([rng.uniform(0, 5, (200, 2)), rng.uniform(200, 300, (300, 2))])
    got = lab[_nearest(xy, lab, cells, 8)]
    assert np.array_equal(got, lab[cKDTree(xy).query(cells, k=8)[1]])


def test_cells_along_steps_refined_put_fewer_points_under_the_other_level():
    """At a height step a cell of half the point spacing can hold points of both levels; split in four
    there, the faces put fewer labelled points under a face more than 0.1 m off their own plane, and
    still tile the outline."""
    model = models.terraced(angle=17)
    counts = {False: 0, True: 0}
    for seed in (1, 2, 3):
        xyz, _ = models.sample_roof(model, 10, 0.03, seed=seed)
        roof = roof_structure(xyz, model.outline)
        for refine in counts:
            counts[refine] += _misplaced_points_and_vertices(roof, xyz, model.outline.area, refine_steps=refine)[0]
    assert counts[True] <= counts[False] / 2  # measured: 0 against 6 points


def test_points_on_no_plane_stand_on_the_plane_just_under_them():
    """A point on no plane joins the face partition with the plane of its neighbours it stands on (at
    most ``rise`` above it, at most ``max_dz`` under it): a coping 0.3 m over the upper level, a gutter
    on the lower one; a wall point between the levels, or a point under both, joins none."""
    from rooftrace.roof.faces import attached_points

    planes = np.array([[0.0, 0.0, 1.0, -5.0], [0.0, 0.0, 1.0, -8.0]])  # lower level at 5 m, upper at 8 m
    g = np.stack(np.meshgrid(np.arange(0.0, 4.0, 0.5), np.arange(0.0, 4.0, 0.5)), -1).reshape(-1, 2)
    P = np.vstack([np.column_stack([g, np.full(len(g), 5.0)]), np.column_stack([g + [4.0, 0.0], np.full(len(g), 8.0)])])
    lab = np.repeat([0, 1], len(g))
    U = np.array([[4.0, 2.0, 8.3], [3.9, 2.0, 5.2], [4.0, 1.0, 6.5], [4.0, 3.0, 4.0]])
    xyz, which = attached_points(U, P, lab, planes, 8, 0.1, 0.5)
    assert xyz.tolist() == U[:2].tolist() and which.tolist() == [1, 0]


def _l_step(angle: float = 23.0):
    """An L-shaped upper level (9 m) round a lower square (5 m) in its corner: a step that turns a corner."""
    return models._build("l_step", [(0, 0), (14, 0), (14, 10), (0, 10)], [(9.0, 0, 0), (5.0, 0, 0)],
                         [(0, 0, 14, 5, [0]), (0, 5, 7, 10, [0]), (7, 5, 14, 10, [1])], [], [], (), angle)


def test_a_point_under_the_other_level_is_claimed_by_its_own_face():
    """Two levels 3 m apart meeting at x = 4: an upper point at x = 4.2 under the lower face is joined to the
    upper face by a wedge; another upper point with a lower-level point between it and its face keeps
    its face (the levels interleave there), and the lower point keeps its own; the faces still tile."""
    from rooftrace.roof.faces import claim_points, points_off_their_faces

    planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])
    outline = shapely.box(0, 0, 8, 6)
    faces = [shapely.box(0, 0, 4, 6), shapely.box(4, 0, 8, 6)]
    xyz = np.array([[3.8, 1.0, 8.0], [4.2, 1.0, 8.0],  # the upper level's edge row, one under the lower face
                    [3.8, 4.0, 8.0], [4.3, 4.0, 5.0], [4.6, 4.0, 8.0],  # an upper point beyond a lower one
                    [6.0, 1.0, 5.0], [6.0, 4.0, 5.0]])
    labels = np.array([0, 0, 0, 1, 0, 1, 1])
    before = points_off_their_faces(faces, [0, 1], xyz, labels, planes, radius=1.0)
    assert before.tolist() == [False, True, False, False, True, False, False]
    polys, ids = claim_points(faces, [0, 1], outline, xyz, labels, planes, radius=1.0, width=0.2)
    after = points_off_their_faces(polys, ids, xyz, labels, planes, radius=1.0)
    assert after.tolist() == [False, False, False, False, True, False, False]
    assert sum(p.area for p in polys) == pytest.approx(outline.area, rel=1e-9)
    assert shapely.union_all(polys).area == pytest.approx(outline.area, rel=1e-9)
    # a point farther than the radius from its plane's faces is no business of the faces
    assert not points_off_their_faces(polys, ids, xyz, labels, planes, radius=0.1)[4]


def test_a_wedge_that_cuts_a_small_face_in_two_takes_the_small_piece(monkeypatch):
    """Two levels 3 m apart meeting at x = 4, a sliver face of a third plane at the foot of the step: the upper
    point at x = 4.2 under the lower face has its wedge cut the sliver in two, which the claim of all wedges at
    once refuses at either width; claimed alone, the wedge takes the sliver's smaller piece with it, and the
    faces still tile the outline, each one polygon."""
    import rooftrace.roof.faces as faces_module
    from rooftrace.roof.faces import claim_points, points_off_their_faces

    planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0], [0.0, 0.0, 1.0, -6.5]])
    outline = shapely.box(0, 0, 8, 6)
    sliver = shapely.box(4.0, 0.7, 4.15, 1.3)
    faces = [shapely.box(0, 0, 4, 6), shapely.box(4, 0, 8, 6) - sliver, sliver]
    xyz = np.array([[3.8, 1.0, 8.0], [4.2, 1.0, 8.0], [6.0, 1.0, 5.0], [6.0, 4.0, 5.0]])
    labels = np.array([0, 0, 1, 1])
    assert points_off_their_faces(faces, [0, 1, 2], xyz, labels, planes, radius=1.0).tolist() == [
        False, True, False, False]
    polys, ids = claim_points(faces, [0, 1, 2], outline, xyz, labels, planes, radius=1.0, width=0.2)
    assert not points_off_their_faces(polys, ids, xyz, labels, planes, radius=1.0).any()
    assert ids == [0, 1, 2] and all(p.geom_type == "Polygon" for p in polys)
    assert 0 < polys[2].area < sliver.area / 2
    assert sum(p.area for p in polys) == pytest.approx(outline.area, rel=1e-9)
    assert shapely.union_all(polys).area == pytest.approx(outline.area, rel=1e-9)
    # a face a wedge covers whole goes with it or stays, never left empty
    speck = shapely.box(4.0, 0.95, 4.05, 1.05)
    specked = [faces[0], shapely.box(4, 0, 8, 6) - speck, speck]
    polys, ids = claim_points(specked, [0, 1, 2], outline, xyz, labels, planes, radius=1.0, width=0.2)
    assert min(p.area for p in polys) > 0
    assert sum(p.area for p in polys) == pytest.approx(outline.area, rel=1e-9)
    # the claim of all wedges at once alone leaves the point where it was
    monkeypatch.setattr(faces_module, "_claimed_singly", lambda polys, ids, *a, **k: (polys, ids))
    polys, ids = claim_points(faces, [0, 1, 2], outline, xyz, labels, planes, radius=1.0, width=0.2)
    assert points_off_their_faces(polys, ids, xyz, labels, planes, radius=1.0)[1]


@pytest.mark.parametrize("model", [models.terraced(angle=17), models.flat_annex(stair_house=True, angle=11), _l_step()],
                         ids=["terraced", "stair_house", "l_step"])
def test_every_labelled_point_near_its_face_lies_under_it_at_steps(model, monkeypatch):
    """The roof's faces keep their promise at height steps (three seeds): every labelled point with a face
    of its own plane within the point spacing (within twice that, unless a main roof plane's eave hides
    it) lies under a face of its plane or of one within 0.1 m of it, and the faces tile the outline; the
    LoD 2.2 solid keeps it for every such point more than the lattice's step (1 cm) inside its face."""
    import rooftrace.roof.structure as structure
    from rooftrace.model import build_model
    from rooftrace.model.measure import points_off_their_roof
    from rooftrace.roof.faces import points_off_their_faces, points_on_their_faces
    from rooftrace.roof.structure import RoofOptions

    def breaks():
        n = 0
        for seed in (1, 2, 3):
            xyz, _ = models.sample_roof(model, 10, 0.03, seed=seed)
            roof = roof_structure(xyz, model.outline)
            faces = [shapely.force_2d(f) for f in roof.faces]
            assert shapely.union_all(faces).area == pytest.approx(model.outline.area, rel=1e-6)
            n += int(points_off_their_faces(faces, roof.face_plane, xyz, roof.labels, roof.planes,
                                            radius=roof.spacing).sum())
            # and within the claim's radius, but for a lower return under a main roof plane's eave
            s = roof.spacing
            eaves = ~roof.plane_detail & (roof.plane_n * s**2 >= 2 * RoofOptions().min_area)
            n += int(points_off_their_faces(faces, roof.face_plane, xyz, roof.labels, roof.planes, radius=2 * s,
                                            hidden_within=s, overhanging=eaves).sum())
            solids = [p.lods["2.2"] for p in build_model(model.outline, roof, xyz, 0.0).parts]
            placed = points_on_their_faces(faces, roof.face_plane, xyz, roof.labels, roof.planes)
            assert placed.sum() > 0.9 * (roof.labels >= 0).sum()
            assert not (placed & points_off_their_roof(solids, xyz, roof.labels, roof.planes, max_dz=0.11)).any()
        return n

    assert breaks() == 0
    if model.name == "terraced":  # without the claim, a party-wall step leaves points under the other roof
        monkeypatch.setattr(structure, "claim_points", lambda polys, ids, *a, **k: (polys, ids))
        assert breaks() > 0  # measured: 5 points (seed 2)


def test_a_face_over_another_levels_points_goes_to_that_level():
    """Upper level 8 m, lower level 5 m, a block at 11 m.  A sliver of the lower level over an upper point is
    merged into the upper face around it; a face of the block over a lone lower point, with no face of the
    lower level beside it, takes the lower plane; a face over no point joins the neighbour sharing most edge;
    a point covered by a higher one counts for no face.  The faces still tile the outline."""
    from rooftrace.roof.faces import faces_off_their_points, fit_faces

    planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0], [0.0, 0.0, 1.0, -11.0]])
    outline = shapely.box(0, 0, 12, 6)
    sliver, block, empty = shapely.box(3.5, 1.5, 4, 2.5), shapely.box(1, 4, 2, 5), shapely.box(6, 0, 6.5, 0.4)
    faces = [shapely.box(0, 0, 4, 6) - sliver - block, shapely.box(4, 0, 8, 6) - empty, sliver, block,
             shapely.box(8, 0, 12, 6), empty]
    ids = [0, 2, 1, 2, 1, 0]
    xyz = np.array([[2.0, 2.0, 8.0], [3.8, 2.0, 8.0],  # the upper level, one point under the lower sliver
                    [6.0, 3.0, 11.0],  # the block
                    [1.5, 4.5, 5.0],  # a lower point under a face of the block
                    [10.0, 3.0, 5.0], [10.1, 3.0, 1.0]])  # the lower level, and a point under it (a wall's foot)
    labels = np.array([0, 0, 2, 1, 1, -1])
    before = faces_off_their_points(faces, ids, xyz, labels, planes, spacing=0.5)
    assert before.tolist() == [False, False, True, True, False, False]
    polys, out = fit_faces(faces, ids, xyz, labels, planes, spacing=0.5)
    assert not faces_off_their_points(polys, out, xyz, labels, planes, spacing=0.5).any()
    assert out == [0, 2, 1, 1]  # the sliver and the empty face merged, the block's face now the lower plane's
    assert polys[0].equals(shapely.box(0, 0, 4, 6) - block) and polys[1].equals(shapely.box(4, 0, 8, 6))
    assert sum(p.area for p in polys) == pytest.approx(outline.area, rel=1e-12)
    assert shapely.union_all(polys).area == pytest.approx(outline.area, rel=1e-12)
    # the lower point counts for no face once a point stands over it (a branch, 0.3 m off in plan) ...
    covered = np.vstack([xyz, [[2.2, 4.5, 11.0]]])
    covered[3, 0] = 1.9
    assert not faces_off_their_points(faces, ids, covered, np.r_[labels, -1], planes, spacing=0.5)[3]
    # ... unless that point may not hide it (a tree's crown a footprint took in)
    by = np.r_[np.ones(len(xyz), bool), False]
    assert faces_off_their_points(faces, ids, covered, np.r_[labels, -1], planes, spacing=0.5, detected=by)[3]


@pytest.mark.parametrize("model", [models.terraced(angle=17), models.flat_annex(stair_house=True, angle=11),
                                   models.gable_dormer(), models.hip(), models.gable(chimney=True),
                                   models.gable(vents=True)],
                         ids=["terraced", "stair_house", "dormer", "hip", "chimney", "vents"])
def test_every_face_fits_the_points_under_it(model):
    """Simulated roofs (three seeds): every face's plane lies within the step height of at least half of
    the top-surface points under it.  Carved in, small faces of another level over a few of a face's
    points (as a sliver merged into a small neighbour leaves them) break it; the step gives them back, the
    faces still tile the outline and the LoD 2.2 heights at the points are those of the roof before."""
    from rooftrace.roof.faces import faces_off_their_points, fit_faces

    for seed in (1, 2, 3):
        xyz, _ = models.sample_roof(model, 10, 0.03, seed=seed)
        roof = roof_structure(xyz, model.outline)
        faces = [shapely.force_2d(f) for f in roof.faces]
        assert not faces_off_their_points(faces, roof.face_plane, xyz, roof.labels, roof.planes,
                                          spacing=roof.spacing).any()
        # three squares of 0.3 m around points of the largest face, given to the plane farthest from them
        rng = np.random.default_rng(seed)
        big = int(np.argmax([f.area for f in faces]))
        inside = np.flatnonzero(shapely.contains_xy(faces[big].buffer(-0.5), xyz[:, 0], xyz[:, 1]))
        carved, ids = list(faces), list(roof.face_plane)
        for p in rng.choice(inside, 3, replace=False):
            sq = shapely.box(*(xyz[p, :2] - 0.15), *(xyz[p, :2] + 0.15))
            far = int(np.argmax(np.abs(plane_height(roof.planes, xyz[p, :2][None])[0] - xyz[p, 2])))
            carved[big] = carved[big] - sq
            carved.append(sq)
            ids.append(far)
        off = faces_off_their_points(carved, ids, xyz, roof.labels, roof.planes, spacing=roof.spacing)
        assert off[len(faces):].all()
        polys, out = fit_faces(carved, ids, xyz, roof.labels, roof.planes, spacing=roof.spacing)
        assert not faces_off_their_points(polys, out, xyz, roof.labels, roof.planes, spacing=roof.spacing).any()
        assert len(polys) == len(faces)
        assert shapely.union_all(polys).area == pytest.approx(model.outline.area, rel=1e-9)
        # the faces are the roof's again: the same plane over every point
        before, after = np.full(len(xyz), -1), np.full(len(xyz), -1)
        for f, k in zip(faces, roof.face_plane):
            before[shapely.contains_xy(f, xyz[:, 0], xyz[:, 1])] = k
        for f, k in zip(polys, out):
            after[shapely.contains_xy(f, xyz[:, 0], xyz[:, 1])] = k
        assert np.array_equal(before, after)


def test_the_detected_points_decide_what_a_small_face_fits():
    """A roof at 3 m under a tree's crown at 9 m, both planes: a small face of the crown over three crown
    points and two roof points goes to the roof when only the roof's points are the detection's building
    points (a footprint took the crown in), stays the crown's when all are; the crown's main face stays."""
    from rooftrace.roof.faces import faces_off_their_points, fit_faces

    planes = np.array([[0.0, 0.0, 1.0, -3.0], [0.0, 0.0, 1.0, -9.0]])
    small = shapely.box(4, 0, 5, 1)
    faces = [shapely.box(0, 0, 4, 4), shapely.box(4, 0, 8, 4) - small, small]
    xyz = np.array([[1.0, 1.0, 3.0], [2.0, 3.0, 3.0],  # the roof
                    [6.0, 2.0, 9.0], [7.0, 3.0, 9.0], [6.0, 3.5, 9.0], [5.5, 2.5, 9.0], [7.0, 1.0, 3.0],  # crown, roof
                    [4.2, 0.2, 9.0], [4.8, 0.8, 9.0], [4.5, 0.2, 9.0], [4.2, 0.8, 3.0], [4.8, 0.5, 3.0]])
    labels = np.array([0, 0, 1, 1, 1, 1, 0, 1, 1, 1, 0, 0])
    detected = labels == 0
    ids = [0, 1, 1]
    assert not faces_off_their_points(faces, ids, xyz, labels, planes, spacing=0.1).any()
    assert faces_off_their_points(faces, ids, xyz, labels, planes, spacing=0.1, detected=detected).tolist() == \
        [False, False, True]
    polys, out = fit_faces(faces, ids, xyz, labels, planes, spacing=0.1, detected=detected)
    assert out == [0, 1] and polys[0].equals(shapely.box(0, 0, 4, 4).union(small))


@pytest.mark.parametrize("seed", range(3))
def test_points_in_faces_are_the_tree_query_s_pairs(seed):
    """The points in (or on) each face, by face then point, are the pairs an STR tree's intersects query finds:
    points on shared edges and corners (a lattice) under both faces, a face with a hole, a face with no point."""
    rng = np.random.default_rng(seed)
    faces = [shapely.box(0, 0, 2, 2).difference(shapely.box(0.5, 0.5, 1.0, 1.0)), shapely.box(2, 0, 4, 2),
             shapely.box(0.5, 0.5, 1.0, 1.0), shapely.Polygon([(0, 2), (4, 2), (2, 3.5)]), shapely.box(10, 10, 11, 11)]
    xy = np.vstack([rng.uniform(-0.5, 4.5, (300, 2)), np.round(rng.uniform(0, 4, (200, 2)) * 2) / 2])
    at, of = points_in_faces(np.array(faces, dtype=object), xy)
    i, f = shapely.STRtree(faces).query(shapely.points(xy), predicate="intersects")
    assert sorted(zip(at.tolist(), of.tolist())) == sorted(zip(i.tolist(), f.tolist()))
    assert (np.lexsort((at, of)) == np.arange(len(at))).all()
