"""Reconstruction of the refined roof in the image and back into object space."""

from __future__ import annotations

import numpy as np
import pytest
from shapely import LineString, Polygon

from rooftrace.grouping.reconstruct import junction_planes, meet, reconstruct_image, ridge_lines, to_object_space
from rooftrace.grouping.topology import roof_topology
from rooftrace.image.camera import FrameCamera


def test_two_lines_intersect_three_meet_in_least_squares():
    p, ok = meet(np.array([[[0, 0], [10, 0]], [[5, -5], [5, 5]]], float), np.zeros(2))
    assert ok and p == pytest.approx([5, 0])
    # three lines through (1, 1) with one shifted by 0.3 px: the point stays within 0.3 px
    lines = np.array([[[0, 1], [5, 1]], [[1, 0], [1, 5]], [[0, 0.3], [5, 5.3]]], float)
    p, ok = meet(lines, np.zeros(2))
    assert ok and np.linalg.norm(p - [1, 1]) < 0.3
    # the least-squares point has zero residual gradient
    n = np.array([[0, 1], [1, 0], [-1, 1] / np.sqrt(2)])
    c = np.array([1, 1, 0.3 / np.sqrt(2)])
    np.testing.assert_allclose(n.T @ (n @ p - c), 0, atol=1e-9)


def test_parallel_lines_fall_back_to_the_reference():
    p, ok = meet(np.array([[[0, 0], [10, 0]], [[0, 2], [10, 2.01]]], float), np.array([4.0, 5.0]))
    assert not ok and p == pytest.approx([4, 1.0], abs=0.01)


def test_exact_lines_give_the_true_vertices_and_max_shift_refuses():
    truth = np.array([[10, 10], [50, 10], [50, 40], [10, 40]], float)
    topo = roof_topology(Polygon(np.column_stack([truth, np.zeros(4)])))
    sides = np.stack([truth, np.roll(truth, -1, axis=0)], axis=1)
    shrunk = sides + (np.roll(sides, 1, axis=1) - sides) * 0.2  # shorter lines, same support
    rec = reconstruct_image(topo, shrunk, truth + 3.0)
    np.testing.assert_allclose(rec.points, truth, atol=1e-9)
    np.testing.assert_allclose(rec.lines, sides, atol=1e-9)
    rec = reconstruct_image(topo, shrunk, truth + 3.0, max_shift=2.0)
    assert not rec.moved.any() and rec.points == pytest.approx(truth + 3.0)


def _nadir_camera():
    return FrameCamera((1000, 1000), 0.01, 50.0, np.array([0.0, 0.0, 500.0, 0, 0, 0]))


def test_rays_hit_the_roof_planes():
    cam = _nadir_camera()
    pts = np.array([[10.0, 20.0, 8.0], [-30.0, 5.0, 12.0]])
    planes = np.array([[0.0, 0.5, 1.0, -18.0], [0.0, 0.0, 1.0, -12.0]])  # both pass through their point
    xyz, ok = to_object_space(cam, cam.project(pts), planes, pts + 0.5)
    assert ok.all()
    np.testing.assert_allclose(xyz, pts, atol=1e-6)
    # a ray landing far from the fallback keeps the fallback
    xyz, ok = to_object_space(cam, cam.project(pts), planes, pts + [10.0, 0, 0], max_move=2.0)
    assert not ok.any() and xyz == pytest.approx(pts + [10.0, 0, 0])


def test_junction_planes_pick_the_face_of_each_vertex():
    # gable roof, ridge along x at y = 3, z = 5; eaves at z = 3 on y = 0 and y = 6
    south = np.array([0.0, -2 / 3, 1.0, -3.0])  # z = 3 + 2/3 y
    north = np.array([0.0, 2 / 3, 1.0, -7.0])  # z = 7 - 2/3 y
    wall = np.array([1.0, 0.0, 0.0, 0.0])
    roof = Polygon([(0, 0, 3.1), (10, 0, 3.1), (10, 6, 3.1), (0, 6, 3.1)])
    topo = roof_topology(roof, [LineString([(0, 3, 5), (10, 3, 5)])])
    planes = junction_planes(topo, np.array([wall, south, north]))
    np.testing.assert_allclose(planes[0], south)
    np.testing.assert_allclose(planes[2], north)
    assert planes[4][2] == 1.0 and abs(planes[4][1]) == pytest.approx(2 / 3)  # a ridge end: either face
    flat = junction_planes(topo, None)
    np.testing.assert_allclose(flat[0], [0, 0, 1, -3.1])


def test_ridge_points_move_along_the_planes_intersection():
    south = np.array([0.0, -2 / 3, 1.0, -3.0])
    north = np.array([0.0, 2 / 3, 1.0, -7.0])
    roof = Polygon([(0, 0, 3), (10, 0, 3), (10, 6, 3), (0, 6, 3)])
    topo = roof_topology(roof, [LineString([(0.5, 3.1, 5.05), (9.5, 2.9, 4.95)])])
    lines = ridge_lines(topo, np.array([south, north]))
    vertex = [j.vertex >= 0 for j in topo.junctions]
    assert np.isnan(lines[vertex]).all() and np.isfinite(lines[~np.array(vertex)]).all()
    np.testing.assert_allclose(np.abs(lines[~np.array(vertex), 1]), [[1, 0, 0]] * 2, atol=1e-12)
    np.testing.assert_allclose(lines[~np.array(vertex), 0][:, 1:], [[3, 5]] * 2, atol=1e-12)
    # a pixel 2 px off the projected ridge still lands on the ridge line, at the right x
    cam = _nadir_camera()
    target = np.array([[4.0, 3.0, 5.0]])
    px = cam.project(target) + [0.0, 2.0]
    j = int(np.flatnonzero(~np.array(vertex))[0])
    xyz, ok = to_object_space(cam, px, np.array([south]), np.array([[4.5, 3.5, 5.0]]), lines=lines[j:j + 1])
    assert ok.all() and xyz[0] == pytest.approx([4.0 * 1.0, 3.0, 5.0], abs=0.02)
