"""``rooftrace evaluate`` end to end: files in, metrics.json and report.html out, user errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pyproj
import pytest
import shapely
from shapely import LineString, Polygon, box
from shapely.affinity import translate

from rooftrace.cli.app import rounded
from rooftrace.cli.main import main
from rooftrace.io.raster import write_geotiff
from rooftrace.io.vector import Layer, write_layers
from tests.conftest import DELFT, need

RD = "EPSG:28992"


def _write(path, polys, crs=RD, ridges=None, layer="roof_outlines", gtype="Polygon"):
    crs = pyproj.CRS.from_user_input(crs) if crs is not None else None
    layers = {layer: Layer(polys, {"building_id": list(range(10, 10 + len(polys)))}, gtype, crs)}
    if ridges is not None:
        layers["ridges"] = Layer(ridges, {}, "LineStringZ", crs)
    write_layers(path, layers, crs)
    return path


@pytest.fixture
def files(tmp_path):
    ref = [box(0, 0, 10, 8), box(20, 0, 32, 10), box(40, 0, 48, 12)]
    ext = [translate(p, 0.4, 0) for p in ref]
    r = _write(tmp_path / "ref.gpkg", ref)
    e = _write(tmp_path / "ext.geojson", ext, layer="ext")
    return e, r, ext, ref


def test_evaluate_writes_metrics_and_report(tmp_path, files, capsys):
    e, r, ext, ref = files
    out = tmp_path / "eval"
    assert main(["evaluate", str(e), str(r), "-o", str(out), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    m = json.loads((out / "metrics.json").read_text())
    assert (out / "report.html").exists() and summary["report"] == str(out / "report.html")
    # independent computation with shapely
    tp = sum(a.intersection(b).area for a, b in zip(ext, ref))
    assert m["completeness"] == pytest.approx(tp / sum(p.area for p in ref), abs=1e-9)
    assert m["correctness"] == pytest.approx(tp / sum(p.area for p in ext), abs=1e-9)
    assert m["polis_mean"] == pytest.approx(0.2, abs=1e-9) and m["hausdorff_mean"] == pytest.approx(0.4, abs=1e-9)
    assert summary["polis_mean"] == rounded(m["polis_mean"])  # the --json summary is rounded, metrics.json is not
    # the shape scores: same rectangles shifted by 0.4 m, every corner found within 0.5 m
    assert (m["corner_ratio_median"], m["corner_ratio_within_1_5"]) == (1.0, 1.0)
    assert (m["corner_completeness"], m["corner_correctness"]) == (1.0, 1.0)
    assert m["corner_offset_mean"] == pytest.approx(0.4) and summary["corner_offset_mean"] == rounded(m["corner_offset_mean"])
    assert [b["n_corners_reference"] for b in m["buildings"]] == [4, 4, 4]
    assert [b["reference_ids"] for b in m["buildings"]] == [[10], [11], [12]]
    assert m["inputs"]["reference_layer"] == "roof_outlines" and m["inputs"]["extracted_layer"] == "ext"
    for key in ("completeness", "correctness", "f_score", "quality", "polis_mean", "hausdorff_mean", "rmse_x",
                "rmse_y", "rmse_z", "n_reference", "n_extracted", "n_matched", "buildings"):
        assert key in m
    # refuses to overwrite, then does with --overwrite
    assert main(["evaluate", str(e), str(r), "-o", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["evaluate", str(e), str(r), "-o", str(out), "--overwrite", "--no-merge-blocks"]) == 0
    out_text = capsys.readouterr().out
    assert "polis_mean" in out_text and "0.200 m" in out_text
    assert "corner_ratio_median" in out_text and "1.00×" in out_text and "0.400 m" in out_text
    assert json.loads((out / "metrics.json").read_text())["matching_rule"] == "one-to-one"
    # a tolerance below the shift: no corner matches
    assert main(["evaluate", str(e), str(r), "-o", str(out), "--overwrite", "--corner-tolerance", "0.3", "-q"]) == 0
    assert json.loads((out / "metrics.json").read_text())["corner_completeness"] == 0.0


def test_aoi_and_ridges(tmp_path):
    ref = [Polygon([(0, 0, 5), (10, 0, 5), (10, 8, 5), (0, 8, 5)]), box(100, 0, 110, 10)]
    ext = [Polygon([(0, 0, 5.3), (10, 0, 5.3), (10, 8, 5.3), (0, 8, 5.3)])]
    r = _write(tmp_path / "ref.gpkg", ref, ridges=[LineString([(0, 4, 8), (10, 4, 8)])], gtype="PolygonZ")
    e = _write(tmp_path / "ext.gpkg", ext, ridges=[LineString([(0, 4.2, 8), (10, 4.2, 8)])], gtype="PolygonZ")
    aoi = _write(tmp_path / "aoi.fgb", [box(-5, -5, 50, 50)], layer="aoi")
    out = tmp_path / "o"
    assert main(["evaluate", str(e), str(r), "-o", str(out), "--aoi", str(aoi), "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_reference"] == 1 and m["completeness"] == 1.0
    assert m["rmse_z"] == pytest.approx(0.3, abs=1e-9)
    assert m["ridge_position_error"] == pytest.approx(0.2, abs=1e-9) and m["ridge_completeness"] == 1.0


def test_user_errors(tmp_path, files, capsys):
    e, r, ext, ref = files
    other = _write(tmp_path / "wgs.gpkg", [box(0, 0, 1, 1)], crs="EPSG:4326")
    lines = tmp_path / "lines.gpkg"
    rd = pyproj.CRS.from_user_input(RD)
    write_layers(lines, {"l": Layer([LineString([(0, 0), (1, 1)])], {}, "LineString", rd)}, rd)
    cases = [
        ([str(e), str(other)], "different CRS"),
        ([str(e), str(tmp_path / "nope.gpkg")], "no such file"),
        ([str(lines), str(r)], "must be polygons"),
        ([str(e), str(r), "--layer", "nolayer"], "no layer"),
        ([str(e), str(r), "--min-overlap", "0"], "--min-overlap"),
        ([str(e), str(r), "--corner-tolerance", "0"], "--corner-tolerance"),
        ([str(e), str(r), "--aoi", str(lines)], "must be polygons"),
        ([str(e), str(r), "--camera", str(r)], "--camera needs --image"),
        ([str(e), str(r), "--compare", str(lines)], "must be polygons"),
        ([str(e), str(r), "--image", str(tmp_path / "plain.tif")], "no georeference"),
    ]
    write_geotiff(tmp_path / "plain.tif", np.zeros((8, 8), np.uint8))
    for k, (args, text) in enumerate(cases):
        code = main(["evaluate", *args, "-o", str(tmp_path / f"o{k}")])
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        assert err.startswith("error:") and text in err and "Traceback" not in err
        assert not (tmp_path / f"o{k}" / "metrics.json").exists()
    # --crs overrides both files' CRS: the mismatch is then the user's explicit choice
    assert main(["evaluate", str(e), str(other), "-o", str(tmp_path / "ov"), "--crs", RD]) == 0
    assert "overridden by --crs" in capsys.readouterr().err


def test_compare_and_orthophoto(tmp_path, files, capsys):
    """A second extracted set side by side, and an orthophoto under the outlines (no camera file needed)."""
    e, r, ext, ref = files
    other = _write(tmp_path / "lidar_only.gpkg", [translate(p, 0.0, 0.8) for p in ref])
    ortho = write_geotiff(tmp_path / "ortho.tif", np.full((3, 60, 260), 120, np.uint8),
                          transform=(0.2, 0.0, -1.0, 0.0, -0.2, 11.0), crs=pyproj.CRS.from_user_input(RD))
    out = tmp_path / "o"
    assert main(["evaluate", str(e), str(r), "-o", str(out), "--compare", str(other), "--compare-label",
                 "LiDAR only", "--label", "refined", "--image", str(ortho)]) == 0
    text = capsys.readouterr().out
    assert "refined" in text and "LiDAR only: 3 reference and 3 extracted buildings" in text
    m = json.loads((out / "metrics.json").read_text())
    assert m["compare"]["label"] == "LiDAR only" and m["inputs"]["label"] == "refined"
    # the compared set is evaluated as the first: a 0.8 m shift in y against 0.4 m in x
    assert m["compare"]["rmse_y"] > 0.4 and m["compare"]["rmse_x"] == 0.0 and m["polis_mean"] < m["compare"]["polis_mean"]
    html = (out / "report.html").read_text()
    assert "<th>refined</th><th>LiDAR only</th>" in html and (out / "image.png").is_file()
    assert main(["evaluate", str(e), str(r), "-o", str(out), "--overwrite", "--compare", str(other),
                 "--json", "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["compare"]["label"] == "lidar_only.gpkg"
    # an orthophoto in another CRS than the outlines is refused
    web = write_geotiff(tmp_path / "web.tif", np.zeros((10, 10), np.uint8), transform=(1.0, 0, 0, 0, -1.0, 10.0),
                        crs=pyproj.CRS.from_user_input("EPSG:3857"))
    assert main(["evaluate", str(e), str(r), "-o", str(tmp_path / "w"), "--image", str(web)]) == 2
    assert "different CRS" in capsys.readouterr().err


def test_missing_crs_is_a_warning(tmp_path, files, capsys):
    e, r, ext, ref = files
    with pytest.warns(UserWarning, match="crs"):  # pyogrio's note when writing without a CRS
        nocrs = _write(tmp_path / "nocrs.gpkg", ref, crs=None)
    assert main(["evaluate", str(e), str(nocrs), "-o", str(tmp_path / "o")]) == 0
    assert "has no CRS" in capsys.readouterr().err


@pytest.mark.slow
def test_bgt_against_itself_and_buffered(tmp_path):
    src = need(DELFT / "bgt_pand.sqlite")
    out = tmp_path / "self"
    assert main(["evaluate", str(src), str(src), "-o", str(out), "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_matched"] == m["n_reference"] == 160
    assert (m["f_score"], m["polis_mean"], m["hausdorff_mean"]) == (1.0, 0.0, 0.0)
    from rooftrace.io.vector import read_layer

    ref = read_layer(src)
    buf = [g.buffer(0.3) for g in ref.geometries]
    b = _write(tmp_path / "buf.gpkg", buf)
    out = tmp_path / "buf"
    assert main(["evaluate", str(b), str(src), "-o", str(out), "-q"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    union_r, union_b = shapely.union_all(ref.geometries), shapely.union_all(buf)
    assert m["completeness"] == pytest.approx(1.0, abs=1e-9)
    assert m["correctness"] == pytest.approx(union_r.area / union_b.area, abs=1e-9)
    # every buffered vertex lies 0.3 m off the original outline or on a reflex corner's offset
    assert 0.3 - 1e-6 <= m["polis_mean"] < 0.36 and m["n_matched"] == 160
    assert not math.isnan(m["rmse_x"])


def test_shapefile_reference(tmp_path, files):
    e, r, ext, ref = files
    import geopandas

    # written with geopandas: write_layers refuses Shapefiles (several files, no atomic rename); evaluate reads them
    shp = tmp_path / "ref.shp"
    geopandas.GeoDataFrame({"bid": [10, 11, 12]}, geometry=ref, crs=RD).to_file(shp)
    out = tmp_path / "o"
    assert main(["evaluate", str(e), str(shp), "-o", str(out), "-q", "--json"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["polis_mean"] == pytest.approx(0.2, abs=1e-9) and m["n_matched"] == 3
