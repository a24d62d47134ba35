import json

import numpy as np
import pyproj
import pytest
import shapely

from rooftrace.errors import InputError
from rooftrace.image.camera import FrameCamera
from rooftrace.io.camera import camera_to_dict, read_camera, write_camera
from rooftrace.io.vector import Layer, list_layers, read_layer, write_layers


def test_gpkg_layers_round_trip_3d(tmp_path):
    poly = shapely.Polygon([(0, 0, 5), (10, 0, 5), (10, 8, 6), (0, 8, 6)], holes=[[(2, 2, 5), (4, 2, 5), (4, 4, 5)]])
    line = shapely.LineString([(0, 4, 9), (10, 4, 9)])
    crs = pyproj.CRS.from_epsg(28992)
    out = write_layers(
        tmp_path / "o.gpkg",
        {
            "roof_outlines": Layer([poly], {"building_id": [1], "alpha_strategy": ["point"], "area": [80.0]}, "PolygonZ"),
            "ridges": Layer([line], {"kind": ["ridge"]}, "LineStringZ"),
            "roof_faces": Layer([], {"slope": []}, "PolygonZ"),
        },
        crs,
    )
    assert list_layers(out) == ["roof_outlines", "ridges", "roof_faces"]
    layer = read_layer(out, "roof_outlines")
    assert layer.crs.to_epsg() == 28992
    assert shapely.equals_exact(layer.geometries[0], poly, tolerance=1e-9)
    assert shapely.get_coordinates(layer.geometries[0], include_z=True)[2, 2] == 6
    assert layer.attributes["alpha_strategy"] == ["point"]
    assert len(read_layer(out, "roof_faces")) == 0
    with pytest.raises(InputError, match="no layer 'nope'"):
        read_layer(out, "nope")


def test_camera_json_round_trip(tmp_path):
    cam = FrameCamera((4500, 3000), 0.012, 120.0, np.array([85000, 447500, 1000, 0.01, -0.02, 0.3]),
                      distortion={"k1": 1e-6}, exterior_covariance=np.diag([0.1, 0.1, 0.1, 1e-6, 1e-6, 1e-6]),
                      crs=pyproj.CRS.from_epsg(28992))
    path = write_camera(tmp_path / "camera.json", cam)
    back = read_camera(path)
    np.testing.assert_allclose(back.exterior, cam.exterior, atol=1e-12)
    np.testing.assert_allclose(back.exterior_covariance, cam.exterior_covariance)
    assert back.crs.to_epsg() == 28992
    assert json.loads(path.read_text())["exterior"]["kappa_deg"] == pytest.approx(np.degrees(0.3))


@pytest.mark.parametrize(
    "patch,match",
    [
        ({"image_size": [10]}, "image_size"),
        ({"focal_length_mm": "long"}, "focal_length_mm"),
        ({"exterior": {"X0": 0}}, "Y0"),
        ({"type": "pinhole"}, "type"),
        ({"exterior_covariance": [[1, 2], [3, 4]]}, "6 x 6"),
        ({"distortion": {"k9": 1}}, "distortion"),
    ],
)
def test_bad_camera_json(tmp_path, patch, match):
    cam = FrameCamera((100, 80), 0.01, 50.0, np.array([0, 0, 500, 0, 0, 0.0]))
    data = camera_to_dict(cam)
    data.update(patch)
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(data))
    with pytest.raises(InputError, match=match):
        read_camera(p)
    p.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_camera(p)
