"""Classified points of tiled runs: core labels, their merge, the streaming writer."""

import laspy
import numpy as np

from rooftrace.io.las import write_las_labels
from rooftrace.tiling.classified import core_labels, merge_labels


def test_core_labels_keep_the_core_and_index_the_keys():
    xy = np.array([[0.5, 0.5], [1.5, 0.5], [0.2, 0.9], [0.9, 1.0]])
    labels = core_labels(np.array([10, 11, 12, 13]), xy, (0.0, 1.0, 0.0, 1.0), np.array([6, 6, 2, 6]),
                         np.array([7, 3, 0, 3]), np.array([3, 7]), np.array([[1.0, 2, 3], [4, 5, 6]]))
    assert labels["gidx"].tolist() == [10, 12]  # (1.5, 0.5) and (0.9, 1.0) lie outside the half-open core
    assert labels["classification"].tolist() == [6, 2]
    assert labels["key_index"].tolist() == [1, -1]


def test_merge_labels_numbers_buildings_by_key():
    parts = [{"gidx": np.array([0, 2]), "classification": np.array([6, 2], np.uint8), "key_index": np.array([0, -1]),
              "keys": np.array([[5.0, 5, 1]])},
             {"gidx": np.array([1, 3]), "classification": np.array([6, 6], np.uint8), "key_index": np.array([1, 0]),
              "keys": np.array([[9.0, 9, 9], [1.0, 1, 1]])}]
    classes, ids = merge_labels(parts, {(1.0, 1.0, 1.0): 1, (5.0, 5.0, 1.0): 2}, 5)
    assert classes.tolist() == [6, 6, 2, 6, 1]
    assert ids.tolist() == [2, 1, 0, 0, 0]  # the key no tile owns (9, 9, 9) gives id 0


def _las(path, xyz, scale):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = np.array([100.0, 200.0, 0.0])
    header.add_extra_dims([laspy.ExtraBytesParams(name="reflectance", type=np.float32)])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.intensity = np.arange(len(xyz), dtype=np.uint16)
    las.reflectance = np.linspace(0, 1, len(xyz)).astype(np.float32)
    las.write(path)
    return las


def test_writer_keeps_every_dimension_across_files(tmp_path):
    rng = np.random.default_rng(0)
    a = _las(tmp_path / "a.laz", rng.uniform(100, 110, (50, 3)), 0.001)
    b = _las(tmp_path / "b.laz", rng.uniform(100, 110, (30, 3)), 0.01)
    classes = np.tile(np.array([2, 6], np.uint8), 40)
    ids = np.arange(80, dtype=np.int32)
    out = write_las_labels([tmp_path / "a.laz", tmp_path / "b.laz"], tmp_path / "out.laz", classes, ids,
                           chunk_size=16)
    got = laspy.read(out)
    assert len(got.points) == 80
    np.testing.assert_array_equal(got.classification, classes)
    np.testing.assert_array_equal(got["building_id"], ids)
    np.testing.assert_allclose(got.reflectance, np.concatenate([a.reflectance, b.reflectance]))
    np.testing.assert_array_equal(got.intensity, np.concatenate([a.intensity, b.intensity]))
    np.testing.assert_allclose(np.column_stack([got.x, got.y, got.z]),
                               np.vstack([np.column_stack([s.x, s.y, s.z]) for s in (a, b)]), atol=0.0006)
