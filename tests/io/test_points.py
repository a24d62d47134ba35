import numpy as np
import pyproj
import pytest

from rooftrace.errors import InputError
from rooftrace.io.points import read_points
from tests.conftest import CITY3D, need


def test_text_cloud_with_header_and_commas(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("x,y,z,i\n1,2,3,4\n5,6,7,8\n# comment\n9,10,11,12\n")
    cloud = read_points(p, crs="EPSG:28992")
    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [5, 6, 7], [9, 10, 11]])
    assert cloud.crs.to_epsg() == 28992


@pytest.mark.parametrize("content,match", [("1 2\n3 4\n", "3 numeric columns"),
                                           ("a b c\nd e f\n", "not a text point cloud"), ("", "empty")])
def test_bad_text(tmp_path, content, match):
    p = tmp_path / "bad.xyz"
    p.write_text(content)
    with pytest.raises(InputError, match=match):
        read_points(p)


def test_ply_binary_city3d():
    cloud = read_points(need(CITY3D / "instances_002" / "0.ply"))
    assert len(cloud) > 40 and np.isfinite(cloud.xyz).all()
    assert {"nx", "red"} <= set(cloud.fields)


def test_unknown_suffix_and_folder(tmp_path):
    p = tmp_path / "c.dat"
    p.write_text("1 2 3\n")
    with pytest.raises(InputError, match="unknown point cloud format"):
        read_points(p)
    with pytest.raises(InputError, match="folder"):
        read_points(tmp_path)
    with pytest.raises(InputError, match="bad crs"):
        read_points(p, crs="bad crs")


def test_non_finite_text_coordinates(tmp_path):
    p = tmp_path / "nan.xyz"
    p.write_text("1 2 3\nnan 5 6\n7 inf 9\n")
    with pytest.raises(InputError, match="2 points have NaN"):
        read_points(p)


def test_summarise_las_in_chunks_gives_what_reading_everything_gives(tmp_path):
    """`rooftrace info` reads LAS/LAZ chunk by chunk; the figures must equal those of the whole cloud."""
    from rooftrace.cloud import PointCloud
    from rooftrace.io.las import write_las
    from rooftrace.io.points import read_points, summarise_las

    rng = np.random.default_rng(3)
    paths = []
    for k, n in enumerate((2500, 1700)):
        xyz = rng.uniform([k * 100.0, 0, 0], [k * 100.0 + 50, 40, 12], (n, 3))
        cls = rng.choice([1, 2, 6], n).astype(np.uint8)
        paths.append(tmp_path / f"t{k}.laz")
        write_las(paths[-1], PointCloud(xyz, {}, crs=pyproj.CRS("EPSG:28992")), classification=cls)
    whole = read_points(paths)
    s = summarise_las(paths, chunk_size=333)
    assert s["points"] == len(whole) and s["crs"].equals(whole.crs)
    np.testing.assert_allclose(s["bounds"], [*whole.xyz.min(axis=0), *whole.xyz.max(axis=0)])
    values, counts = np.unique(whole.fields["classification"], return_counts=True)
    assert s["classes"] == dict(zip(values.tolist(), counts.tolist()))
    assert "classification" in s["dimensions"] and "x" not in s["dimensions"]
    # the checks of read_points: a file in another CRS is refused
    other = tmp_path / "l93.laz"
    write_las(other, PointCloud(whole.xyz[:10], {}, crs=pyproj.CRS("EPSG:2154")))
    with pytest.raises(InputError, match="differs from"):
        summarise_las([paths[0], other])
