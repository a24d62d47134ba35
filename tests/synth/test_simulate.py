"""The issue's "done when" properties, on small scenes (issue 5)."""

import numpy as np
import pytest
import shapely

from rooftrace.errors import InputError
from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.synth import Building, SceneOptions, simulate_scene
from rooftrace.synth.checks import edge_gradient_ratio, outline_distances, roof_density, roof_point_heights


def _roof_points(scene):
    return roof_point_heights(scene)


def test_density_over_roofs_is_within_20_percent(small_scene):
    area = sum(b.roof_outline.area for b in small_scene.buildings)
    pts, dz = _roof_points(small_scene)
    on_roof = np.abs(dz) < 0.2
    assert np.count_nonzero(on_roof) / area == pytest.approx(8.0, rel=0.2)
    assert len(pts) / area == pytest.approx(8.0, rel=0.2)  # walls included
    assert roof_density(small_scene) == pytest.approx(np.count_nonzero(on_roof) / area)
    first = np.count_nonzero(small_scene.cloud.fields["return_number"] == 1) / 60.0**2
    assert first == pytest.approx(8.0, rel=0.05)


def test_building_points_lie_inside_their_roof_outline(small_scene):
    c = small_scene.cloud
    ids = c.fields["truth_building_id"]
    assert set(np.unique(ids[ids > 0])) == {b.building_id for b in small_scene.buildings}
    assert np.all((ids > 0) == (c.fields["truth_class"] == 6))
    for b in small_scene.buildings:
        m = ids == b.building_id
        d = shapely.distance(b.roof_outline, shapely.points(c.xyz[m, :2]))
        assert d.max() < 0.08, (b.building_id, d.max())
    assert outline_distances(small_scene).max() < 0.08


def test_roof_heights_carry_the_range_noise(small_scene):
    _, dz = _roof_points(small_scene)
    on = np.abs(dz) < 0.2
    assert 0.02 < np.std(dz[on]) < 0.045
    assert abs(np.mean(dz[on])) < 0.01


def test_cloud_is_raw_with_returns_strips_outliers_and_wires(small_scene):
    f = small_scene.cloud.fields
    assert np.all(f["classification"] == 1)
    assert f["truth_class"].dtype == np.uint8 and f["truth_building_id"].dtype == np.int32
    assert {2, 5, 6, 7, 14} <= set(np.unique(f["truth_class"]).tolist())
    assert np.all(f["return_number"] <= f["number_of_returns"])
    veg = f["truth_class"] == 5
    assert np.mean(f["number_of_returns"][veg] > 1) > 0.3  # crowns give multiple returns
    under = (f["truth_class"] == 2) & (f["number_of_returns"] > 1) & (f["return_number"] == f["number_of_returns"])
    assert np.count_nonzero(under) > 20  # last returns reach the ground below crowns
    assert len(np.unique(f["point_source_id"])) >= 2
    for s in np.unique(f["point_source_id"]):
        assert np.all(np.diff(f["gps_time"][f["point_source_id"] == s]) >= 0)
    z = small_scene.cloud.z
    noise = f["truth_class"] == 7
    terrain = small_scene.terrain.height(small_scene.cloud.x, small_scene.cloud.y)
    assert np.any(z[noise] > terrain[noise] + 20) and np.any(z[noise] < terrain[noise] - 1)
    assert np.all(np.abs(f["scan_angle"] * 0.006) <= small_scene.options.scan_angle_deg + 1.0)


def _edge_ratio(scene, camera):
    return edge_gradient_ratio(scene.image, camera, scene.truth["roof_outlines"].geometries)


def test_truth_edges_land_on_strong_image_gradients(small_scene):
    assert isinstance(small_scene.camera, FrameCamera)
    assert small_scene.image.dtype == np.uint8 and small_scene.image.shape[0] == 3
    assert _edge_ratio(small_scene, small_scene.camera) >= 3.0
    # a wrong camera (2 m shift) must lose the alignment: the check can fail
    eo = small_scene.camera.exterior.copy()
    eo[0] += 2.0
    assert _edge_ratio(small_scene, small_scene.camera.with_exterior(eo)) < 0.7 * _edge_ratio(small_scene, small_scene.camera)


def test_frame_camera_has_the_requested_gsd_and_looks_off_nadir(small_scene):
    cam = small_scene.camera
    c = np.array([*small_scene.options.center, small_scene.terrain.height(*small_scene.options.center)])
    px = cam.project(np.array([c, c + [1.0, 0, 0], c + [0, 1.0, 0]]))
    assert np.hypot(*(px[1] - px[0])) == pytest.approx(1 / 0.2, rel=0.1)
    assert np.hypot(*(px[2] - px[0])) == pytest.approx(1 / 0.2, rel=0.1)
    w, h = cam.image_size
    assert np.all(px[0] > 0.3 * w) and np.all(px[0] < 0.7 * w)
    nadir = np.hypot(*(cam.center[:2] - c[:2])) / (cam.center[2] - c[2])
    assert np.degrees(np.arctan(nadir)) == pytest.approx(6.0, abs=0.5)


def test_orthophoto_mode(ortho_scene):
    cam = ortho_scene.camera
    assert isinstance(cam, OrthoCamera)
    assert ortho_scene.ortho_transform == cam.transform
    assert cam.image_size == (300, 300)
    assert _edge_ratio(ortho_scene, cam) >= 3.0


def test_seed_reproduces_the_scene_and_changes_it():
    opts = SceneOptions(size=40.0, density=3.0, seed=11, gsd=0.4)
    a, b = simulate_scene(opts), simulate_scene(opts)
    np.testing.assert_array_equal(a.cloud.xyz, b.cloud.xyz)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.cloud.fields["intensity"], b.cloud.fields["intensity"])
    c = simulate_scene(SceneOptions(size=40.0, density=3.0, seed=12, gsd=0.4))
    assert len(c.cloud) != len(a.cloud) or not np.array_equal(c.cloud.xyz, a.cloud.xyz)
    # switching the image off leaves the cloud unchanged
    d = simulate_scene(SceneOptions(size=40.0, density=3.0, seed=11, gsd=0.4, image=False))
    np.testing.assert_array_equal(a.cloud.xyz, d.cloud.xyz)
    assert d.image is None and d.camera is None


def test_custom_buildings_and_tall_building_occlusion():
    o = np.array([85000.0, 447000.0])
    tower = Building.rectangle(1, o + [20, 20], 8.0, 8.0, kind="flat", eave_height=40.0, overhang=0.0)
    shed = Building.rectangle(2, o + [20, 6], 8.0, 5.0, kind="shed", eave_height=3.0, ridge_height=5.0)
    s = simulate_scene(SceneOptions(size=40.0, density=6.0, image=False, trees=False, outlier_fraction=0.0,
                                    scan_angle_deg=25.0, flying_height=150.0), buildings=[tower, shed])
    assert [b.building_id for b in s.buildings] == [1, 2] and tower.base_height is None  # input not modified
    assert {r["kind"] if isinstance(r, dict) else r for r in s.truth["roof_outlines"].attributes["kind"]} == {"flat", "shed"}
    # occlusion: each strip sees less ground on the far side of the tower than on its own side
    f = s.cloud.fields
    ground = f["truth_class"] == 2
    west = ground & shapely.contains_xy(shapely.box(*(o + [11, 17]), *(o + [15, 23])), s.cloud.x, s.cloud.y)
    east = ground & shapely.contains_xy(shapely.box(*(o + [25, 17]), *(o + [29, 23])), s.cloud.x, s.cloud.y)
    strips = np.unique(f["point_source_id"])
    assert len(strips) == 2
    first, last = f["point_source_id"] == strips[0], f["point_source_id"] == strips[-1]  # western, eastern strip
    assert np.count_nonzero(east & first) < 0.5 * np.count_nonzero(west & first)
    assert np.count_nonzero(west & last) < 0.5 * np.count_nonzero(east & last)


@pytest.mark.parametrize("kw, match", [
    ({"density": 0}, "density"), ({"size": 5}, "size"), ({"strip_overlap": 0.95}, "strip_overlap"),
    ({"gsd": 0.001}, "gsd"), ({"scan_angle_deg": 80}, "scan_angle"),
])
def test_bad_options_raise_input_error(kw, match):
    with pytest.raises(InputError, match=match):
        SceneOptions(**kw)


def test_buildings_outside_the_scene_or_duplicated_are_refused():
    o = np.array([85000.0, 447000.0])
    with pytest.raises(InputError, match="inside the scene"):
        simulate_scene(SceneOptions(size=40.0, image=False),
                       buildings=[Building.rectangle(1, o + [39, 20], 8.0, 6.0)])
    with pytest.raises(InputError, match="unique"):
        simulate_scene(SceneOptions(size=40.0, image=False),
                       buildings=[Building.rectangle(1, o + [10, 20], 6.0, 6.0), Building.rectangle(1, o + [28, 20], 6.0, 6.0)])


def test_power_line_shows_in_the_image_and_the_cloud(small_scene):
    f = small_scene.cloud.fields
    wire = small_scene.cloud.xyz[f["truth_class"] == 14]
    terrain = small_scene.terrain.height(wire[:, 0], wire[:, 1])
    assert len(wire) > 50 and np.all(wire[:, 2] - terrain > 10)
    x0, y0, x1, y1, z0, z1, sag = small_scene.power_line.as_array()[1]
    s = np.linspace(0.3, 0.7, 200)
    xyz = np.column_stack([x0 + s * (x1 - x0), y0 + s * (y1 - y0), z0 + s * (z1 - z0) - 4 * sag * s * (1 - s)])
    cr = small_scene.camera.project(xyz)
    grey = small_scene.image.astype(float).mean(axis=0)
    r, c = np.round(cr[:, 1]).astype(int), np.round(cr[:, 0]).astype(int)
    on, beside = grey[r, c], (grey[r + 4, c] + grey[r - 4, c]) / 2
    assert np.median(on - beside) < -4.0  # a faint dark line (1 px, blurred)


def test_tiny_and_empty_scenes():
    s = simulate_scene(SceneOptions(size=20.0, density=2.0, gsd=0.4))
    assert len(s.buildings) == 1 and s.buildings[0].kind == "gable"
    e = simulate_scene(SceneOptions(size=30.0, density=2.0, gsd=0.4), buildings=[])
    assert len(e.truth["roof_outlines"]) == 0 and np.all(e.cloud.fields["truth_building_id"] == 0)
    assert e.image.shape == (3, 84, 84)
