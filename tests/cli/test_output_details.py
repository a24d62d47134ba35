"""What a user reads in the outputs: rounded numbers with units, GeoPackage 1.3, compound CRSs (issue 21)."""

from __future__ import annotations

import json
import re
import sqlite3

import laspy
import pyogrio
import pyproj
import pytest

from rooftrace.cli.app import rounded
from rooftrace.cli.main import main
from rooftrace.errors import InputError
from rooftrace.io.checks import check_same_crs, horizontal_crs, require_metric_crs
from rooftrace.io.vector import GPKG_VERSION, read_layer
from tests.cli.badfiles import scene_xyz, write_las_file

NOISE = re.compile(r"\d\.\d{5,}")  # float noise such as -0.5680000000000001 or 14.073153819610031


def floats(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from floats(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from floats(v)
    elif isinstance(obj, float):
        yield obj


@pytest.fixture(scope="module")
def compound_run(tmp_path_factory):
    """One run of a small scene with --crs EPSG:7415 (RD New + NAP height), the classified points and --json."""
    tmp = tmp_path_factory.mktemp("compound")
    src = write_las_file(tmp / "scene.laz", scene_xyz())
    out, points = tmp / "roofs.gpkg", tmp / "classified.laz"
    return tmp, src, out, points


def test_rounded_keeps_millimetres_and_four_digits():
    assert rounded(-0.5680000000000001) == -0.568
    assert rounded(14.073153819610031) == 14.073
    assert rounded(0.022522160337) == 0.02252
    assert rounded(85000.00123) == 85000.001
    assert rounded({"a": [1, True, None, "x", 2.0]}) == {"a": [1, True, None, "x", 2.0]}
    assert rounded(rounded(0.123456789)) == rounded(0.123456789)


def test_info_prints_rounded_numbers_with_units(tmp_path, capsys):
    src = write_las_file(tmp_path / "scene.laz", scene_xyz() + [0.0, 0.0, -0.5680000000000001])
    assert main(["info", str(src)]) == 0
    text = capsys.readouterr().out
    assert not NOISE.search(text), text
    assert re.search(r"density_bbox: \d+\.\d\d pts/m²", text), text
    assert re.search(r"bounds: x [\d.]+ to [\d.]+ m, y [\d.]+ to [\d.]+ m, z -?[\d.]+ to [\d.]+ m", text), text
    assert main(["info", str(src), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary) >= {"points", "crs", "bounds", "density_bbox", "dimensions", "run"}
    assert all(v == rounded(v) for v in floats(summary))
    assert summary["density_bbox"] == round(summary["density_bbox"], 3)


def test_compound_crs_recorded_and_gpkg_13_and_rounded_json(compound_run, capsys):
    tmp, src, out, points = compound_run
    assert main(["run", str(src), "--crs", "EPSG:7415", "-o", str(out), "--classified", str(points), "--json"]) == 0
    captured = capsys.readouterr()
    assert "overridden" not in captured.err  # RD New + its height system is no override of RD New
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert {"output", "points", "buildings", "ridges", "roof_faces", "refined", "mean_spacing", "parameters"} <= set(summary)
    assert all(v == rounded(v) for v in floats(summary)) and not NOISE.search(json.dumps(summary["mean_spacing"]))
    # the GeoPackage says 1.3 (GDAL 3.6 warns about 1.4) and carries the compound CRS
    with sqlite3.connect(out) as db:
        assert db.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47  # 'GPKG'
        assert db.execute("PRAGMA user_version").fetchone()[0] == 10300 and GPKG_VERSION == "1.3"
    crs = pyproj.CRS.from_user_input(pyogrio.read_info(out, layer="roof_outlines")["crs"])
    assert crs.is_compound and crs.to_epsg() == 7415
    assert read_layer(out, "roof_outlines").crs.equals(pyproj.CRS("EPSG:7415"))
    # the classified LAZ records it in its WKT VLR
    las_crs = laspy.read(points).header.parse_crs()
    assert las_crs.is_compound and "NAP height" in las_crs.to_wkt()


def test_compound_crs_horizontal_part_checks():
    rd_nap = pyproj.CRS("EPSG:7415")
    assert horizontal_crs(rd_nap).to_epsg() == 28992
    require_metric_crs(rd_nap, "cloud.laz")
    check_same_crs(rd_nap, pyproj.CRS("EPSG:28992"), "cloud.laz", "camera.json")
    with pytest.raises(InputError, match="height system only.*EPSG:28992\\+5709"):
        require_metric_crs(pyproj.CRS("EPSG:5709"), "cloud.laz")
    with pytest.raises(InputError, match="geographic"):
        require_metric_crs(pyproj.CRS("EPSG:4326+5773"), "cloud.laz")
    with pytest.raises(InputError, match="different CRSs"):
        check_same_crs(rd_nap, pyproj.CRS("EPSG:2154"), "cloud.laz", "camera.json")
