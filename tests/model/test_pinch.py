"""prism_solid where faces or the outline touch themselves at one point: always a valid solid."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rooftrace.errors import GeometryError
from rooftrace.model import horizontal_plane, prism_solid, solid_errors, solid_volume

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
SNAP = 0.01
#: a bound of the area a notch takes from (or adds to) this test's footprints: the octagon of radius 2 snap, and the
#: slivers of its new vertices rounded to the lattice (half a step off, pivoting the edges they end, 3 to 4 m long)
NOTCH = 8 * np.sin(np.pi / 4) / 2 * (2 * SNAP) ** 2 + 2 * 4.0 * SNAP / 2


def _pinched():
    """10 x 10 m whose hole (a courtyard) touches the outer ring at (0, 5), as Delft LiDAR-only building 126's
    outline variant did."""
    fp = shapely.Polygon([(0, 0), (10, 0), (10, 10), (0, 10)], [[(0, 5), (3, 3), (3, 7)]])
    assert fp.is_valid
    return fp


def test_a_hole_touching_the_shell_gives_valid_solids_at_every_level():
    fp = _pinched()
    lod12 = prism_solid([(fp, horizontal_plane(8.0))], 0.0, footprint=fp)
    assert solid_errors(lod12) == []
    assert solid_volume(lod12) == pytest.approx(fp.area * 8.0, abs=NOTCH * 8.0)
    halves = [(fp.intersection(shapely.box(0, 0, 10, 5)), horizontal_plane(8.0)),
              (fp.intersection(shapely.box(0, 5, 10, 10)), horizontal_plane(6.0))]
    two = prism_solid(halves, 0.0, footprint=fp)
    assert solid_errors(two) == []
    assert solid_volume(two) == pytest.approx(fp.area / 2 * 14.0, abs=NOTCH * 8.0)


def test_a_footprint_not_touching_itself_is_left_as_it_is():
    from rooftrace.model.solid import _unpinched

    fp = shapely.box(0, 0, 10, 8).difference(shapely.box(3, 3, 5, 5))
    assert _unpinched(fp, SNAP) is fp


def test_the_notch_opens_the_hole_and_stays_within_two_lattice_steps():
    from rooftrace.model.solid import _pinch_points, _unpinched

    fp = _pinched()
    out = _unpinched(fp, SNAP)
    assert out.geom_type == "Polygon" and len(out.interiors) == 0  # the courtyard opens onto the outside
    assert not len(_pinch_points(out))
    assert shapely.symmetric_difference(fp, out).area <= NOTCH
    # the outline moves by the notch's radius at most, and its rounding to the lattice
    assert shapely.hausdorff_distance(fp.boundary, out.boundary) <= 2 * SNAP + SNAP / np.sqrt(2) + 1e-9


def test_two_holes_touching_at_one_point_become_one():
    from rooftrace.model.solid import _unpinched

    fp = shapely.Polygon([(0, 0), (10, 0), (10, 10), (0, 10)], [[(2, 2), (5, 5), (2, 5)], [(5, 5), (8, 8), (8, 5)]])
    assert fp.is_valid
    out = _unpinched(fp, SNAP)
    assert len(out.interiors) == 1
    assert solid_errors(prism_solid([(fp, horizontal_plane(5.0))], 0.0, footprint=fp)) == []


def test_a_lobe_touching_the_footprint_at_a_corner_is_dropped_or_joined():
    """A part's footprint cut from a building's arrangement was a polygon and a lobe of a few cm² touching it at a
    corner (IGN with s/4 faces): the part lost every level ("the footprint falls into 2 pieces")."""
    from rooftrace.model.solid import SLIVER_AREA, _unpinched

    main = shapely.box(0, 0, 6, 4)
    for lobe, kept in ((shapely.box(6, 4, 6.1, 4.2), False), (shapely.box(6, 4, 8, 6), True)):
        fp = shapely.MultiPolygon([main, lobe])
        assert fp.is_valid and (lobe.area >= SLIVER_AREA) == kept
        out = _unpinched(fp, SNAP)
        assert out.geom_type == "Polygon" and out.contains(main.buffer(-1e-9))
        assert out.contains(lobe.buffer(-1e-9)) == kept
        solid = prism_solid([(main, horizontal_plane(6.0)), (lobe, horizontal_plane(5.0))], 0.0, footprint=fp)
        assert solid_errors(solid) == []
        assert solid_volume(solid) == pytest.approx(main.area * 6.0 + kept * lobe.area * 5.0, abs=NOTCH * 6.0)
    with pytest.raises(GeometryError, match="falls into 2 pieces"):  # pieces apart are not one solid
        far = shapely.MultiPolygon([main, shapely.box(7, 0, 9, 2)])
        prism_solid([(far, horizontal_plane(6.0))], 0.0, footprint=far)


def _raster_partition(seed: int, n: int, size: float, levels: int = 4):
    """Random faces on an ``n`` x ``n`` raster of ``size`` m cells: one height level per cell (half of the
    faces tilted), some cells left out of the footprint, faces and holes meeting at corners (saddles,
    faces touching themselves, holes touching the shell, pieces of the footprint touching at corners)."""
    rng = np.random.default_rng(seed)
    level = rng.integers(0, levels, (n, n))
    inside = rng.random((n, n)) > 0.15
    inside[n // 2, n // 2] = True
    boxes: dict[int, list] = {}
    for i, j in zip(*np.nonzero(inside)):
        boxes.setdefault(int(level[i, j]), []).append(shapely.box(i * size, j * size, (i + 1) * size, (j + 1) * size))
    fp = shapely.union_all([b for v in boxes.values() for b in v])
    pieces = sorted(shapely.get_parts(fp), key=lambda g: -g.area)
    # pieces touching the largest at corners stay (lobes to drop or join), the others go
    fp = shapely.union_all([g for g in pieces if shapely.intersects(g, pieces[0])])
    return _cells(rng, boxes, fp), fp


def _lines_partition(seed: int, size: float, n_lines: int = 8, levels: int = 4):
    """Random faces from an arrangement of ``n_lines`` random lines over a random outline (``size`` m across,
    a third of them with a hole touching the shell): narrow sectors, faces meeting at points at any angle."""
    rng = np.random.default_rng(seed)
    angle = np.sort(rng.uniform(0, 2 * np.pi, 9))
    radius = rng.uniform(0.5, 1.0, 9) * size / 2
    fp = shapely.Polygon(np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])).buffer(0)
    fp = max(shapely.get_parts(fp), key=lambda g: g.area)
    if rng.random() < 0.3:
        c = shapely.get_coordinates(fp.exterior)[0]
        fp = fp.difference(shapely.Polygon([c, c / 2 + rng.normal(0, size / 20, 2), c / 2 + rng.normal(0, size / 20, 2)]))
        fp = max(shapely.get_parts(fp), key=lambda g: g.area)
    lines = []
    for _ in range(n_lines):
        p, a = rng.uniform(-size / 2, size / 2, 2), rng.uniform(0, np.pi)
        d = np.array([np.cos(a), np.sin(a)]) * size * 2
        lines.append(shapely.LineString([p - d, p + d]))
    pieces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.union_all([fp.boundary, *lines]))))
    pieces = [g for g in pieces if fp.contains(g.point_on_surface())]
    level = rng.integers(0, levels, len(pieces))
    boxes: dict[int, list] = {}
    for g, k in zip(pieces, level.tolist()):
        boxes.setdefault(k, []).append(g)
    return _cells(rng, boxes, fp), fp


def _cells(rng, pieces: dict, fp) -> list:
    cells = []
    for k, group in sorted(pieces.items()):
        for g in shapely.get_parts(shapely.intersection(shapely.union_all(group), fp)):
            if g.geom_type != "Polygon" or g.area == 0:
                continue
            h = 4.0 + 1.5 * k
            if rng.random() < 0.5:
                gx, gy = rng.normal(0, 0.3, 2)
                xy = shapely.get_coordinates(g) - [g.centroid.x, g.centroid.y]
                h += max(0.0, 1.0 - float((h - xy @ [gx, gy]).min()))  # a metre over the ground at least
                plane = np.array([gx, gy, 1.0, -h - gx * g.centroid.x - gy * g.centroid.y])
            else:
                plane = horizontal_plane(h)
            cells.append((g, plane))
    return cells


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 10), size=st.sampled_from([0.05, 0.3, 1.0]))
def test_random_small_face_rasters_give_valid_solids(seed, n, size):
    cells, fp = _raster_partition(seed, n, size)
    assert solid_errors(prism_solid(cells, 0.0, footprint=fp)) == []


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), size=st.sampled_from([2.0, 10.0, 30.0]))
def test_random_line_arrangements_give_valid_solids(seed, size):
    cells, fp = _lines_partition(seed, size)
    assert solid_errors(prism_solid(cells, 0.0, footprint=fp)) == []


@pytest.mark.parametrize("seed, size, n_lines", [(274, 10.0, 6), (217, 2.0, 6)])
def test_a_footprint_pinched_in_a_narrow_wedge(seed, size, n_lines):
    """Outlines whose pinch lies in a wedge of a few degrees, under a lattice step wide for decimetres: notches of 2,
    4 and 8 steps left a new pinch at their own edge (two of 400 random arrangements); the notch grows up to 64."""
    from rooftrace.model.solid import _pinch_points, _unpinched

    cells, fp = _lines_partition(seed, size, n_lines=n_lines)
    out = _unpinched(fp, SNAP)
    assert len(_pinch_points(shapely.set_precision(fp, SNAP))) and not len(_pinch_points(out))
    assert shapely.hausdorff_distance(shapely.set_precision(fp, SNAP).boundary, out.boundary) <= 64 * SNAP * 1.1
    assert solid_errors(prism_solid(cells, 0.0, footprint=fp)) == []
