import numpy as np
import pytest

from rooftrace.lidar.spacing import height_precision, mean_spacing, point_density


def test_mean_spacing_of_a_square_grid():
    g = np.stack(np.meshgrid(np.arange(0, 30, 0.5), np.arange(0, 30, 0.5)), -1).reshape(-1, 2)
    # Delaunay of a square grid: 2 sides and one diagonal per cell -> (1 + 1 + sqrt 2)/3 * step
    assert mean_spacing(g + 1e5) == pytest.approx(0.5 * (2 + np.sqrt(2)) / 3, rel=0.02)


def test_mean_spacing_uses_blocks_without_changing_the_density(rng):
    xy = rng.uniform(0, 140, (40_000, 2)) + [85_000, 447_000]
    full = mean_spacing(xy, max_points=100_000)
    blocks = mean_spacing(xy, max_points=12_000)
    # Poisson process: mean Delaunay edge = 32/(9 pi) / sqrt(density)
    expected = 32 / (9 * np.pi) / np.sqrt(2.0)
    assert full == pytest.approx(expected, rel=0.05)
    assert blocks == pytest.approx(full, rel=0.05)


def test_mean_spacing_rejects_degenerate_input():
    with pytest.raises(ValueError, match="at least 3 points"):
        mean_spacing(np.array([[0.0, 0.0], [1.0, 1.0]]))


def test_point_density_ignores_empty_areas(rng):
    a = rng.uniform(0, 20, (4000, 2))
    b = rng.uniform(0, 20, (4000, 2)) + [100, 0]  # a gap of 80 m between two patches
    assert point_density(np.vstack([a, b])) == pytest.approx(10.0, rel=0.1)


@pytest.mark.parametrize("sigma", [0.02, 0.1])
def test_height_precision_recovers_the_noise_of_planes(rng, sigma):
    xy = rng.uniform(0, 40, (16_000, 2))
    z = 0.4 * xy[:, 0] - 0.2 * xy[:, 1] + rng.normal(0, sigma, len(xy))
    # a tree-like volume in one corner must not inflate the estimate
    tree = np.column_stack([rng.uniform(0, 8, (3000, 2)), rng.uniform(0, 10, 3000)])
    est = height_precision(np.vstack([np.column_stack([xy, z]), tree]))
    assert est == pytest.approx(sigma, rel=0.25)
