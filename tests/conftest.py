"""Shared fixtures: paths to the real data and small clouds.

The real datasets are found in ``$ROOFTRACE_DATA``, else in ``../shared/data``
beside the repository.  A test whose dataset is missing is skipped, and the
skip names the variable; with ``ROOFTRACE_REQUIRE_DATA=1`` (set by ``.ci/run``)
it fails instead, so that CI never passes without the real-data tests.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("ROOFTRACE_DATA") or ROOT.parent / "shared" / "data")
DELFT = DATA / "3dfier_delft_ahn3_bgt"
CITY3D = DATA / "city3d_ahn3_single_buildings"
IGN = DATA / "ign_montpellier_lidarhd_bdortho"


def need(path: Path) -> Path:
    """Skip a test when a real dataset is absent (it lives outside the repository); fail if CI requires it."""
    if not path.exists():
        where = "ROOFTRACE_DATA" if os.environ.get("ROOFTRACE_DATA") else "ROOFTRACE_DATA unset, default ../shared/data"
        message = f"real data not found: {path} ({where}); set ROOFTRACE_DATA to the folder holding the datasets"
        if os.environ.get("ROOFTRACE_REQUIRE_DATA", "") not in ("", "0"):
            pytest.fail(f"{message} (ROOFTRACE_REQUIRE_DATA is set)", pytrace=False)
        pytest.skip(message)
    return path


def delft_around(footprint_id, margin: float):
    """The west AHN3 Delft tile around one BGT footprint: the footprints within ``margin`` metres of its box,
    the points within 5 m of theirs, and the footprint's index among them (``(cloud, footprints, index)``)."""
    import shapely

    from rooftrace.footprints import Footprints
    from rooftrace.io.footprints import read_footprints
    from rooftrace.io.points import read_points

    cloud = read_points([need(DELFT / "ahn3_cropped_1.laz")], crs="EPSG:7415")
    fps = read_footprints(need(DELFT / "bgt_pand.sqlite"), cloud.crs)
    box = shapely.box(*fps.polygons[fps.ids.index(footprint_id)].bounds).buffer(margin)
    keep = [i for i, p in enumerate(fps.polygons) if p.intersects(box)]
    near = Footprints(tuple(fps.polygons[i] for i in keep), tuple(fps.ids[i] for i in keep), fps.id_field)
    x0, y0, x1, y1 = shapely.total_bounds(np.asarray(near.polygons, dtype=object)) + [-5, -5, 5, 5]
    cloud = cloud.subset((cloud.x >= x0) & (cloud.x <= x1) & (cloud.y >= y0) & (cloud.y <= y1))
    return cloud, near, near.ids.index(footprint_id)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
