import numpy as np
import pytest

from rooftrace.lidar.outliers import OutlierOptions, histogram_outliers
from tests.lidar.scenes import scene


def test_finds_high_and_low_outliers_only(rng):
    xyz, _ = scene(rng, size=80, density=4)
    spikes = np.column_stack([rng.uniform(0, 80, (20, 2)), rng.choice([-30.0, 80.0], 20)])
    noise = histogram_outliers(np.vstack([xyz, spikes]))
    assert noise[len(xyz):].all()
    assert not noise[: len(xyz)].any()


def test_cells_without_a_populated_bin_are_kept():
    p = np.array([[0.0, 0, 0], [1, 1, 5], [2, 2, 9]])
    assert not histogram_outliers(p).any()


def test_disabled_and_bad_options():
    assert not histogram_outliers(np.array([[0.0, 0, 0], [0, 0, 100]]), OutlierOptions(enabled=False)).any()
    with pytest.raises(ValueError, match="min_count"):
        OutlierOptions(min_count=0)
