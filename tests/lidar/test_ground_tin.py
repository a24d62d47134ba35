import numpy as np
import pytest
from scipy.spatial import Delaunay

from rooftrace.errors import GeometryError
from rooftrace.lidar.ground_tin import locate, serpentine_order, triangulate


def _contains(pts, tri, q, eps=1e-9):
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]

    def side(u, v):
        return (v[:, 0] - u[:, 0]) * (q[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (q[:, 0] - u[:, 0])

    return (side(a, b) >= -eps) & (side(b, c) >= -eps) & (side(c, a) >= -eps)


def test_same_triangles_as_qhull_on_random_points(rng):
    xy = rng.uniform(0, 100, (2000, 2))
    order, tris, nbrs = triangulate(xy)
    ours = {tuple(sorted(order[t])) for t in tris}
    qhull = {tuple(sorted(t)) for t in Delaunay(xy).simplices}
    assert ours == qhull
    # counter-clockwise, starting at the smallest vertex, neighbours across the opposite edge
    p = xy[order]
    u, v = p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]]
    area = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    assert (area > 0).all() and (tris[:, 0] < tris[:, 1:].min(axis=1)).all()
    t, k = np.nonzero(nbrs >= 0)
    for ti, ki in zip(t[:200], k[:200]):
        edge = {tris[ti, (ki + 1) % 3], tris[ti, (ki + 2) % 3]}
        assert edge <= set(tris[nbrs[ti, ki]].tolist())


def test_locate_finds_the_containing_triangle_and_the_outside(rng):
    xy = rng.uniform(0, 100, (3000, 2))
    order, tris, nbrs = triangulate(xy)
    pts = xy[order]
    q = rng.uniform(-20, 120, (5000, 2))
    for walk in (np.arange(len(q)), serpentine_order(q, 10.0), rng.permutation(len(q))):
        t = np.empty(len(q), np.int64)
        t[walk] = locate(pts, tris, nbrs, q[walk])
        inside = Delaunay(xy).find_simplex(q) >= 0
        assert ((t >= 0) == inside).all()
        assert _contains(pts, tris[t[inside]], q[inside]).all()
    assert locate(pts, tris, nbrs, np.array([[np.nan, 1.0]]))[0] == -1


def test_a_point_on_an_edge_gets_the_same_triangle_whatever_else_is_triangulated():
    # a grid: every query on the x = 1 line lies on a triangle edge; the
    # points far away change the numbering but not the triangle chosen
    g = np.array([[x, y] for x in range(4) for y in range(4)], float) + [[0.0, 0.013]] * 16
    g[:, 1] += 0.001 * g[:, 0] ** 2  # break the co-circularity of the square cells
    q = np.array([[1.0, 0.5 + 0.013 + 0.001], [1.0, 1.5 + 0.014]])
    found = []
    for extra in (np.empty((0, 2)), np.array([[50.0, 50.0], [-40.0, 7.0], [20.0, -30.0]])):
        xy = np.concatenate([extra, g])
        order, tris, nbrs = triangulate(xy)
        t = locate(xy[order], tris, nbrs, q)
        found.append([tuple(np.round(xy[order][tris[i]], 9).ravel()) for i in t])
        # and whatever the walk came from
        t2 = locate(xy[order], tris, nbrs, q[::-1])[::-1]
        assert (t2 == t).all()
    assert found[0] == found[1]


def test_errors():
    with pytest.raises(GeometryError, match="collinear"):
        triangulate(np.column_stack([np.arange(5.0), np.arange(5.0)]))
    with pytest.raises(GeometryError, match="fewer than 3"):
        triangulate(np.zeros((2, 2)))
