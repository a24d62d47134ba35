import math

import numpy as np
import pytest
import shapely

from rooftrace.synth import Building, SceneOptions
from rooftrace.synth.als import _strip_pulses, strip_layout
from rooftrace.synth.raycast import cast_rays
from rooftrace.synth.scene import make_terrain
from rooftrace.synth.simulate import surface_model
from rooftrace.synth.truth import roof_faces

O = np.array([85000.0, 447000.0])


@pytest.fixture(scope="module")
def gable_model():
    opts = SceneOptions(size=30.0, seed=4)
    terrain = make_terrain(opts, np.random.default_rng(0))
    b = Building.rectangle(1, O + 15, 12.0, 8.0, angle_deg=25, kind="gable", eave_height=6, ridge_height=9, overhang=0.5)
    b.base_height = float(terrain.height(*(O + 15)))
    faces = roof_faces(b)
    return opts, terrain, b, faces, surface_model(opts, faces, terrain)


def test_vertical_rays_hit_the_exact_roof_planes_and_terrain(gable_model):
    opts, terrain, b, faces, model = gable_model
    rng = np.random.default_rng(1)
    xy = O + rng.uniform(0.5, 29.5, (3000, 2))
    orig = np.column_stack([xy, np.full(len(xy), 500.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    t, face, wall = cast_rays(orig, dirs, *model.args(), model.z_top, model.z_bot)
    z = 500.0 - t
    outline = b.roof_outline
    d = shapely.distance(outline.boundary, shapely.points(xy))
    inside = shapely.contains_xy(outline, xy[:, 0], xy[:, 1]) & (d > 0.05)
    outside = ~shapely.contains_xy(outline, xy[:, 0], xy[:, 1]) & (d > 0.05)
    np.testing.assert_allclose(z[inside], b.base_height + b.height(xy[inside, 0], xy[inside, 1]), atol=1e-6)
    np.testing.assert_allclose(z[outside], terrain.height(xy[outside, 0], xy[outside, 1]), atol=1e-6)
    assert np.all(face[inside] >= 0) and np.all(face[outside] == -1) and not wall.any()


def test_oblique_rays_meet_the_walls_at_the_roof_edge(gable_model):
    opts, terrain, b, faces, model = gable_model
    # rays coming from outside, 20 degrees off vertical, aimed at the wall 3 m above the base
    ring = b.roof_outline.exterior
    p = np.array([ring.interpolate(s, normalized=True).coords[0] for s in np.linspace(0.01, 0.99, 60)])
    c = np.asarray(b.roof_outline.centroid.coords[0])
    out = (p - c) / np.linalg.norm(p - c, axis=1, keepdims=True)
    s20, c20 = math.sin(math.radians(20)), math.cos(math.radians(20))
    d = np.column_stack([-out * s20, np.full(len(p), -c20)])
    target = np.column_stack([p, np.full(len(p), b.base_height + 3.0)])
    orig = target - 60.0 * d
    t, face, wall = cast_rays(orig, d, *model.args(), model.z_top, model.z_bot)
    hit = orig + t[:, None] * d
    assert wall.all() and np.all(face >= 0)
    # the 5 cm face raster: walls are within a cell diagonal in plan, hence /tan(20 deg) in height
    assert shapely.distance(ring, shapely.points(hit[:, :2])).max() < 0.05
    assert np.abs(hit[:, 2] - target[:, 2]).max() < 0.05 / math.tan(math.radians(20)) + 0.01


def test_strip_pulses_follow_the_scan_geometry():
    opts = SceneOptions(size=60.0, density=6.0, flying_height=400.0, scan_angle_deg=15.0)
    layout = strip_layout(opts)
    assert layout["swath"] == pytest.approx(2 * 400 * math.tan(math.radians(15)))
    assert len(layout["offsets"]) >= 2
    o, d, t, beta, dbeta = _strip_pulses(opts, layout, 0, 10.0, np.random.default_rng(0))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    off_nadir = np.degrees(np.arccos(-d[:, 2]))
    # eq. 2.4: the beam leaves at the scan angle, tilted by the attitude (< 0.5 deg) and boresight
    assert np.all(np.abs(off_nadir - np.degrees(np.abs(beta))) < 0.8)
    assert np.degrees(np.abs(beta)).max() == pytest.approx(15.0, abs=0.01)
    assert np.all(np.abs(o[:, 2] - 410.0) < 2.5)
    step = np.linalg.norm(np.diff(o[:, :2], axis=0), axis=1)
    assert np.median(step) == pytest.approx(opts.flight_speed / layout["pulse_rate"], rel=0.05)
    assert np.all(np.diff(t) > 0)
