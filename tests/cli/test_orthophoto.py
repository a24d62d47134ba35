"""``--image`` with a georeferenced orthophoto needs no camera file; a frame image without one is one clear error (issue 21)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rooftrace.cli.main import main
from rooftrace.io.camera import image_camera, read_camera
from rooftrace.io.raster import write_geotiff
from rooftrace.io.vector import list_layers, read_layer
from tests.cli.badfiles import scene_xyz, write_las_file
from tests.conftest import IGN, need

BOTH = ("--camera camera.json", "georeferenced orthophoto")


@pytest.fixture(scope="module")
def ortho_scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("ortho") / "scene"
    assert main(["simulate", "-o", str(out), "--size", "40", "--density", "4", "--orthophoto", "--gsd", "0.4",
                 "--seed", "3", "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def frame_image(tmp_path_factory):
    """A TIFF with no georeference, as an aerial frame image is."""
    path = tmp_path_factory.mktemp("frame") / "photo.tif"
    write_geotiff(path, np.full((3, 20, 30), 128, np.uint8))
    return path


def test_the_geotiff_is_the_camera(ortho_scene):
    tif = ortho_scene / "image.tif"
    assert json.loads((ortho_scene / "camera.json").read_text())["type"] == "orthophoto"
    derived = image_camera(tif)
    from_file = read_camera(ortho_scene / "camera.json", tif)
    assert derived.image_size == from_file.image_size
    assert np.allclose(derived.transform, from_file.transform)
    assert derived.crs.equals(from_file.crs)
    xyz = np.array([[1.0, 2.0, 30.0], [-15.0, 12.5, 0.0]]) + ortho_scene_origin(ortho_scene)
    assert np.allclose(derived.project(xyz), from_file.project(xyz))


def ortho_scene_origin(folder):
    truth = read_layer(folder / "truth.gpkg", "roof_outlines")
    c = truth.geometries[0].centroid
    return np.array([c.x, c.y, 0.0])


def test_refine_with_the_orthophoto_alone_equals_with_its_camera_file(ortho_scene, tmp_path, capsys):
    tif, truth = ortho_scene / "image.tif", ortho_scene / "truth.gpkg"
    outs = []
    for name, extra in (("alone", []), ("file", ["--camera", str(ortho_scene / "camera.json")])):
        out = tmp_path / f"{name}.gpkg"
        assert main(["refine", str(truth), "--image", str(tif), *extra, "-o", str(out), "-q", "--json"]) == 0
        outs.append(read_layer(out, "roof_outlines"))
    capsys.readouterr()
    assert len(outs[0]) == len(outs[1]) > 0
    for a, b in zip(outs[0].geometries, outs[1].geometries):
        assert a.equals_exact(b, 1e-9)


@pytest.mark.parametrize("command", ["run", "refine", "snake"])
def test_a_frame_image_without_camera_says_what_to_give(command, frame_image, tmp_path, capsys):
    laz = write_las_file(tmp_path / "scene.laz", scene_xyz())
    out = tmp_path / "out.gpkg"
    if command == "run":
        args = ["run", str(laz), "--image", str(frame_image), "-o", str(out)]
    elif command == "refine":
        src = tmp_path / "roofs.gpkg"
        assert main(["outline", "--single-building", str(laz), "-o", str(src), "-q"]) in (0, 2)
        args = ["refine", str(src), "--image", str(frame_image), "-o", str(out)]
    else:
        seeds = tmp_path / "seeds.geojson"
        seeds.write_text(json.dumps({"type": "FeatureCollection", "features": []}))
        args = ["snake", "--image", str(frame_image), "--points", str(laz), "--seeds", str(seeds), "-o", str(out)]
    if command == "refine" and not src.exists():
        pytest.skip("no outline to refine")
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {frame_image}: no georeference")
    assert all(option in err for option in BOTH)
    assert not out.exists()


def test_run_help_shows_both_cases(capsys):
    assert main(["run", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--image ortho.tif -o roofs.gpkg" in text and "--image photo.tif --camera camera.json" in text


def test_camera_without_image_is_refused(tmp_path, capsys):
    laz = write_las_file(tmp_path / "scene.laz", scene_xyz())
    assert main(["run", str(laz), "--camera", str(tmp_path / "camera.json"), "-o", str(tmp_path / "o.gpkg")]) == 2
    assert "--camera needs --image" in capsys.readouterr().err


@pytest.mark.slow
def test_ign_runs_with_the_orthophoto_alone(tmp_path, capsys):
    laz = need(IGN / "test_data_77055_627760_LA93_IGN69.laz")
    tif = need(IGN / "test_data_rgb.tif")
    out = tmp_path / "roofs.gpkg"
    assert main(["run", str(laz), "--image", str(tif), "-o", str(out), "-q", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["refined"] is True and summary["buildings"] >= 3
    assert {"roof_outlines", "ridges", "roof_faces"} <= set(list_layers(out))
