"""``rooftrace refine`` end to end: GeoPackage + image + camera.json in, refined layers out; user errors."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyproj
import pytest
import shapely
from shapely.affinity import translate

from rooftrace.cli.main import main
from rooftrace.evaluate.metrics import polis
from rooftrace.io.camera import write_camera
from rooftrace.io.raster import write_geotiff
from rooftrace.io.vector import Layer, read_layer, write_layers
from tests.refine.test_buildings import _perturb, _scene

RD = pyproj.CRS.from_user_input("EPSG:28992")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("refine")
    cam, img, truth, ridges, _ = _scene()
    rng = np.random.default_rng(7)
    lidar = [_perturb(p, rng) for p in truth]
    lidar_ridges = [_perturb(r, rng, sigma=0.2) for r in ridges]
    write_layers(tmp / "lidar.gpkg", {
        "roof_outlines": Layer(lidar, {"building_id": [11, 12], "name": ["flat", "gable"]}, "PolygonZ"),
        "ridges": Layer(lidar_ridges, {"building_id": [12], "kind": ["ridge"]}, "LineStringZ"),
    }, RD)
    write_layers(tmp / "far.gpkg", {"roof_outlines": Layer([translate(p, 5000, 0) for p in lidar], {}, "PolygonZ")}, RD)
    write_layers(tmp / "noroofs.gpkg", {"ridges": Layer(lidar_ridges, {}, "LineStringZ")}, RD)
    write_geotiff(tmp / "image.tif", np.clip(np.round(img * 255), 0, 255).astype(np.uint8))
    write_camera(tmp / "camera.json", replace(cam, crs=RD))
    write_camera(tmp / "camera_wgs.json", replace(cam, crs=pyproj.CRS.from_user_input("EPSG:3857")))
    return tmp, truth, lidar


def _run(tmp, *args):
    return main(["refine", str(tmp / "lidar.gpkg"), "--image", str(tmp / "image.tif"), "--camera",
                 str(tmp / "camera.json"), *map(str, args)])


def test_refine_writes_refined_layers_with_attributes(files, capsys):
    tmp, truth, lidar = files
    out = tmp / "out.gpkg"
    assert _run(tmp, "-o", out, "--json", "--quiet", "--seed", "3") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["buildings"] == 2 and summary["status"] == {"refined": 2}
    assert summary["exact_checked"] == 2 and summary["ga_reached_exact"] == 2
    roofs = read_layer(out, "roof_outlines")
    assert roofs.crs.equals(RD)
    assert roofs.attributes["name"] == ["flat", "gable"] and roofs.attributes["building_id"] == [11, 12]
    assert roofs.attributes["candidates_per_side"][1].count(",") == 3
    assert set(roofs.attributes) >= {"refine_status", "refined_sides", "refine_energy", "ga_exact_gap"}
    for before, after, true in zip(lidar, roofs.geometries, truth):
        assert polis(after, true) < 0.5 * polis(before, true)
    ridges = read_layer(out, "ridges")
    assert ridges.attributes["kind"] == ["ridge"] and ridges.attributes["refined"] == [1]
    # an existing output needs --overwrite
    assert _run(tmp, "-o", out, "--quiet") == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize("case, message", [
    ("crs", "different CRSs"),
    ("far", "does not cover"),
    ("nolayer", "no layer 'roof_outlines'"),
    ("suffix", "GeoPackage"),
    ("config", "[mrf] beta must be > 0"),
])
def test_user_errors_exit_2(files, capsys, case, message):
    tmp, _, _ = files
    src, cam, out = tmp / "lidar.gpkg", tmp / "camera.json", tmp / f"bad_{case}.gpkg"
    if case == "crs":
        cam = tmp / "camera_wgs.json"
    elif case == "far":
        src = tmp / "far.gpkg"
    elif case == "nolayer":
        src = tmp / "noroofs.gpkg"
    extra = []
    if case == "config":
        (tmp / "bad.toml").write_text("[mrf]\nbeta = -1\n")
        extra = ["--config", str(tmp / "bad.toml")]
    elif case == "suffix":
        out = tmp / "bad.shp"
    code = main(["refine", str(src), "--image", str(tmp / "image.tif"), "--camera", str(cam), "-o", str(out), "-q",
                 *extra])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error:") and message in err, err
    assert not out.exists()


def test_refine_with_points_uses_lidar_roof_planes(files, capsys):
    from rooftrace.cloud import PointCloud
    from rooftrace.io.las import write_las

    tmp, truth, lidar = files
    # 4 pts/m² on the gable's two faces and on the flat roof, plus ground around them
    rng = np.random.default_rng(5)
    pts = []
    for poly, z_of in ((truth[0], lambda x, y: np.full_like(x, 7.0)),
                       (truth[1], lambda x, y: np.where(y < -24.0, 6.0 + 0.5 * (y + 30.0), 6.0 + 0.5 * (-18.0 - y)))):
        x0, y0, x1, y1 = poly.bounds
        n = int(4 * (x1 - x0) * (y1 - y0))
        x, y = rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)
        inside = shapely.contains_xy(shapely.force_2d(poly), x, y)
        z = z_of(x[inside], y[inside]) + rng.normal(0, 0.03, inside.sum())
        pts.append(np.column_stack([x[inside], y[inside], z]))
    g = rng.uniform(-60, 60, (6000, 2))
    pts.append(np.column_stack([g, np.zeros(len(g))]))
    write_las(tmp / "points.laz", PointCloud(np.concatenate(pts), crs=RD))
    out = tmp / "with_points.gpkg"
    assert _run(tmp, "-o", out, "--points", tmp / "points.laz", "--json", "-q") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == {"refined": 2}
    roofs = read_layer(out, "roof_outlines")
    for before, after, true in zip(lidar, roofs.geometries, truth):
        assert polis(after, true) < 0.5 * polis(before, true)
    # the gable's eave corners land on its roof planes, at the eave height
    z = shapely.get_coordinates(roofs.geometries[1], include_z=True)[:, 2]
    np.testing.assert_allclose(z, 6.0, atol=0.25)
