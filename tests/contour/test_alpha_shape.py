import numpy as np
import pytest
import shapely
from scipy.spatial import cKDTree

from rooftrace.contour.alpha_shape import AlphaOptions, alpha_reach, alpha_shape, boundary_edges, trace_rings
from rooftrace.contour.spacing import PlanMesh, building_alpha, delaunay_edges, point_spacing
from rooftrace.errors import GeometryError
from tests.contour.shapes import COURTYARD, L_SHAPE, RECT, sample


def _polygon(xy, shape):
    return shapely.Polygon(xy[shape.rings[0]], [xy[r] for r in shape.rings[1:]])


def _signed_area(xy):
    return 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])


@pytest.mark.parametrize("strategy", ["global", "building", "point"])
@pytest.mark.parametrize("truth", [RECT, L_SHAPE], ids=["rect", "L"])
def test_outer_ring_closed_ccw_and_close_to_truth(strategy, truth):
    xyz = sample(truth, 10)
    shape = alpha_shape(xyz[:, :2], AlphaOptions(strategy=strategy), mean_spacing=1 / np.sqrt(10))
    assert len(shape.rings) == 1
    ring = xyz[shape.rings[0], :2]
    assert _signed_area(ring) > 0  # counter-clockwise
    poly = _polygon(xyz[:, :2], shape)
    assert poly.is_valid
    # the boundary runs through the outermost points: inside the truth, about half a spacing in
    # (at a reflex corner the boundary may cut across it)
    assert truth.buffer(0.5).contains(poly)
    assert poly.difference(truth).area < 0.5
    assert 0.9 * truth.area < poly.area < truth.area
    assert shapely.hausdorff_distance(poly.exterior, truth.exterior) < 0.6


def test_courtyard_is_a_clockwise_hole():
    xyz = sample(COURTYARD, 10)
    shape = alpha_shape(xyz[:, :2], AlphaOptions(strategy="point"))
    assert len(shape.rings) == 2
    hole = xyz[shape.rings[1], :2]
    assert _signed_area(hole) < 0
    assert abs(-_signed_area(hole) - 48) < 6  # 8 x 6 m, grown by about half a spacing per side


def test_small_gaps_do_not_become_courtyards():
    xyz = sample(RECT, 10)
    gap = (np.hypot(xyz[:, 0] - 10, xyz[:, 1] - 6) < 0.8)  # a 2 m² patch without returns
    shape = alpha_shape(xyz[~gap, :2], AlphaOptions(strategy="building", min_hole_area=4.0))
    assert len(shape.rings) == 1
    shape = alpha_shape(xyz[~gap, :2], AlphaOptions(strategy="building", min_hole_area=0.5))
    assert len(shape.rings) == 2


def test_density_change_global_alpha_breaks_point_alpha_holds():
    # thesis fig. 1.2: 16 pts/m² on the left half, 4 pts/m² on the right (strip overlap)
    xyz = sample(RECT, 16, density_right=4, seed=3)
    dense_spacing = 1 / np.sqrt(16)
    s1 = alpha_shape(xyz[:, :2], AlphaOptions(strategy="global", scale=1.0), mean_spacing=dense_spacing)
    s2 = alpha_shape(xyz[:, :2], AlphaOptions(strategy="building", scale=1.0))
    s3 = alpha_shape(xyz[:, :2], AlphaOptions(strategy="point", scale=1.0))
    a3 = _polygon(xyz[:, :2], s3).area
    # the sparse half falls apart with one alpha for the whole building
    assert _polygon(xyz[:, :2], s1).area < 0.6 * RECT.area
    assert _polygon(xyz[:, :2], s2).area < 0.6 * RECT.area
    assert a3 > 0.9 * RECT.area
    assert len(s3.rings) == 1
    assert s3.spacing[xyz[:, 0] > 14].mean() > 1.8 * s3.spacing[xyz[:, 0] < 6].mean()


def test_boundary_edges_match_brute_force_circle_test(rng):
    xy = rng.uniform(0, 10, (120, 2))
    edges, lengths = delaunay_edges(xy)
    alpha = 1.1
    got = {tuple(e) for e in boundary_edges(xy, edges, alpha)}
    want = set()
    for i, j in edges:
        d = xy[j] - xy[i]
        s2 = d @ d
        if s2 > 4 * alpha**2:
            continue
        h = np.sqrt(alpha**2 / s2 - 0.25)
        mid = xy[i] + 0.5 * d
        c_right = mid + h * np.array([d[1], -d[0]])
        c_left = mid - h * np.array([d[1], -d[0]])
        others = np.delete(xy, [i, j], axis=0)
        right_empty = np.all(np.hypot(*(others - c_right).T) >= alpha)
        left_empty = np.all(np.hypot(*(others - c_left).T) >= alpha)
        if right_empty and not left_empty:
            want.add((i, j))
        elif left_empty and not right_empty:
            want.add((j, i))
    assert got == want and len(want) > 10


def test_building_alpha_drops_long_edges():
    lengths = np.concatenate([np.full(200, 0.3), [5.0]])
    assert building_alpha(lengths) == pytest.approx(0.3)


def test_point_spacing_matches_brute_force(rng):
    xy = rng.uniform(0, 8, (150, 2))
    edges, lengths = delaunay_edges(xy)
    got = point_spacing(xy, edges, lengths, radius=2.0)
    for i in (0, 7, 42):
        inside = np.hypot(*(xy - xy[i]).T) <= 2.0
        sel = inside[edges[:, 0]] & inside[edges[:, 1]]
        assert got[i] == pytest.approx(lengths[sel].mean())


def test_point_spacing_sums_in_the_scan_order(rng):
    # ps_avg is one sequential sum per point, in the order of a scan of the 3 x 3 cells (by cell, then by
    # point order within a cell, then each point's edges): another order moves it by 1e-15, which once
    # changed an outline.  The compiled kernel (four sums side by side) must give these sums bit for bit,
    # for a point count that is not a multiple of four too.
    xy = rng.uniform(0, 8, (151, 2))
    edges, lengths = delaunay_edges(xy)
    radius = 2.0
    got = point_spacing(xy, edges, lengths, radius=radius)
    cell = np.floor((xy - xy.min(axis=0)) / radius).astype(int)
    by_cell = {}
    for j in np.argsort(cell[:, 0] * 1000 + cell[:, 1], kind="stable"):
        by_cell.setdefault(tuple(cell[j]), []).append(j)
    low = edges[:, 0]  # each edge is met at its first end point, in edge order
    for i in range(len(xy)):
        total, count = 0.0, 0
        for cx in range(cell[i, 0] - 1, cell[i, 0] + 2):
            for cy in range(cell[i, 1] - 1, cell[i, 1] + 2):
                for j in by_cell.get((cx, cy), []):
                    if (xy[j, 0] - xy[i, 0]) ** 2 + (xy[j, 1] - xy[i, 1]) ** 2 > radius**2:
                        continue
                    for e in np.flatnonzero(low == j):
                        h = edges[e, 1]
                        if (xy[h, 0] - xy[i, 0]) ** 2 + (xy[h, 1] - xy[i, 1]) ** 2 <= radius**2:
                            total += lengths[e]
                            count += 1
        assert got[i] == total / count


def _triangle_set(triangles):
    t = np.sort(np.asarray(triangles), axis=1)
    return t[np.lexsort(t.T[::-1])]


def test_delaunay_mesh_is_qhulls_mesh_whichever_library_made_it(rng):
    from scipy.spatial import Delaunay

    from rooftrace.contour.spacing import _certified_triangle_mesh, delaunay_mesh

    scattered = rng.uniform(0, 40, (2000, 2))  # in a building's local frame: Triangle's mesh, certified
    grid = np.mgrid[0:10:0.5, 0:6:0.5].reshape(2, -1).T.astype(float)  # four points on every circle
    far = scattered + [85_000.0, 446_000.0]  # national-grid coordinates: Qhull's round-off decides
    assert _certified_triangle_mesh(scattered) is not None
    assert _certified_triangle_mesh(grid) is None
    assert _certified_triangle_mesh(far) is None
    for xy in (scattered, grid, far):
        edges, lengths, triangles, neighbours = delaunay_mesh(xy)
        assert np.array_equal(_triangle_set(triangles), _triangle_set(Delaunay(xy).simplices))
        a, b, c = (xy[triangles[:, k]] for k in range(3))
        assert ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] > 0).all()  # counter-clockwise
        # the neighbour opposite corner k shares the other two corners
        t, k = np.nonzero(neighbours >= 0)
        for ti, ki in zip(t[:200], k[:200]):
            u = neighbours[ti, ki]
            assert {triangles[ti, (ki + 1) % 3], triangles[ti, (ki + 2) % 3]} <= set(triangles[u])
        assert len(edges) == len(lengths) and (edges[:, 0] < edges[:, 1]).all()
    # Triangle is not asked where it could crash (it did on 18 copies of one point): Qhull decides
    for degenerate in (np.tile([2.0, 3.0], (18, 1)), np.column_stack([np.arange(9.0), 2.0 * np.arange(9.0)])):
        assert _certified_triangle_mesh(degenerate) is None
        with pytest.raises(GeometryError):
            delaunay_mesh(degenerate)
    assert _certified_triangle_mesh(np.concatenate([scattered, scattered[:3]])) is None  # a point twice


def test_degenerate_input_raises_geometry_error():
    with pytest.raises(GeometryError, match="too_few_points"):
        alpha_shape(np.zeros((2, 2)))
    line = np.column_stack([np.arange(10.0), np.arange(10.0)])
    with pytest.raises(GeometryError, match="collinear"):
        alpha_shape(line)


def test_bad_option_names_value():
    with pytest.raises(ValueError, match="strategy"):
        AlphaOptions(strategy="triangle")


def test_trace_rings_keeps_a_ring_whose_walk_starts_on_a_doubled_stretch():
    # square 1-2-3-4 (counter-clockwise) with a second chain 2 -> 0 -> 3 beside its east side;
    # the walk starts at vertex 0, comes round to 2, takes 2 -> 3 and is stuck at 3
    # (its edge used): it used to drop the whole square (a Delft block lost its outer ring)
    xy = np.array([[11.0, 5.0], [0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    directed = np.array([[1, 2], [2, 3], [3, 4], [4, 1], [2, 0], [0, 3]])
    rings = trace_rings(xy, directed)
    assert len(rings) == 1
    assert sorted(rings[0].tolist()) == [0, 1, 2, 3, 4]
    assert abs(_signed_area(xy[rings[0]])) >= 100.0


def test_a_shared_mesh_traces_the_same_shapes_as_a_fresh_one(rng):
    xy = rng.uniform(0, 20, (600, 2))
    xy = xy[~((xy[:, 0] > 8) & (xy[:, 0] < 12) & (xy[:, 1] > 8) & (xy[:, 1] < 12))]  # a courtyard
    mesh = PlanMesh(xy)
    for strategy in ("point", "building"):
        for scale in (1.0, 1.5):
            fresh = alpha_shape(xy, AlphaOptions(strategy=strategy, min_hole_area=1.0), alpha_scale=scale)
            shared = alpha_shape(xy, AlphaOptions(strategy=strategy, min_hole_area=1.0), alpha_scale=scale, mesh=mesh)
            assert [r.tolist() for r in shared.rings] == [r.tolist() for r in fresh.rings]
            np.testing.assert_array_equal(shared.spacing, fresh.spacing)
    assert len(mesh._spacing) == 1  # ps_avg computed once for the two point-strategy shapes
    with pytest.raises(ValueError):
        alpha_shape(xy[:-1], mesh=mesh)


@pytest.mark.parametrize("strategy", ["point", "building", "global"])
def test_nothing_of_the_shape_lies_beyond_its_reach(rng, strategy):
    # sparse points and a large alpha: big triangles, whose middles lie far from every point
    xy = rng.uniform(0, 20, (60, 2))
    mesh = PlanMesh(xy)
    options = AlphaOptions(strategy=strategy, scale=1.0)
    shape = alpha_shape(xy, options, mean_spacing=2.5, alpha_scale=1.5, mesh=mesh)
    polygon = _polygon(xy, shape)
    reach = alpha_reach(mesh, options, mean_spacing=2.5, alpha_scale=1.5)
    grid = np.mgrid[0:20:0.05, 0:20:0.05].reshape(2, -1).T
    inside = grid[shapely.contains_xy(polygon, grid[:, 0], grid[:, 1])]
    farthest = cKDTree(xy).query(inside)[0].max()
    assert 0.25 * reach < farthest <= reach  # the bound holds, and is not far off
    assert alpha_reach(mesh, options, mean_spacing=2.5, alpha_scale=3.0) == pytest.approx(2 * reach)
