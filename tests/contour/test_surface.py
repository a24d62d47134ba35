"""The roof-surface filter: wall points out, sloped roofs kept, outline Z at the eave."""

import numpy as np
import pytest

from rooftrace.contour.outline import trace_outline
from rooftrace.contour.surface import SurfaceOptions, below_roof

EAVE, RIDGE = 10.0, 14.0  # a 45° gable over a 8 m x 12 m house: half-width 4 m, rise 4 m


def _gable_house(spacing=0.3, seed=0):
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 12, round(12 / spacing) + 1), np.linspace(-4, 4, round(8 / spacing) + 1))
    x, y = x.ravel(), y.ravel()
    roof = np.column_stack([x, y, RIDGE - np.abs(y) * (RIDGE - EAVE) / 4])
    # walls flush with the roof edge (no overhang), from 0 to the eave, as a slant scan sees them: a dense line in plan
    n_wall = 400
    wall = np.concatenate([np.column_stack([rng.uniform(0.05, 11.95, n_wall), np.full(n_wall, side * 4.02),
                                            rng.uniform(0.5, EAVE - 0.6, n_wall)]) for side in (-1, 1)])
    roof = roof + rng.normal(0, 0.02, roof.shape)
    return roof, wall


def test_walls_are_below_roof_and_sloped_roof_is_not():
    roof, wall = _gable_house()
    flags = below_roof(np.vstack([roof, wall]), 0.6)
    assert not flags[: len(roof)].any()
    # every wall point lower than tolerance + the slope allowance under the eave is flagged
    low = wall[:, 2] < EAVE - 0.5 - 0.6 * np.sqrt(2) * np.tan(np.radians(60))
    assert flags[len(roof):][low].all()


def test_steep_roof_beyond_max_slope_is_flagged_as_wall():
    x = np.repeat(np.arange(0, 3, 0.2), 5)
    y = np.tile(np.arange(0, 1, 0.2), 15)
    steep = np.column_stack([x, y, 5 * x])  # 79°: a wall, not a roof
    assert below_roof(steep, 0.4, max_slope=60).mean() > 0.9
    assert not below_roof(steep, 0.4, max_slope=85).any()


def test_outline_z_is_eave_height_with_walls_present():
    roof, wall = _gable_house()
    xyz = np.vstack([roof, wall])
    outline = trace_outline(xyz, mean_spacing=0.3)
    z = np.asarray(outline.polygon.exterior.coords)[:, 2]
    # the gable ends rise to the ridge; no vertex comes from a wall (the wall's top metre may remain)
    assert z.min() > EAVE - 1.0
    assert np.median(z) > EAVE - 0.2
    assert z.max() < RIDGE + 0.2
    # four eave corners and the two gable apexes; wall points would add corners at every jump
    assert len(outline.corners[0]) == 6
    # the grid's outermost points lie on the roof edge; the outline moves out by less than a spacing
    # (edge_factor) where no points beyond say where the roof ends, never to the wall points' spread
    assert 12 * 8.0 < outline.polygon.area < (12 + 0.3) * (8.04 + 0.3)


def test_degenerate_inputs():
    assert below_roof(np.empty((0, 3)), 1.0).shape == (0,)
    assert not below_roof(np.zeros((5, 3)), 1.0).any()  # identical points: none is higher
    with pytest.raises(ValueError):
        below_roof(np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError):
        SurfaceOptions(max_slope=90)


def test_lift_to_roof_takes_the_nearest_roof_point_ties_to_the_lower_index():
    # the sort the compiled pass replaced: both directions of every pair, nearest roof point first,
    # ties to the lower index; points on a 0.5 m lattice tie often
    from scipy.spatial import cKDTree

    from rooftrace.contour.surface import below_roof, lift_to_roof

    rng = np.random.default_rng(5)
    g = np.mgrid[0:20:0.5, 0:12:0.5].reshape(2, -1).T
    z = np.where(rng.random(len(g)) < 0.2, rng.uniform(0, 8, len(g)), 10.0 + 0.1 * g[:, 0])
    xyz = np.column_stack([g, z])
    flagged = below_roof(xyz, 1.2)
    pairs = cKDTree(xyz[:, :2]).query_pairs(1.2, output_type="ndarray")
    d = np.hypot(*(xyz[pairs[:, 0], :2] - xyz[pairs[:, 1], :2]).T)
    src, dst = np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])
    dist = np.tile(d, 2)
    use = flagged[src] & ~flagged[dst]
    order = np.lexsort((dst[use], dist[use], src[use]))
    s, t = src[use][order], dst[use][order]
    first = np.ones(len(s), bool)
    first[1:] = s[1:] != s[:-1]
    want = xyz.copy()
    want[s[first], 2] = xyz[t[first], 2]
    assert flagged.sum() > 50
    assert np.array_equal(lift_to_roof(xyz, 1.2), want)
