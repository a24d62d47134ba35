"""The snake on rendered scenes with exact truth (issue 8, DESIGN.md stage 10)."""

import numpy as np
import pytest
import shapely

from rooftrace.errors import InputError
from rooftrace.evaluate.metrics import polis
from rooftrace.snake.scene import Roof, l_shape, rectangle, render_scene
from rooftrace.snake.seeds import pixel_seeds_to_object
from rooftrace.snake.snake import SnakeOptions, snake_outline


@pytest.fixture(scope="module")
def scene():
    roofs = [Roof(rectangle(-12, -8, 16, 9, 20), 8.0),
             Roof(l_shape(12, 10, 16, 7, -10), 6.0, grey=0.85),
             Roof(rectangle(10, -14, 14, 8, 5), 7.0, "gable", 3.0)]
    return render_scene(roofs, seed=3)


def _perturb(ring, seed, radius=1.0):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi, len(ring))
    r = radius * np.sqrt(rng.uniform(0.3, 1.0, len(ring)))
    return ring[:, :2] + np.column_stack([r * np.cos(ang), r * np.sin(ang)])


@pytest.mark.parametrize("which", [0, 1, 2], ids=["rectangle", "l-shape", "gable"])
def test_snake_recovers_outline_from_perturbed_seeds(scene, which):
    truth = scene.truth[which]
    seeds = _perturb(truth, 10 + which)
    res = snake_outline(seeds, scene.image, scene.camera, scene.xyz)
    assert res.xyz.shape == (len(truth), 3)
    assert res.converged
    assert polis(shapely.Polygon(seeds), shapely.Polygon(truth)) > 0.3  # the seeds were off
    assert polis(shapely.Polygon(res.xyz), shapely.Polygon(truth)) < 0.15
    np.testing.assert_allclose(res.xyz[:, 2], truth[:, 2], atol=0.2)
    assert res.energy < -0.5 * len(truth)  # most sides sit on strong edges
    assert res.terms["angle"] < 0.01 * len(truth)  # right angles


def test_snake_seed_order_and_direction_do_not_matter(scene):
    truth = scene.truth[0]
    seeds = _perturb(truth, 3)
    a = snake_outline(seeds, scene.image, scene.camera, scene.xyz).xyz
    b = snake_outline(seeds[::-1], scene.image, scene.camera, scene.xyz).xyz[::-1]
    c = snake_outline(np.roll(seeds, 1, 0), scene.image, scene.camera, scene.xyz).xyz
    np.testing.assert_allclose(a, b, atol=1e-9)
    np.testing.assert_allclose(a, np.roll(c, -1, 0), atol=1e-9)


def test_snake_is_deterministic_and_ignores_point_order(scene):
    seeds = _perturb(scene.truth[1], 4)
    a = snake_outline(seeds, scene.image, scene.camera, scene.xyz)
    perm = np.random.default_rng(0).permutation(len(scene.xyz))
    b = snake_outline(seeds, scene.image, scene.camera, scene.xyz[perm])
    np.testing.assert_allclose(a.xyz[:, :2], b.xyz[:, :2], atol=1e-9)
    np.testing.assert_allclose(a.xyz[:, 2], b.xyz[:, 2], atol=1e-6)
    assert a.energy == pytest.approx(b.energy)


def test_right_angle_weight_straightens_corners(scene):
    truth = scene.truth[2]
    seeds = _perturb(truth, 8)
    free = snake_outline(seeds, scene.image, scene.camera, scene.xyz, SnakeOptions(w_angle=0.0))
    square = snake_outline(seeds, scene.image, scene.camera, scene.xyz, SnakeOptions(w_angle=2.0))
    assert square.terms["angle"] <= free.terms["angle"] + 1e-12


def test_pixel_seeds_map_to_object_space(scene):
    truth = scene.truth[0]
    cr = scene.camera.project(truth)
    xy = pixel_seeds_to_object(cr, scene.camera, scene.xyz)
    # the roof surface is dilated by ~0.5 m: a corner's height is the roof's
    np.testing.assert_allclose(xy, truth[:, :2], atol=0.1)


def test_snake_input_errors(scene):
    ring = scene.truth[0][:, :2]
    with pytest.raises(InputError, match="at least 3 seed"):
        snake_outline(ring[:2], scene.image, scene.camera, scene.xyz)
    with pytest.raises(InputError, match="coincide"):
        snake_outline(np.vstack([ring, ring[-1:]]), scene.image, scene.camera, scene.xyz)
    with pytest.raises(InputError, match="LiDAR points near the seeds"):
        snake_outline(ring + 1000.0, scene.image, scene.camera, scene.xyz)
    far = scene.xyz.copy()
    far[:, 0] += 200.0  # cloud and seeds moved together, off the image
    with pytest.raises(InputError, match="outside the image"):
        snake_outline(ring + [200.0, 0.0], scene.image, scene.camera, far)


@pytest.mark.parametrize("kw, match", [({"grid": 4}, "grid"), ({"window": 0}, "window"),
                                       ({"shrink": 1.0}, "shrink"), ({"w_angle": -1}, "w_angle"),
                                       ({"min_step": 0.0}, "min_step")])
def test_options_are_checked(kw, match):
    with pytest.raises(ValueError, match=match):
        SnakeOptions(**kw)
