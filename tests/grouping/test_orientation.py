"""Exterior orientation from matched lines (issue 7, optional part): synthetic correspondences with known truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rooftrace.errors import GeometryError, InputError
from rooftrace.grouping.orientation import correct_orientation
from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.refine import orientation_summary

TRUE_EO = np.array([20.0, -10.0, 1008.0, 0.01, -0.008, 0.05])


def _camera(cov=None):
    # 0.2 m GSD at 1000 m: a narrow field of view, where X0 and phi (Y0 and omega) nearly trade off
    return FrameCamera((1000, 1000), 0.012, 60.0, TRUE_EO.copy(), exterior_covariance=cov)


def _roofs(rng, n=25, spread=80.0):
    """Rectangular roofs: lines (4n, 2, 3), roof index (4n,)."""
    lines, groups = [], []
    for k in range(n):
        c = TRUE_EO[:2] + rng.uniform(-spread, spread, 2)
        a, h = rng.uniform(0, np.pi), rng.uniform(5, 15)
        u, v = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        p = [c - 6 * u - 4 * v, c + 6 * u - 4 * v, c + 6 * u + 4 * v, c - 6 * u + 4 * v]
        lines += [[[*p[i], h], [*p[(i + 1) % 4], h]] for i in range(4)]
        groups += [k] * 4
    return np.array(lines), np.array(groups)


def _matches(cam, lines, groups, rng, growth=1.5, noise=0.3, outliers=0.1, outlier_px=5.0):
    """Image lines: the true projections moved outward by ``growth`` px, noisy, some another edge further out."""
    px = cam.project(lines.reshape(-1, 3)).reshape(-1, 2, 2)
    centre = np.stack([px[groups == g].reshape(-1, 2).mean(axis=0) for g in groups])
    d = px[:, 1] - px[:, 0]
    n = np.column_stack([-d[:, 1], d[:, 0]]) / np.linalg.norm(d, axis=1)[:, None]
    n[np.einsum("md,md->m", n, px.mean(axis=1) - centre) < 0] *= -1
    image = px + growth * n[:, None] + rng.normal(0, noise, px.shape)
    bad = rng.random(len(px)) < outliers
    image[bad] += outlier_px * n[bad][:, None]
    return image, n, bad


def _displacement(cam, lines):
    xyz = lines.reshape(-1, 3)
    return float(np.mean(np.hypot(*(cam.project(xyz) - _camera().project(xyz)).T)))


def test_a_known_perturbation_is_recovered_within_its_precision():
    rng = np.random.default_rng(3)
    lines, groups = _roofs(rng)
    image, outward, bad = _matches(_camera(), lines, groups, rng)
    prior = np.diag([0.5, 0.5, 0.5, 5e-4, 5e-4, 5e-4]) ** 2
    off = dataclasses.replace(_camera(prior), exterior=TRUE_EO + [0.4, -0.5, 0.3, 3e-4, -2e-4, 4e-4])
    assert _displacement(off, lines) > 2.5  # px
    res = correct_orientation(off, lines, image, outward=outward, groups=groups)
    assert res.parameters == ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    assert _displacement(res.camera, lines) < 0.1
    assert np.all(np.abs(res.exterior - TRUE_EO) < 3 * res.std() + 1e-9)
    np.testing.assert_allclose(res.growth, 1.5, atol=0.6)  # each roof's own growth, outliers included
    assert np.all(res.weights[bad] < 0.5) and np.mean(res.weights[~bad] > 0.5) > 0.95
    assert res.n_inliers == int((res.weights > 0.5).sum()) and res.rms < 0.6
    np.testing.assert_allclose(res.delta, res.exterior - off.exterior)
    summary = orientation_summary(res)
    assert summary["lines"] == len(lines) and set(summary["delta"]) == {"X0", "Y0", "Z0", "omega", "phi", "kappa"}


def test_same_input_same_result_and_start_does_not_move_the_prior():
    rng = np.random.default_rng(5)
    lines, groups = _roofs(rng, 12)
    image, outward, _ = _matches(_camera(), lines, groups, rng)
    off = dataclasses.replace(_camera(np.eye(6) * 0.1), exterior=TRUE_EO + [0.3, 0.3, 0, 0, 0, 0])
    a = correct_orientation(off, lines, image, outward=outward, groups=groups)
    b = correct_orientation(off, lines[::-1], image[::-1], outward=outward[::-1], groups=groups[::-1])
    np.testing.assert_allclose(a.exterior, b.exterior, atol=1e-9)
    c = correct_orientation(off, lines, image, outward=outward, groups=groups, start=a.exterior)
    np.testing.assert_allclose(c.exterior, a.exterior, atol=1e-6)
    np.testing.assert_allclose(c.delta, a.delta, atol=1e-6)  # delta is always from the camera's own EO


def test_without_a_prior_weak_geometry_gets_the_reduced_set():
    rng = np.random.default_rng(7)
    lines, groups = _roofs(rng, 1)  # one roof of 12 m x 8 m: the tilts are not determined
    lines = np.concatenate([lines, lines + [0.0, 0.0, 3.0]])  # and its ridge-level copy, 8 lines
    groups = np.zeros(len(lines), int)
    image, outward, _ = _matches(_camera(), lines, groups, rng, growth=0.0, noise=0.05, outliers=0.0)
    off = _camera().with_exterior(TRUE_EO + [0.3, -0.2, 0.0, 0.0, 0.0, 2e-4])
    res = correct_orientation(off, lines, image, groups=groups)  # no outward: no growth
    assert res.parameters == ("X0", "Y0", "Z0", "kappa")
    assert _displacement(res.camera, lines) < 0.1  # right where the lines are
    np.testing.assert_allclose(res.delta[3:5], 0.0, atol=1e-12)  # the tilts held
    with pytest.raises(GeometryError, match="do not determine"):
        correct_orientation(off, lines, image, groups=groups, parameters="full")


def test_degenerate_or_bad_input_is_refused():
    rng = np.random.default_rng(9)
    cam = _camera()
    lines, groups = _roofs(rng, 20)
    image, outward, _ = _matches(cam, lines, groups, rng, outliers=0.0)
    parallel = np.flatnonzero(np.arange(len(lines)) % 2 == 0)  # sides 0 and 2 of each roof...
    along = lines[parallel].copy()
    along[:, :, :2] = along[:1, :, :2] + np.arange(len(along))[:, None, None] * [0.0, 3.0]  # ...all one direction
    with pytest.raises(GeometryError, match="do not determine"):
        correct_orientation(cam, along, cam.project(along.reshape(-1, 3)).reshape(-1, 2, 2))
    with pytest.raises(GeometryError, match="at least 8"):
        correct_orientation(cam, lines[:5], image[:5])
    with pytest.raises(InputError, match="frame camera"):
        correct_orientation(OrthoCamera((10, 10), (1, 0, 0, 0, -1, 0)), lines, image)
    with pytest.raises(InputError, match="distinct"):
        correct_orientation(cam, lines, np.repeat(image[:, :1], 2, axis=1))
    with pytest.raises(InputError, match=r"\(M, 2, 3\)"):
        correct_orientation(cam, lines, image[:3])
    with pytest.raises(InputError, match="parameters"):
        correct_orientation(cam, lines, image, parameters="tilts")
    # a third of the matches are another structure 8 px off: they are rejected, and if too few remain,
    # the correction is refused rather than made from them
    wild = image.copy()
    wild[::3] += 8.0 * outward[::3, None] * np.where(np.arange(len(wild))[::3] % 2, 1.0, -1.0)[:, None, None]
    ok = correct_orientation(cam, lines, wild, outward=outward, groups=groups)
    assert np.all(ok.weights[::3] < 0.5) and _displacement(ok.camera, lines) < 0.1
    with pytest.raises(GeometryError, match="agree"):
        correct_orientation(cam, lines, wild, outward=outward, groups=groups, min_lines=len(lines) - 2)
