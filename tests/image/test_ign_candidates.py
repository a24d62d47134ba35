"""Line candidates on real data: the IGN 0.2 m orthophoto with LiDAR HD class-6 points (Montpellier)."""

import numpy as np
import pytest
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from rooftrace.image.candidates import extract_candidates
from rooftrace.image.corners import harris_corners
from rooftrace.image.projection import in_window
from tests.conftest import IGN, need


@pytest.fixture(scope="module")
def ign():
    tif = need(IGN / "test_data_rgb.tif")
    laz = need(IGN / "test_data_77055_627760_LA93_IGN69.laz")
    import rasterio

    from rooftrace.io.camera import camera_from_dict
    from rooftrace.io.points import read_points

    cam = camera_from_dict({"type": "orthophoto"}, "ign", image=tif)
    with rasterio.open(tif) as ds:
        rgb = np.moveaxis(ds.read()[:3], 0, -1).astype(float) / 255.0
    cloud = read_points(laz)
    return cam, rgb, cloud.xyz, np.asarray(cloud.fields["classification"])


def _largest_building(xyz):
    pairs = cKDTree(xyz[:, :2]).query_pairs(0.8, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xyz), len(xyz)))
    _, label = connected_components(graph, directed=False)
    pts = xyz[label == np.argmax(np.bincount(label))]
    hull = shapely.concave_hull(shapely.MultiPoint(pts[:, :2]), ratio=0.1).simplify(1.0)
    ring = shapely.get_coordinates(hull.exterior)
    z = float(np.percentile(pts[:, 2], 10))
    return np.array([[[*ring[i], z], [*ring[i + 1], z]] for i in range(len(ring) - 1)]), pts


def test_candidates_on_the_ign_terrace_block(ign):
    cam, rgb, xyz, cls = ign
    lines, pts = _largest_building(xyz[cls == 6])
    assert len(lines) >= 8
    out = extract_candidates(rgb, cam, lines, ["outline"] * len(lines), points_xyz=xyz, building_xyz=pts)
    assert len(out) == len(lines)
    found = [c for c in out if not c.projected_only]
    assert len(found) >= 0.7 * len(out)
    for c in found:
        ends = c.candidates.reshape(-1, 2)
        assert in_window(ends, c.window + 1e-6 * (c.window - c.window.mean(0))).mean() > 0.95
        d = c.reference[1] - c.reference[0]
        e = c.candidates[:, 1] - c.candidates[:, 0]
        cosang = np.abs(e @ d) / (np.hypot(*e.T) * np.hypot(*d))
        assert np.all(cosang >= np.cos(np.radians(20)) - 1e-9)  # the candidate filter's 20 degrees
    corners = harris_corners(rgb, np.stack([c.window for c in out]))
    assert len(corners) > 10
