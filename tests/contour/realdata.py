"""The real datasets as buildings (points and ids) for the outline invariant's tests and benchmark.

Buildings are the provider's class 6 split into connected components at
2 s_avg, as ``rooftrace outline`` does without building ids
(:func:`rooftrace.contour.buildings.classified_buildings`); City3D clouds are
one building each.
"""

from __future__ import annotations

import json

import numpy as np

from rooftrace.contour.buildings import classified_buildings
from rooftrace.contour.spacing import building_mean_spacing
from tests.conftest import CITY3D, DELFT, IGN

__all__ = ["DELFT", "CITY3D", "IGN", "class6_buildings", "delft_cloud", "thinned", "ign_tiles", "city3d_buildings"]


def class6_buildings(cloud) -> tuple[np.ndarray, np.ndarray, float]:
    """(xyz, building ids, s_avg) of a cloud's class-6 points."""
    xyz, ids = classified_buildings(cloud.xyz, cloud.fields["classification"])
    return xyz, ids, building_mean_spacing(xyz[:, :2])


def delft_cloud():
    from rooftrace.io.points import read_points

    return read_points(sorted(DELFT.glob("ahn3_cropped_*.laz")), "EPSG:28992")


def thinned(cloud, density: float, seed: int = 0):
    """The cloud thinned at random (seeded) to ``density`` pts/m² over its tiles' extent."""
    x0, y0 = cloud.xyz[:, :2].min(axis=0)
    x1, y1 = cloud.xyz[:, :2].max(axis=0)
    keep = np.random.default_rng(seed).random(len(cloud.xyz)) < density * (x1 - x0) * (y1 - y0) / len(cloud.xyz)
    return cloud.subset(keep)


def ign_tiles() -> list:
    from rooftrace.io.points import read_points

    return [read_points(p) for p in sorted(IGN.glob("*.laz"))]


def city3d_buildings() -> tuple[np.ndarray, np.ndarray, float, list]:
    """(xyz, ids 1..50, median s_avg, footprints) of the 50 single-building clouds of instances_002."""
    import shapely
    from plyfile import PlyData

    folder = CITY3D / "instances_002"
    feats = json.loads((folder / "002_footprint.geojson").read_text())["features"]
    clouds = []
    for f in feats:
        v = PlyData.read(str(folder / f["properties"]["instance_ply"]))["vertex"]
        clouds.append(np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64))
    ids = np.repeat(np.arange(1, len(clouds) + 1), [len(c) for c in clouds])
    spacing = float(np.median([building_mean_spacing(c[:, :2]) for c in clouds]))
    return np.concatenate(clouds), ids, spacing, [shapely.geometry.shape(f["geometry"]) for f in feats]
