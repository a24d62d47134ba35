"""Footprints in: every OGR format, reprojection to the cloud's CRS, the id field, bad files."""

from __future__ import annotations

import logging

import numpy as np
import pyogrio
import pyproj
import pytest
import shapely

from rooftrace.errors import InputError
from rooftrace.io.checks import check_footprints_overlap
from rooftrace.io.footprints import read_footprints
from rooftrace.io.vector import Layer, write_layers
from tests.conftest import CITY3D, DELFT, need

RD = pyproj.CRS.from_epsg(28992)
RD_NAP = pyproj.CRS.from_epsg(7415)
HOUSES = [shapely.box(85000, 447500, 85006, 447510), shapely.box(85006, 447500, 85012, 447510)]


def _write(path, crs=RD, attrs=None, geoms=HOUSES, driver=None):
    attrs = attrs if attrs is not None else {"identificatie": np.array(["NL.1", "NL.2"], dtype=object)}
    wkb = np.asarray(shapely.to_wkb(np.asarray(geoms, dtype=object)))
    fields = list(attrs)
    pyogrio.raw.write(str(path), wkb, [np.asarray(attrs[k]) for k in fields], fields, driver=driver,
                      geometry_type="Polygon", crs=crs.to_wkt() if crs is not None else None)
    return path


@pytest.mark.filterwarnings("ignore:Normalized/laundered field name")
@pytest.mark.parametrize("suffix,driver", [(".gpkg", "GPKG"), (".geojson", "GeoJSON"), (".fgb", "FlatGeobuf"),
                                           (".shp", "ESRI Shapefile"), (".sqlite", "SQLite")])
def test_every_format_reads_with_its_id_field(tmp_path, suffix, driver):
    fp = read_footprints(_write(tmp_path / f"fp{suffix}", driver=driver), RD_NAP)
    # FlatGeobuf's spatial index may reorder features: compare (id, polygon) pairs
    got = dict(zip(fp.ids, fp.polygons))
    assert sorted(got) == ["NL.1", "NL.2"]
    assert fp.id_field == ("identifica" if suffix == ".shp" else "identificatie")  # Shapefile names: 10 chars
    for key, house in zip(("NL.1", "NL.2"), HOUSES):
        assert shapely.equals_exact(shapely.normalize(got[key]), shapely.normalize(house), 1e-6)
    assert all(not p.has_z for p in fp.polygons)


def test_reprojected_to_the_clouds_crs(tmp_path):
    to_wgs = pyproj.Transformer.from_crs(RD, 4326, always_xy=True)
    wgs = [shapely.transform(p, lambda xy: np.column_stack(to_wgs.transform(xy[:, 0], xy[:, 1]))) for p in HOUSES]
    fp = read_footprints(_write(tmp_path / "wgs.gpkg", pyproj.CRS.from_epsg(4326), geoms=wgs), RD_NAP)
    for got, want in zip(fp.polygons, HOUSES):
        assert shapely.hausdorff_distance(got, want) < 0.01  # metres after the round trip
    # the id field can be chosen, and "fid" is the feature id
    assert read_footprints(tmp_path / "wgs.gpkg", RD, id_field="fid").ids == (1, 2)


@pytest.mark.filterwarnings("ignore:.crs. was not provided")
def test_no_crs_takes_the_clouds_with_a_warning(tmp_path, caplog):
    path = _write(tmp_path / "nocrs.gpkg", crs=None, attrs={"id": np.array([7, 8])})
    with caplog.at_level(logging.WARNING):
        fp = read_footprints(path, RD)
    assert "no CRS" in caplog.text and fp.ids == (7, 8) and fp.id_field == "id"
    assert shapely.equals_exact(fp.polygons[0], HOUSES[0], 1e-6)


def test_geojson_in_local_metres_is_not_taken_for_wgs84(caplog):
    # City3D's footprints: a GeoJSON without a crs member (GDAL says WGS 84) in a local metric frame
    with caplog.at_level(logging.WARNING):
        fp = read_footprints(need(CITY3D / "scene001" / "001_footprint.geojson"), None)
    assert "not longitude/latitude" in caplog.text
    assert len(fp) == 1 and fp.polygons[0].area == pytest.approx(993, abs=1)


def test_delft_bgt_footprints():
    fp = read_footprints(need(DELFT / "bgt_pand.sqlite"), RD_NAP)
    assert len(fp) == 160 and fp.id_field == "identificatiebagpnd" and len(set(fp.ids)) == 160
    assert sum(p.area for p in fp.polygons) == pytest.approx(8654, abs=1)


def test_bad_files(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_footprints(tmp_path / "missing.gpkg", RD)
    junk = tmp_path / "junk.gpkg"
    junk.write_bytes(b"not a geopackage at all")
    with pytest.raises(InputError, match="not a readable vector file"):
        read_footprints(junk, RD)
    lines = write_layers(tmp_path / "lines.gpkg", {"roads": Layer([shapely.LineString([(0, 0), (1, 1)])], {},
                                                                  "LineString")}, RD)
    with pytest.raises(InputError, match="no polygon layer"):
        read_footprints(lines, RD)
    with pytest.raises(InputError, match="no attribute 'bag_id'.*identificatie"):
        read_footprints(_write(tmp_path / "fp.gpkg"), RD, id_field="bag_id")


def test_footprints_away_from_the_cloud_are_refused(tmp_path):
    fp = read_footprints(_write(tmp_path / "fp.gpkg"), RD)
    cloud = np.array([[0.0, 0.0, 1.0], [100.0, 100.0, 2.0]])
    with pytest.raises(InputError, match="no footprint lies over the point cloud"):
        check_footprints_overlap(fp, cloud, "fp.gpkg", "cloud.laz")
    near = np.array([[85003.0, 447505.0, 1.0], [85100.0, 447600.0, 2.0]])
    assert check_footprints_overlap(fp, near, "fp.gpkg", "cloud.laz") == 2
