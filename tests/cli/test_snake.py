"""``rooftrace snake`` end to end on a rendered scene written to files (issue 8)."""

import json
from dataclasses import replace

import numpy as np
import pyproj
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.cloud import PointCloud
from rooftrace.evaluate.metrics import polis
from rooftrace.io.camera import write_camera
from rooftrace.io.las import write_las
from rooftrace.io.raster import write_geotiff
from rooftrace.io.vector import Layer, read_layer, write_layers
from rooftrace.snake.scene import Roof, l_shape, rectangle, render_scene

CRS = pyproj.CRS.from_epsg(28992)
SHIFT = np.array([85000.0, 445000.0, 0.0])  # map-sized coordinates


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("snake")
    scene = render_scene([Roof(rectangle(-10, -8, 14, 9, 15), 7.0), Roof(l_shape(10, 9, 15, 6, -5), 6.0)],
                         extent=50.0, seed=4)
    cam = scene.camera
    cam = replace(cam, exterior=cam.exterior + np.r_[SHIFT, 0, 0, 0], crs=CRS)
    write_geotiff(d / "image.tif", np.round(np.repeat(scene.image[None], 3, 0) * 255).astype(np.uint8))
    write_camera(d / "camera.json", cam)
    write_las(d / "points.laz", PointCloud(scene.xyz + SHIFT, crs=CRS))
    truth = [t + SHIFT for t in scene.truth]
    rng = np.random.default_rng(1)
    geoms, names = [], []
    for name, t in zip(["house", "ell"], truth):
        for p in t[:, :2] + rng.uniform(-0.7, 0.7, (len(t), 2)):
            geoms.append(shapely.Point(p))
            names.append(name)
    write_layers(d / "seeds.geojson", {"seeds": Layer(geoms, {"building": names}, "Point")}, CRS)
    return d, truth, cam


def _args(d, seeds="seeds.geojson", out="out.gpkg"):
    return ["snake", "--image", str(d / "image.tif"), "--camera", str(d / "camera.json"), "--points",
            str(d / "points.laz"), "--seeds", str(d / seeds), "-o", str(d / out), "--quiet"]


def test_snake_cli_writes_outlines(files, capsys):
    d, truth, _ = files
    assert main(_args(d) + ["--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["buildings"] == 2
    layer = read_layer(d / "out.gpkg", "roof_outlines")
    assert layer.attributes["building"] == ["house", "ell"]
    assert layer.crs.equals(CRS)
    for geom, t in zip(layer.geometries, truth):
        assert shapely.has_z(geom) and len(geom.exterior.coords) == len(t) + 1
        assert polis(geom, shapely.Polygon(t)) < 0.2
        np.testing.assert_allclose(shapely.get_coordinates(geom, include_z=True)[:-1, 2], t[:, 2], atol=0.2)
    assert all(e < 0 for e in layer.attributes["energy"])
    # refuses to overwrite without --overwrite
    assert main(_args(d)) == 2
    assert main(_args(d) + ["--overwrite"]) == 0


def test_snake_cli_multipoint_pixel_seeds(files):
    d, truth, cam = files
    geoms = [shapely.MultiPoint(cam.project(t) + 1.5) for t in truth]
    write_layers(d / "px.geojson", {"seeds": Layer(geoms, {"building": [7, 8]}, "MultiPoint")}, None)
    assert main(_args(d, "px.geojson", "px.gpkg") + ["--seeds-in-pixels"]) == 0
    layer = read_layer(d / "px.gpkg", "roof_outlines")
    assert [int(b) for b in layer.attributes["building"]] == [7, 8]
    for geom, t in zip(layer.geometries, truth):
        assert polis(geom, shapely.Polygon(t)) < 0.2


@pytest.mark.parametrize("case, match", [
    ("no_attr", "'building' attribute"),
    ("two", "at least 3"),
    ("pixels_out", "outside the image"),
    ("line", "Point or MultiPoint"),
])
def test_snake_cli_bad_seeds(files, capsys, case, match):
    d, truth, cam = files
    pts = [shapely.Point(p) for p in truth[0][:, :2]]
    attrs = {"building": [1] * len(pts)}
    extra = []
    if case == "no_attr":
        attrs = {"name": ["a"] * len(pts)}
    elif case == "two":
        pts, attrs = pts[:2], {"building": [1, 1]}
    elif case == "pixels_out":
        pts = [shapely.Point(5000, 10), shapely.Point(10, 10), shapely.Point(10, 50)]
        attrs = {"building": [1, 1, 1]}
        extra = ["--seeds-in-pixels"]
    elif case == "line":
        pts, attrs = [shapely.LineString(truth[0][:, :2])], {"building": [1]}
    write_layers(d / f"{case}.geojson", {"s": Layer(pts, attrs, "Unknown")}, CRS, overwrite=True)
    assert main(_args(d, f"{case}.geojson", f"{case}.gpkg") + extra) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and match in err
    assert not (d / f"{case}.gpkg").exists()


def test_snake_cli_seeds_off_image(files, capsys):
    d, truth, _ = files
    pts = [shapely.Point(p) for p in truth[0][:, :2] + [0.0, 80.0]]
    write_layers(d / "far.geojson", {"s": Layer(pts, {"building": [1] * 4}, "Point")}, CRS, overwrite=True)
    assert main(_args(d, "far.geojson", "far.gpkg")) == 2
    err = capsys.readouterr().err
    assert "error:" in err and ("outside the image" in err or "LiDAR points" in err)


def test_snake_cli_config_table(files, capsys):
    d, truth, _ = files
    (d / "paper.toml").write_text("[snake]\nw_height = 0.0\nw_angle = 1.0\n")
    assert main(_args(d, out="paper.gpkg") + ["--config", str(d / "paper.toml")]) == 0
    assert len(read_layer(d / "paper.gpkg", "roof_outlines")) == 2
    (d / "typo.toml").write_text("[snake]\nw_angel = 1.0\n")
    assert main(_args(d, out="typo.gpkg") + ["--config", str(d / "typo.toml")]) == 2
    assert "w_angel" in capsys.readouterr().err


def test_snake_cli_plain_geojson_in_map_coordinates(files):
    # a hand-written GeoJSON has no "crs" member: it reads as WGS 84, but the
    # coordinates are metres in the cloud's CRS and must be taken as such
    d, truth, _ = files
    feats = [{"type": "Feature", "properties": {"building": "b"},
              "geometry": {"type": "MultiPoint", "coordinates": (truth[0][:, :2] + 0.3).tolist()}}]
    (d / "plain.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    assert main(_args(d, "plain.geojson", "plain.gpkg")) == 0
    geom = read_layer(d / "plain.gpkg", "roof_outlines").geometries[0]
    assert polis(geom, shapely.Polygon(truth[0])) < 0.2
