"""Vector output: single-file formats written atomically, Shapefiles refused, empty layers kept (issue 10)."""

from __future__ import annotations

import pyproj
import pytest
import shapely

from rooftrace.errors import InputError, OutputExistsError
from rooftrace.io.vector import Layer, list_layers, read_layer, vector_driver, write_layers

RD = pyproj.CRS.from_epsg(28992)
ROOF = shapely.Polygon([(0, 0, 5), (10, 0, 5), (10, 8, 6), (0, 8, 6)])


@pytest.mark.parametrize("suffix", [".shp", ".SHP", ".dbf", ".tab"])
def test_multi_file_formats_are_refused_before_anything_is_written(tmp_path, suffix):
    # regression, issue 10: the atomic rename moved the .shp and left .shx/.dbf under temporary names
    with pytest.raises(InputError, match="not supported.*GeoPackage"):
        write_layers(tmp_path / f"roofs{suffix}", {"roof_outlines": Layer([ROOF], {"building_id": [1]}, "PolygonZ")}, RD)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix,driver", [(".gpkg", "GPKG"), (".geojson", "GeoJSON"), (".fgb", "FlatGeobuf")])
def test_single_file_formats_round_trip_and_leave_no_temporary_file(tmp_path, suffix, driver):
    assert vector_driver(f"x{suffix}") == driver
    path = write_layers(tmp_path / f"roofs{suffix}", {"roof_outlines": Layer([ROOF], {"building_id": [7]},
                                                                              "PolygonZ")}, RD)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    layer = read_layer(path)
    assert shapely.equals_exact(layer.geometries[0], ROOF, 1e-9) and layer.geometries[0].has_z
    assert [int(v) for v in layer.attributes["building_id"]] == [7] and layer.crs.equals(RD)


def test_empty_layers_keep_their_schema_and_existing_files_need_overwrite(tmp_path):
    path = tmp_path / "empty.gpkg"
    write_layers(path, {"roof_outlines": Layer([], {"building_id": [], "status": []}, "PolygonZ"),
                        "ridges": Layer([], {}, "LineStringZ")}, RD)
    assert list_layers(path) == ["roof_outlines", "ridges"]
    layer = read_layer(path, "roof_outlines")
    assert len(layer) == 0 and set(layer.attributes) == {"building_id", "status"}
    before = path.read_bytes()
    with pytest.raises(OutputExistsError, match="pass overwrite"):
        write_layers(path, {"roof_outlines": Layer([ROOF], {}, "PolygonZ")}, RD)
    assert path.read_bytes() == before
    write_layers(path, {"roof_outlines": Layer([ROOF], {}, "PolygonZ")}, RD, overwrite=True)
    assert len(read_layer(path, "roof_outlines")) == 1


def test_unknown_suffix_and_several_layers_in_a_one_layer_format(tmp_path):
    with pytest.raises(InputError, match="unknown vector format"):
        write_layers(tmp_path / "roofs.txt", {"a": Layer([ROOF])}, RD)
    with pytest.raises(InputError, match="holds one layer"):
        write_layers(tmp_path / "roofs.geojson", {"a": Layer([ROOF]), "b": Layer([ROOF])}, RD)
    assert list(tmp_path.iterdir()) == []
