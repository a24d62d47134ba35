"""The outline invariant on every real dataset: each outline covers >= 99 % of its building's points.

Buildings are the provider's class 6 in connected components (tests/contour/realdata.py).  Every
outline must exist and cover the points within their local alpha (each point's own alpha radius in
the outline's alpha shape, as the pipeline's invariant reads it); measured figures in benchmarks/RESULTS.md,
"Outline coverage".
"""

from __future__ import annotations

import numpy as np
import pytest

from rooftrace.contour.coverage import MIN_COVERAGE, outline_coverage
from rooftrace.contour.outline import outline_buildings
from tests.conftest import need
from tests.contour import realdata


def _check(xyz: np.ndarray, ids: np.ndarray, spacing: float) -> list:
    outlines = outline_buildings(xyz, ids, mean_spacing=spacing)
    assert len(outlines) == ids.max()
    for o in outlines:
        pts = xyz[ids == o.building_id]
        if o.polygon is None and len(pts) < 10:  # a few stray points (components from 3 points): no outline, said so
            assert o.status in ("too_few_points", "collinear", "no_ring")
            continue
        assert o.polygon is not None, (o.building_id, o.status)
        covered = outline_coverage(o.polygon, pts, realdata.local_alpha(o, pts))
        assert covered >= MIN_COVERAGE and o.coverage >= MIN_COVERAGE, (o.building_id, len(pts), o.status, covered)
        assert o.status != "low_coverage"
    return outlines


@pytest.fixture(scope="module")
def delft():
    need(realdata.DELFT)
    return realdata.delft_cloud()


def test_delft_every_building_is_covered(delft):
    outlines = _check(*realdata.class6_buildings(delft))
    assert len(outlines) > 60


def test_delft_thinned_to_3_points_per_m2_every_building_is_covered(delft):
    thin = realdata.thinned(delft, 3.0, seed=0)
    assert len(thin.xyz) == pytest.approx(len(delft.xyz) * 3.0 / 12.0, rel=0.5)
    _check(*realdata.class6_buildings(thin))


def test_ign_every_building_is_covered():
    need(realdata.IGN)
    for tile in realdata.ign_tiles():
        _check(*realdata.class6_buildings(tile))


def test_city3d_every_building_is_covered():
    need(realdata.CITY3D)
    xyz, ids, spacing, _ = realdata.city3d_buildings()
    assert len(_check(xyz, ids, spacing)) == 50
