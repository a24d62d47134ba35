import laspy
import numpy as np
import pytest

from rooftrace.tiling import TileOptions, split_to_tiles, tile_grid


def test_grid_is_anchored_at_multiples_of_the_tile_size():
    xs, ys = tile_grid([1030.0, 2010.0, 1490.0, 2260.0], 100.0)
    np.testing.assert_array_equal(xs, [1000, 1100, 1200, 1300, 1400])
    np.testing.assert_array_equal(ys, [2000, 2100, 2200])


def _las(path, xyz):
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales = [0.001] * 3
    header.offsets = [0, 0, 0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(path)


def test_split_puts_each_point_in_every_buffered_tile_that_holds_it(tmp_path, rng):
    xyz = np.column_stack([rng.uniform(0, 300, 5000), rng.uniform(0, 200, 5000), rng.uniform(0, 10, 5000)])
    a, b = tmp_path / "a.las", tmp_path / "b.laz"
    _las(a, xyz[:2500])
    _las(b, xyz[2500:])
    opts = TileOptions(tile_size=100.0, buffer=20.0, chunk_size=700)
    index = split_to_tiles([a, b], tmp_path / "run", opts)
    assert index["tile_size"] == 100.0 and index["buffer"] == 20.0
    for key, tile in index["tiles"].items():
        x0, y0 = tile["origin"]
        parts = sorted((tmp_path / "run" / "tiles" / key).glob("*.npy"))
        got = np.concatenate([np.load(p) for p in parts])
        expect = xyz[(xyz[:, 0] >= x0 - 20) & (xyz[:, 0] < x0 + 120) & (xyz[:, 1] >= y0 - 20) & (xyz[:, 1] < y0 + 120)]
        # the floor-based assignment is half-open like the expectation, up to the 1 mm scale
        assert abs(len(got) - len(expect)) <= 2
        assert tile["points"] == len(got)
    cores = sum(
        ((xyz[:, 0] >= t["origin"][0]) & (xyz[:, 0] < t["origin"][0] + 100)
         & (xyz[:, 1] >= t["origin"][1]) & (xyz[:, 1] < t["origin"][1] + 100)).sum()
        for t in index["tiles"].values()
    )
    assert cores == len(xyz)


def test_split_refuses_non_las(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("1 2 3\n")
    from rooftrace.errors import InputError

    with pytest.raises(InputError, match="LAS/LAZ only"):
        split_to_tiles([p], tmp_path / "run", TileOptions())
