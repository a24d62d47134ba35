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

__all__ = ["DELFT", "CITY3D", "IGN", "class6_buildings", "delft_cloud", "thinned", "ign_tiles", "city3d_buildings",
           "local_alpha"]


def class6_buildings(cloud) -> tuple[np.ndarray, np.ndarray, float]:
    """(xyz, building ids, s_avg) of a cloud's class-6 points."""
    xyz, ids = classified_buildings(cloud.xyz, cloud.fields["classification"])
    return xyz, ids, building_mean_spacing(xyz[:, :2])


def local_alpha(outline, xy: np.ndarray) -> np.ndarray:
    """Each point's alpha radius (m) in ``outline``'s alpha shape: the invariant's tolerance.

    For the point strategy (S3) a point's alpha is its own ps_avg scaled as
    the outline's shape was (``outline.alpha`` is the median over the
    Delaunay edges of the scaled edge alphas); for the others it is one value.
    Recomputed here from the points, not read from the pipeline.
    """
    from rooftrace.contour.alpha_shape import AlphaOptions
    from rooftrace.contour.spacing import delaunay_mesh, point_spacing

    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    if outline.alpha_strategy != "point":
        return np.full(len(xy), outline.alpha)
    # points sharing a plan position count once in the shape (the highest is its roof point)
    plan, inverse = np.unique(xy, axis=0, return_inverse=True)
    edges, lengths, _, _ = delaunay_mesh(plan)
    spacing = point_spacing(plan, edges, lengths, AlphaOptions().radius)
    unscaled = float(np.median(0.5 * (spacing[edges[:, 0]] + spacing[edges[:, 1]])))
    return spacing[inverse.ravel()] * (outline.alpha / unscaled)


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
