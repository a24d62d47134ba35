"""Plane intersections, adjacency and ridge lines against analytic truth."""

import numpy as np
import pytest
import shapely

from rooftrace.roof import models
from rooftrace.roof.adjacency import plane_adjacency
from rooftrace.roof.planes import estimate_spacing, plane_height
from rooftrace.roof.ridges import intersect_planes, intersection_lines, triple_point
from rooftrace.roof.segmentation import segment_planes


def _plane(p, q, r):
    v = np.array([-p, -q, 1.0, -r])
    return v / np.linalg.norm(v[:3])


def test_intersect_planes_lies_on_both():
    pa, pb = _plane(0.5, 0.0, 3.0), _plane(-0.5, 0.2, 8.0)
    x0, u = intersect_planes(pa, pb, near=np.array([1.0, 2.0, 0.0]))
    assert np.hypot(*u[:2]) == pytest.approx(1.0)
    for t in (-3.0, 0.0, 7.5):
        p = x0 + t * u
        assert abs(pa[:3] @ p + pa[3]) < 1e-12 and abs(pb[:3] @ p + pb[3]) < 1e-12
    assert intersect_planes(pa, pa) is None  # parallel


def test_triple_point():
    pa, pb, pc = _plane(0.5, 0, 3), _plane(-0.5, 0, 8), _plane(0, 0.5, 1)
    p = triple_point(pa, pb, pc)
    for pl in (pa, pb, pc):
        assert abs(pl[:3] @ p + pl[3]) < 1e-12
    assert triple_point(pa, pa, pc) is None


def _segment_lines(model, noise, seed=0):
    xyz, face = models.sample_roof(model, 12, noise, seed)
    s = estimate_spacing(xyz)
    labels, fit, _ = segment_planes(xyz, s)
    adj = plane_adjacency(xyz, labels, fit.planes, 2.5 * s)
    lines = intersection_lines(fit.planes, adj, model.outline, line_tolerance=2.5 * s, snap=max(1.0, 4 * s),
                               xyz=xyz, labels=labels)
    return xyz, labels, fit, adj, lines


def _max_vertex_error(lines, truth):
    """Largest distance (3D) from a truth vertex to the nearest extracted vertex, per truth line."""
    ext = np.array([c for g in lines for c in g.coords])
    return max(np.linalg.norm(ext - np.asarray(c), axis=1).min() for g in truth for c in g.coords)


@pytest.mark.parametrize("make", [models.gable, models.hip, models.l_hip], ids=["gable", "hip", "l_hip"])
def test_noise_free_lines_are_exact(make):
    """Exact planes: every ridge, hip and valley is found with its end points
    exact (junctions from three planes, ends on the outline)."""
    model = make(angle=17, offset=(1000.0, 2000.0))
    _, _, fit, _, lines = _segment_lines(model, noise=0.0)
    assert len(lines.lines) == len(model.ridges)
    assert sorted(lines.kinds) == sorted(model.ridge_kind)
    assert _max_vertex_error(lines.lines, model.ridges) < 1e-6


def test_adjacency_convexity_of_l_hip():
    model = models.l_hip()
    xyz, labels, fit, adj, lines = _segment_lines(model, noise=0.04)
    # One valley (concave), seven convex lines.
    assert lines.kinds.count("valley") == 1
    assert sum(c < 0 for c in lines.convex) == 1
    (a, b), = [p for p, k in zip(lines.pairs, lines.kinds) if k == "valley"]
    i = [tuple(p) for p in adj.pairs].index((a, b))
    assert adj.convexity[i] < 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_hip_lines_within_tolerance(seed):
    model = models.hip(chimney=True, angle=33)
    _, _, _, _, lines = _segment_lines(model, noise=0.05, seed=seed)
    assert sorted(lines.kinds) == sorted(model.ridge_kind)
    for g in lines.lines:
        # Every extracted line lies on a truth line of its kind: mean plan
        # distance of its points under 0.15 m.
        pts = shapely.segmentize(shapely.force_2d(g), 0.1)
        d = [min(shapely.distance(shapely.Point(c), shapely.force_2d(t)) for t in model.ridges) for c in pts.coords]
        assert np.mean(d) < 0.15
    assert _max_vertex_error(lines.lines, model.ridges) < 0.5


@pytest.mark.parametrize("make, atol", [(models.hip, 1e-9), (models.l_hip, 0.03)], ids=["hip", "l_hip"])
def test_lines_lie_on_their_planes(make, atol):
    """Exactly where at most three planes meet; within cm where the four planes
    of the L's centre share one least-squares junction."""
    model = make(angle=-20)
    _, _, fit, _, lines = _segment_lines(model, noise=0.04)
    for g, (a, b) in zip(lines.lines, lines.pairs):
        c = np.asarray(g.coords)
        for k in (a, b):
            assert np.allclose(plane_height(fit.planes[k][None], c[:, :2])[:, 0], c[:, 2], atol=atol)


def test_l_hip_centre_is_one_junction():
    """Ridge A, ridge B, the outer hip and the valley meet at one point."""
    model = models.l_hip(angle=8)
    _, _, fit, _, lines = _segment_lines(model, noise=0.05, seed=4)
    centre = np.asarray(model.ridges[0].coords[0])
    ends = np.array([c for g in lines.lines for c in g.coords])
    near = ends[np.linalg.norm(ends[:, :2] - centre[:2], axis=1) < 0.5]
    assert len(near) == 4
    assert np.ptp(near, axis=0).max() < 1e-9
    assert np.linalg.norm(near[0] - centre) < 0.15


def test_adjacency_medians_are_numpys_median_of_each_pair():
    from rooftrace.roof.adjacency import _medians

    rng = np.random.default_rng(3)
    sizes = rng.integers(1, 12, 400)  # odd and even counts
    group = np.repeat(np.arange(len(sizes)), sizes)
    values = np.round(rng.normal(0, 1, len(group)), 2)  # ties
    values[rng.choice(len(values), 5, replace=False)] = np.nan
    values[rng.choice(len(values), 20, replace=False)] = -0.0
    shuffle = rng.permutation(len(values))  # a group's values need not be together
    got = _medians(values[shuffle], group[shuffle], len(sizes))
    with np.errstate(invalid="ignore"):
        want = np.array([np.median(values[group == g]) for g in range(len(sizes))])
    assert np.array_equal(got, want, equal_nan=True)
