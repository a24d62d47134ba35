"""TIN interpolation and the roof heights at eaves (issue 8)."""

import numpy as np
import pytest

from rooftrace.errors import GeometryError
from rooftrace.snake.surface import Tin, roof_surface, vertex_heights


def _box_roof(rng, slope=0.0, n=6000):
    """Points over 40 x 40 m: ground z=0, a 10 x 12 m roof at z = 8 + slope * x."""
    xy = rng.uniform(0, 40, (n, 2))
    inside = (xy[:, 0] > 15) & (xy[:, 0] < 25) & (xy[:, 1] > 14) & (xy[:, 1] < 26)
    z = np.where(inside, 8.0 + slope * (xy[:, 0] - 15), 0.0)
    ring = np.array([[15.0, 14.0], [25.0, 14.0], [25.0, 26.0], [15.0, 26.0]])
    return np.column_stack([xy, z]), ring


def test_tin_exact_on_a_plane(rng):
    xy = rng.uniform(1e5, 1e5 + 50, (500, 2))  # map-sized coordinates
    plane = lambda p: 3.0 + 0.2 * (p[:, 0] - 1e5) - 0.1 * (p[:, 1] - 1e5)  # noqa: E731
    tin = Tin(np.column_stack([xy, plane(xy)]))
    q = rng.uniform(1e5 + 10, 1e5 + 40, (2000, 2))
    np.testing.assert_allclose(tin(q), plane(q), atol=1e-9)


def test_tin_linear_inside_a_triangle_and_nan_outside():
    tin = Tin(np.array([[0, 0, 0], [10, 0, 10], [0, 10, 20.0]]))
    z = tin(np.array([[2.0, 3.0], [0.0, 0.0], [9.0, 9.0], [-1.0, 5.0]]))
    np.testing.assert_allclose(z[:2], [2.0 + 6.0, 0.0])
    assert np.isnan(z[2:]).all()


def test_tin_grid_equals_pointwise(rng):
    xyz = np.column_stack([rng.uniform(0, 30, (800, 2)), rng.normal(0, 2, 800)])
    tin = Tin(xyz)
    g = tin.grid(-2.0, -2.0, 0.37, 95, 90)
    gx, gy = np.meshgrid(-2.0 + 0.37 * np.arange(95), -2.0 + 0.37 * np.arange(90))
    ref = tin(np.column_stack([gx.ravel(), gy.ravel()])).reshape(g.shape)
    np.testing.assert_allclose(g, ref, atol=1e-9)
    assert np.isnan(g[0, 0]) and np.isfinite(g[40, 40])


def test_tin_independent_of_point_order(rng):
    xyz, _ = _box_roof(rng)
    q = rng.uniform(5, 35, (300, 2))
    a = Tin(xyz)(q)
    b = Tin(xyz[rng.permutation(len(xyz))])(q)
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_tin_spacing_matches_density(rng):
    tin = Tin(np.column_stack([rng.uniform(0, 50, (10000, 2)), np.zeros(10000)]))
    # Poisson points at 4 pts/m^2: median Delaunay edge ~ 0.5 m
    assert 0.35 < tin.spacing() < 0.6


def test_tin_rejects_degenerate():
    with pytest.raises(GeometryError):
        Tin(np.array([[0, 0, 0], [1, 1, 0], [2, 2, 0.0]]))
    with pytest.raises(GeometryError, match="at least 3"):
        Tin(np.zeros((2, 3)))


def test_plain_tin_blends_the_eave_but_roof_surface_does_not(rng):
    xyz, ring = _box_roof(rng)
    tin = Tin(xyz)
    eave = np.column_stack([np.linspace(16, 24, 50), np.full(50, 14.0)])
    assert tin(eave).mean() < 7.0  # the blend the module docstring is about
    surf = roof_surface(tin, (5, 5, 35, 35), cell=0.2, radius=1.0)
    np.testing.assert_allclose(surf(eave), 8.0, atol=1e-9)
    assert surf(np.array([[5.0, 5.0]]))[0] == pytest.approx(0.0)


@pytest.mark.parametrize("slope", [0.0, 0.4])
def test_vertex_heights_exact_on_planar_roofs(rng, slope):
    xyz, ring = _box_roof(rng, slope)
    tin = Tin(xyz)
    z = vertex_heights(tin, ring, offset=tin.spacing())
    truth = 8.0 + slope * (ring[:, 0] - 15)
    np.testing.assert_allclose(z, truth, atol=1e-6)
    z_cw = vertex_heights(tin, ring[::-1], offset=tin.spacing())  # orientation does not matter
    np.testing.assert_allclose(z_cw, truth[::-1], atol=1e-6)
    assert np.abs(tin(ring) - truth).max() > 1.0  # the plain TIN would be wrong here


def test_vertex_heights_on_reflex_corner(rng):
    xy = rng.uniform(0, 40, (8000, 2))
    l_ring = np.array([[10, 10], [30, 10], [30, 18], [18, 18], [18, 30], [10, 30.0]])
    import shapely

    inside = shapely.contains_xy(shapely.Polygon(l_ring), xy[:, 0], xy[:, 1])
    tin = Tin(np.column_stack([xy, np.where(inside, 6.0, 0.0)]))
    np.testing.assert_allclose(vertex_heights(tin, l_ring, tin.spacing()), 6.0, atol=1e-6)


def test_vertex_heights_from_a_vertex_just_outside_the_roof(rng):
    # regression (issue 8 benchmark): a corner 0.5 m outside the eave starts on
    # clean ground triangles; mixing them with roof samples gave Z metres low
    xyz, ring = _box_roof(rng, slope=0.2, n=12000)
    tin = Tin(xyz)
    outside = ring + np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    z = vertex_heights(tin, outside, offset=tin.spacing())
    truth = 8.0 + 0.2 * (outside[:, 0] - 15)  # the roof plane continued
    np.testing.assert_allclose(z, truth, atol=1e-6)
