"""CRS comparison between inputs: equal, written differently but the same coordinates, or really different."""

import pytest
from pyproj import CRS

from rooftrace.errors import InputError
from rooftrace.io.checks import check_same_crs
from tests.conftest import IGN, need

# what GDAL writes for an IGN orthophoto: Lambert-93's projection without its datum
DATUMLESS_L93 = (
    'PROJCS["EPSG:2154",GEOGCS["unknown",DATUM["unnamed",SPHEROID["unretrievable - using WGS84",6378137,298.257223563]],'
    'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],'
    'PARAMETER["latitude_of_origin",46.5],PARAMETER["central_meridian",3],PARAMETER["standard_parallel_1",49],'
    'PARAMETER["standard_parallel_2",44],PARAMETER["false_easting",700000],PARAMETER["false_northing",6600000],'
    'UNIT["metre",1],AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
)


def test_same_and_compound_crs_pass():
    check_same_crs(CRS("EPSG:28992"), CRS("EPSG:28992"), "a", "b")
    check_same_crs(CRS("EPSG:28992+5709"), CRS("EPSG:28992"), "a", "b")
    check_same_crs(None, CRS("EPSG:28992"), "a", "b")


def test_a_datumless_copy_of_the_projection_passes():
    assert not CRS("EPSG:2154").equals(CRS.from_wkt(DATUMLESS_L93), ignore_axis_order=True)
    check_same_crs(CRS("EPSG:2154"), CRS.from_wkt(DATUMLESS_L93), "cloud.laz", "ortho.tif")


@pytest.mark.parametrize("other", ["EPSG:27572", "EPSG:32631", "EPSG:4326"])
def test_another_projection_or_datum_is_refused(other):
    with pytest.raises(InputError, match="different CRSs"):
        check_same_crs(CRS("EPSG:2154"), CRS(other), "cloud.laz", "ortho.tif")


def test_wkt_without_authority_on_both_sides():
    # the LAS VLR of IGN LiDAR HD is Lambert-93 as WKT without an ID (no area of use)
    import laspy

    from rooftrace.io.las import las_crs

    path = need(IGN / "test_data_77055_627760_LA93_IGN69.laz")
    with laspy.open(path) as f:
        l93 = las_crs(f.header, str(path))
    assert l93.area_of_use is None
    check_same_crs(l93, CRS.from_wkt(DATUMLESS_L93), "cloud.laz", "ortho.tif")
    with pytest.raises(InputError):
        check_same_crs(l93, CRS("EPSG:27572"), "cloud.laz", "ortho.tif")


def test_tiled_and_untiled_runs_take_the_same_crs_rule(tmp_path, caplog):
    """A vertical component on one file only is one CRS for both paths; another projection is refused by both."""
    from rooftrace.errors import OptionError
    from rooftrace.io.points import common_crs, read_points
    from rooftrace.tiling import TileOptions, run_tiled
    from tests.cli.badfiles import scene_xyz, write_las_file

    a = write_las_file(tmp_path / "a.laz", scene_xyz(seed=1))
    b = write_las_file(tmp_path / "b.laz", scene_xyz(seed=2) + [0.0, 40.0, 0.0], crs="EPSG:7415")
    c = write_las_file(tmp_path / "c.laz", scene_xyz(seed=3), crs="EPSG:2154")
    d = write_las_file(tmp_path / "d.laz", scene_xyz(seed=4), crs=None)
    with caplog.at_level("WARNING"):
        assert read_points([a, b]).crs.equals(CRS("EPSG:28992"))
    assert "b.laz: CRS" in caplog.text and "same plan coordinates" in caplog.text
    tiled = run_tiled([a, b], tiling=TileOptions(tile_size=40.0, buffer=20.0))
    assert tiled.crs.equals(CRS("EPSG:28992"))
    for bad in (c, d):
        with pytest.raises(OptionError, match=f"{bad.name}: CRS .* differs from"):
            read_points([a, bad])
        with pytest.raises(OptionError, match=f"{bad.name}: CRS .* differs from"):
            run_tiled([a, bad], tiling=TileOptions(tile_size=40.0, buffer=20.0))
    with pytest.raises(OptionError, match=r"c.laz: CRS \(RGF93 v1 / Lambert-93\) differs"):
        common_crs([a, b, c], [CRS("EPSG:28992"), CRS("EPSG:7415"), CRS("EPSG:2154")])
