"""Constructed roofs with known volumes, shared by the model tests."""

from __future__ import annotations

import numpy as np
import shapely

from rooftrace.model.solid import horizontal_plane


def plane_through(p0, p1, p2) -> np.ndarray:
    """The plane (a, b, c, d), c > 0, through three points."""
    p0, p1, p2 = (np.asarray(p, dtype=np.float64) for p in (p0, p1, p2))
    n = np.cross(p1 - p0, p2 - p0)
    n /= np.linalg.norm(n)
    if n[2] < 0:
        n = -n
    return np.r_[n, -n @ p0]


def box():
    """10 x 8 m, flat at 6 m: 480 m³ over ground 0."""
    return [(shapely.box(0, 0, 10, 8), horizontal_plane(6.0))], 480.0


def ell():
    """An L of 10 x 4 + 4 x 6 m, flat at 5 m."""
    return [(shapely.Polygon([(0, 0), (10, 0), (10, 4), (4, 4), (4, 10), (0, 10)]), horizontal_plane(5.0))], 64 * 5.0


def courtyard():
    """20 x 20 m with a 10 x 10 m courtyard, flat at 10 m over ground 1."""
    ring = shapely.box(0, 0, 20, 20).difference(shapely.box(5, 5, 15, 15))
    return [(ring, horizontal_plane(10.0))], 300 * 9.0


def gable():
    """10 x 8 m, eaves at 6 m, ridge along y = 4 at 9 m."""
    a = plane_through((0, 0, 6), (10, 0, 6), (0, 4, 9))
    b = plane_through((0, 8, 6), (10, 8, 6), (0, 4, 9))
    return [(shapely.box(0, 0, 10, 4), a), (shapely.box(0, 4, 10, 8), b)], 480.0 + 0.5 * 8 * 3 * 10


def hip():
    """12 x 8 m, eaves at 5 m, ridge (4, 4)-(8, 4) at 8 m."""
    r1, r2 = (4, 4), (8, 4)
    faces = [shapely.Polygon([(0, 0), (12, 0), r2, r1]), shapely.Polygon([(12, 0), (12, 8), r2]),
             shapely.Polygon([(12, 8), (0, 8), r1, r2]), shapely.Polygon([(0, 8), (0, 0), r1])]
    planes = [plane_through((0, 0, 5), (12, 0, 5), (4, 4, 8)), plane_through((12, 0, 5), (12, 8, 5), (8, 4, 8)),
              plane_through((12, 8, 5), (0, 8, 5), (4, 4, 8)), plane_through((0, 8, 5), (0, 0, 5), (4, 4, 8))]
    return list(zip(faces, planes)), 480.0 + 3 * 8 / 6 * (2 * 12 + 4)


def stepped():
    """Three flat blocks at 6, 9 and 4 m: steps between them."""
    return [(shapely.box(0, 0, 5, 8), horizontal_plane(6.0)), (shapely.box(5, 0, 10, 8), horizontal_plane(9.0)),
            (shapely.box(2, 8, 8, 12), horizontal_plane(4.0))], 40 * 6 + 40 * 9 + 24 * 4.0


def curved():
    """A round tower of radius 5 m, flat at 10 m; the outline faceted every ~0.25 m."""
    disk = shapely.Point(0, 0).buffer(5.0, quad_segs=32)
    return [(disk, horizontal_plane(10.0))], disk.area * 10.0


def crossing():
    """Two sloped faces whose planes cross along their shared edge (the wall between changes side)."""
    a = plane_through((0, 0, 5), (0, 8, 5), (5, 0, 4))
    b = plane_through((5, 0, 6), (5, 8, 3), (10, 0, 6))
    za = lambda x, y: 5 - 0.2 * x  # noqa: E731
    del za
    return [(shapely.box(0, 0, 5, 8), a), (shapely.box(5, 0, 10, 8), b)], None


def saddle():
    """Four flat quarters, high-low-high-low around the centre (four walls would meet on one edge)."""
    return [(shapely.box(0, 0, 5, 5), horizontal_plane(8.0)), (shapely.box(5, 0, 10, 5), horizontal_plane(5.0)),
            (shapely.box(5, 5, 10, 10), horizontal_plane(8.0)), (shapely.box(0, 5, 5, 10), horizontal_plane(5.0))], None


def pinch():
    """A flat roof whose hole (a lower roof) touches its outer ring at one vertex."""
    hole = [(0, 5), (3, 3), (3, 7)]
    outer = shapely.Polygon([(0, 0), (10, 0), (10, 10), (0, 10)], [hole])
    assert outer.is_valid
    return [(outer, horizontal_plane(8.0)), (shapely.Polygon(hole), horizontal_plane(5.0))], 100 * 8.0 - 6 * 3.0


CASES = {"box": box, "ell": ell, "courtyard": courtyard, "gable": gable, "hip": hip, "stepped": stepped,
         "curved": curved, "crossing": crossing, "saddle": saddle, "pinch": pinch}
GROUND = {"courtyard": 1.0}
