"""One-roof refinement helpers: the image/LiDAR fusion and the options."""

from __future__ import annotations

import numpy as np
import pytest

from rooftrace.refine.building import RefineOptions, fuse_positions


def test_fusion_removes_the_common_shift_then_weights_by_precision():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 100, (8, 2))
    lidar = truth - [3.0, -2.0] + rng.normal(0, 0.5, truth.shape)  # a camera error of ~3.6 px plus LiDAR noise
    image = truth + rng.normal(0, 0.5, truth.shape)
    use = np.ones(8, bool)
    use[0] = False
    equal = fuse_positions(image, lidar, use, 0.5, 0.5)
    t = np.median(image[use] - lidar[use], axis=0)
    np.testing.assert_allclose(equal[use], 0.5 * (image[use] + lidar[use] + t))
    np.testing.assert_array_equal(equal[0], image[0])  # unsupported vertices are untouched
    # a sparse cloud (large LiDAR sigma) leaves the image; a precise one pulls to the shifted LiDAR
    np.testing.assert_allclose(fuse_positions(image, lidar, use, 0.5, 1e3)[use], image[use], atol=1e-5)
    np.testing.assert_allclose(fuse_positions(image, lidar, use, 1e3, 0.5)[use], (lidar + t)[use], atol=1e-5)
    # both sources are noisy and independent: the fusion beats each of them on average
    err = lambda p: np.linalg.norm(p[use] - truth[use], axis=1).mean()  # noqa: E731
    assert err(equal) < min(err(image), err(lidar + t))


def test_options_are_checked():
    with pytest.raises(ValueError, match="image_sigma_px"):
        RefineOptions(image_sigma_px=0)
    with pytest.raises(ValueError, match="simplify_tolerance"):
        RefineOptions(simplify_tolerance=-1.0)
    with pytest.raises(ValueError, match="junction_tolerance"):
        RefineOptions(junction_tolerance=0)
    with pytest.raises(ValueError, match="wall_penalty"):
        RefineOptions(wall_penalty=-1.0)
