import numpy as np
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


@pytest.mark.parametrize("content,match", [("1 2\n3 4\n", "3 numeric columns"), ("a b c\nd e f\n", "not a text point cloud"), ("", "empty")])
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
