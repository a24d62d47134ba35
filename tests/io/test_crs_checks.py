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
