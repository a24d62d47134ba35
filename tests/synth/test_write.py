import json

import numpy as np
import pytest

from rooftrace.errors import OutputExistsError
from rooftrace.io.camera import read_camera
from rooftrace.io.las import read_las
from rooftrace.io.vector import list_layers, read_layer
from rooftrace.synth import write_scene
from rooftrace.synth.preview import save_preview


def test_write_scene_files_round_trip(small_scene, tmp_path):
    paths = write_scene(tmp_path / "scene", small_scene, perturbed_camera_px=3.0)
    assert {p.name for p in paths.values()} == {"points.laz", "image.tif", "camera.json", "truth.gpkg",
                                               "camera_perturbed.json", "scene.json"}
    cloud = read_las(paths["points"])
    assert len(cloud) == len(small_scene.cloud)
    np.testing.assert_allclose(cloud.xyz, small_scene.cloud.xyz, atol=6e-4)
    np.testing.assert_array_equal(cloud.fields["truth_class"], small_scene.cloud.fields["truth_class"])
    np.testing.assert_array_equal(cloud.fields["truth_building_id"], small_scene.cloud.fields["truth_building_id"])
    assert np.all(cloud.fields["classification"] == 1)
    assert cloud.crs is not None and cloud.crs.to_epsg() == 28992
    assert set(list_layers(paths["truth"])) == {"roof_outlines", "ridges", "footprints", "roof_faces"}
    outlines = read_layer(paths["truth"], "roof_outlines")
    assert len(outlines) == len(small_scene.buildings) and outlines.geometries[0].has_z
    ridges = read_layer(paths["truth"], "ridges")
    assert set(ridges.attributes["kind"]) <= {"ridge", "hip", "valley", "step"}
    faces = read_layer(paths["truth"], "roof_faces")
    assert "slope_deg" in faces.attributes and "aspect_deg" in faces.attributes
    cam = read_camera(paths["camera"])
    xyz = np.asarray(outlines.geometries[0].exterior.coords)
    np.testing.assert_allclose(cam.project(xyz), small_scene.camera.project(xyz), atol=1e-6)
    meta = json.loads(paths["scene"].read_text())
    assert meta["options"]["seed"] == 3 and meta["info"]["points"] == len(small_scene.cloud)


def test_perturbed_camera_moves_projections_by_the_requested_pixels(small_scene, tmp_path):
    paths = write_scene(tmp_path, small_scene, perturbed_camera_px=4.0)
    true, off = read_camera(paths["camera"]), read_camera(paths["camera_perturbed"])
    pts = np.vstack([np.asarray(g.exterior.coords) for g in small_scene.truth["roof_outlines"].geometries])
    shift = np.hypot(*(off.project(pts) - true.project(pts)).T)
    assert shift.mean() == pytest.approx(4.0, rel=0.05)
    cov = off.exterior_covariance
    assert cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
    # the covariance predicts displacements of the same size
    pred = np.sqrt(np.mean(np.einsum("nik,kl,nil->n", *[off.jacobians(pts)[0]] * 1, cov, off.jacobians(pts)[0])))
    assert 1.0 < pred < 16.0
    delta = off.exterior - true.exterior
    assert np.all(np.abs(delta) / np.sqrt(np.diag(cov)) < 5)


def test_write_scene_refuses_to_overwrite(small_scene, tmp_path):
    write_scene(tmp_path, small_scene)
    with pytest.raises(OutputExistsError, match="overwrite"):
        write_scene(tmp_path, small_scene)
    paths = write_scene(tmp_path, small_scene, overwrite=True)
    assert paths["points"].exists()


def test_orthophoto_is_written_as_geotiff(ortho_scene, tmp_path):
    from rooftrace.io.raster import read_raster_meta

    paths = write_scene(tmp_path, ortho_scene)
    meta = read_raster_meta(paths["image"])
    assert meta.transform == pytest.approx(ortho_scene.ortho_transform)
    assert meta.count == 3 and meta.crs.to_epsg() == 28992
    cam = read_camera(paths["camera"], image=paths["image"])
    assert cam.kind == "orthophoto"


def test_preview_png(small_scene, tmp_path):
    out = save_preview(small_scene, tmp_path / "preview.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert 20_000 < len(data) < 300_000
