import laspy
import numpy as np
import pyproj
import pytest

from rooftrace.errors import InputError, OutputExistsError
from rooftrace.io.las import read_las, write_las
from rooftrace.io.points import read_points
from tests.conftest import DELFT, IGN, need


def _make_las(path, version="1.2", point_format=1, n=500, crs=None, seed=0, extra=False):
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(version=version, point_format=point_format)
    header.scales = [0.01, 0.01, 0.01]
    header.offsets = [85000, 447000, 0]
    if extra:
        header.add_extra_dims([laspy.ExtraBytesParams(name="reflectance", type=np.float32)])
    if crs is not None:
        header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x = 85000 + rng.uniform(0, 50, n)
    las.y = 447000 + rng.uniform(0, 50, n)
    las.z = rng.uniform(0, 10, n)
    las.intensity = rng.integers(0, 1000, n).astype(np.uint16)
    las.classification = np.full(n, 1, np.uint8)
    if extra:
        las.reflectance = rng.normal(size=n).astype(np.float32)
    las.write(path)
    return las


@pytest.mark.parametrize("version,fmt,suffix", [("1.2", 1, ".las"), ("1.4", 6, ".laz"), ("1.4", 8, ".laz"), ("1.2", 3, ".laz")])
def test_round_trip_keeps_dimensions_and_adds_building_id(tmp_path, version, fmt, suffix):
    src = tmp_path / f"in{suffix}"
    las = _make_las(src, version, fmt, extra=True)
    cloud = read_las(src)
    assert len(cloud) == 500
    np.testing.assert_allclose(cloud.xyz[:, 0], las.x, atol=1e-9)
    assert "reflectance" in cloud.fields and "intensity" in cloud.fields
    cls = np.where(cloud.z > 5, 6, 2)
    bid = np.arange(len(cloud), dtype=np.int32) % 7
    out = write_las(tmp_path / f"out{suffix}", cloud, classification=cls, building_id=bid)
    back = laspy.read(out)
    assert back.header.point_format.id == fmt
    np.testing.assert_array_equal(back.classification, cls)
    np.testing.assert_array_equal(back.building_id, bid)
    assert back.building_id.dtype == np.int32
    np.testing.assert_allclose(back.reflectance, las.reflectance)
    np.testing.assert_array_equal(back.intensity, las.intensity)
    np.testing.assert_allclose(back.z, las.z, atol=1e-9)


def test_crs_from_wkt_and_geotiff_vlrs_is_kept(tmp_path):
    for version, fmt in (("1.4", 6), ("1.2", 1)):  # WKT VLR and GeoTIFF keys
        src = tmp_path / f"crs{fmt}.las"
        _make_las(src, version, fmt, crs="EPSG:28992")
        cloud = read_las(src)
        assert cloud.crs is not None and cloud.crs.to_epsg() == 28992
        out = write_las(tmp_path / f"o{fmt}.laz", cloud)
        assert read_las(out).crs.to_epsg() == 28992


def test_crs_override_and_mismatch(tmp_path):
    a, b = tmp_path / "a.las", tmp_path / "b.las"
    _make_las(a, "1.4", 6, crs="EPSG:28992")
    _make_las(b, "1.4", 6, crs="EPSG:2154")
    with pytest.raises(InputError, match="CRS"):
        read_points([a, b])
    cloud = read_points([a, b], crs="EPSG:28992")
    assert cloud.crs.to_epsg() == 28992 and len(cloud) == 1000
    np.testing.assert_array_equal(np.unique(cloud.fields["source_index"]), [0, 1])


def test_refuses_overwrite_and_writes_atomically(tmp_path):
    src = tmp_path / "in.las"
    _make_las(src)
    cloud = read_las(src)
    out = tmp_path / "out.laz"
    write_las(out, cloud)
    before = out.read_bytes()
    with pytest.raises(OutputExistsError, match="pass overwrite"):
        write_las(out, cloud)
    assert out.read_bytes() == before
    write_las(out, cloud, overwrite=True)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_truncated_and_garbage_files(tmp_path):
    src = tmp_path / "in.laz"
    _make_las(src, n=20000)
    data = src.read_bytes()
    cut = tmp_path / "cut.laz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="cut.laz"):
        read_las(cut)
    junk = tmp_path / "junk.las"
    junk.write_bytes(b"this is not a las file at all" * 10)
    with pytest.raises(InputError, match="junk.las"):
        read_las(junk)
    with pytest.raises(InputError, match="no such file"):
        read_las(tmp_path / "missing.las")


def test_real_delft_and_ign_headers():
    cloud = read_las(need(DELFT / "ahn3_cropped_2.laz"))
    assert len(cloud) == 208432 and cloud.crs is None
    ign = read_las(need(IGN / "test_data_77055_627760_LA93_IGN69.laz"))
    assert len(ign) == 60653 and ign.crs is not None
    assert "Lambert-93" in ign.crs.name or ign.crs.to_epsg() == 2154


def test_header_that_lies_about_bounds_is_refused(tmp_path):
    import struct

    src = tmp_path / "lies.las"
    _make_las(src)
    data = bytearray(src.read_bytes())
    data[179:187] = struct.pack("<d", 85010.0)  # Max X: the points reach 85050
    src.write_bytes(bytes(data))
    with pytest.raises(InputError, match="outside the header bounds"):
        read_las(src)
