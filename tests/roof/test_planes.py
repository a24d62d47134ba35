"""Plane segmentation and least-squares fits on constructed roofs with exact planes."""

import numpy as np
import pytest

from rooftrace.errors import GeometryError
from rooftrace.roof import models
from rooftrace.roof.planes import estimate_spacing, fit_planes, level_untilted, plane_height, point_normals
from rooftrace.roof.segmentation import detail_planes, point_neighbourhoods, segment_planes


def _truth_match(labels, face, K):
    """Truth face of each extracted plane by majority of its points."""
    out = []
    for k in range(K):
        f = face[(labels == k) & (face >= 0)]
        out.append(np.bincount(f).argmax() if len(f) else -1)
    return np.array(out)


def test_fit_planes_exact_and_covariance(rng):
    n = 400
    xy = rng.uniform(0, 10, (n, 2)) + [85000.0, 447000.0]
    p, q, z0 = 0.3, -0.7, 12.0
    z = z0 + p * (xy[:, 0] - 85000) + q * (xy[:, 1] - 447000)
    labels = np.zeros(n, int)
    fit = fit_planes(np.column_stack([xy, z]), labels)
    assert fit.sigma[0] < 1e-6
    assert np.allclose(plane_height(fit.planes, xy)[:, 0], z, atol=1e-7)
    assert fit.planes[0, 2] > 0 and np.isclose(np.linalg.norm(fit.planes[0, :3]), 1)
    assert np.allclose(fit.pqr[0, :2], [p, q])
    # With noise the covariance is sigma^2 (A^T A)^-1 of the centred design.
    zn = z + rng.normal(0, 0.05, n)
    fit = fit_planes(np.column_stack([xy, zn]), labels)
    A = np.column_stack([xy - fit.centre[0], np.ones(n)])
    coef, rss, *_ = np.linalg.lstsq(A, zn, rcond=None)
    assert np.allclose(fit.pqr[0], coef)
    s2 = rss[0] / (n - 3)
    assert np.isclose(fit.sigma[0] ** 2, s2)
    assert np.allclose(fit.cov[0], s2 * np.linalg.inv(A.T @ A))


def test_fit_planes_collinear_is_nan():
    x = np.linspace(0, 5, 20)
    xyz = np.column_stack([x, 2 * x, x])
    fit = fit_planes(xyz, np.zeros(20, int))
    assert np.isnan(fit.planes).all()


def test_point_normals_on_plane(rng):
    xy = rng.uniform(0, 10, (500, 2))
    n_true = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    z = -(n_true[0] * xy[:, 0] + n_true[1] * xy[:, 1]) / n_true[2]
    normals, rms, nn = point_normals(np.column_stack([xy, z]), k=12)
    assert nn.shape == (500, 12)
    assert np.allclose(normals, n_true, atol=1e-6)
    assert rms.max() < 1e-6


def test_spacing_of_grid():
    g = np.mgrid[0:20:0.25, 0:10:0.25].reshape(2, -1).T
    assert estimate_spacing(g) == pytest.approx(0.25, rel=0.03)
    with pytest.raises(GeometryError, match="collinear"):
        estimate_spacing(np.column_stack([np.arange(10.0), np.arange(10.0)]))


@pytest.mark.parametrize(
    "model",
    [
        models.gable(chimney=True, angle=23, offset=(85000, 447000)),
        models.hip(chimney=True, angle=-40),
        models.l_hip(angle=15),
        models.flat_annex(),
        models.shed(),
        models.gable_dormer(angle=70),
    ],
    ids=lambda m: m.name,
)
def test_segment_finds_every_plane_with_exact_slope(model):
    xyz, face = models.sample_roof(model, density=12, noise=0.04, seed=3)
    labels, fit, tol = segment_planes(xyz, estimate_spacing(xyz))
    K = len(fit.planes)
    match = _truth_match(labels, face, K)
    # One extracted plane per true plane, none spurious.
    assert sorted(match) == list(range(len(model.planes)))
    slope = np.degrees(np.arccos(fit.planes[:, 2]))
    assert np.abs(slope - model.slopes_deg[match]).max() < 1.0
    # Points are on their true faces; chimney points are left out.
    on = labels >= 0
    assert np.mean(match[labels[on]] == face[on]) > 0.97
    assert np.mean(labels[face < 0] < 0) > 0.9 if (face < 0).any() else True
    assert np.all(fit.sigma < 0.06)


def test_segment_is_deterministic_and_order_free(rng):
    m = models.hip()
    xyz, _ = models.sample_roof(m, 12, 0.04, seed=5)
    s = estimate_spacing(xyz)
    l1, f1, _ = segment_planes(xyz, s)
    perm = rng.permutation(len(xyz))
    l2, f2, _ = segment_planes(xyz[perm], s)
    # Same planes (up to order), same partition.
    o1 = np.lexsort(f1.planes.T[::-1])
    o2 = np.lexsort(f2.planes.T[::-1])
    assert np.allclose(f1.planes[o1], f2.planes[o2], atol=1e-3)
    r1 = np.argsort(o1)[l1]
    r2 = np.argsort(o2)[l2]
    assert np.mean(r1[perm] == r2) > 0.99


def test_segment_rejects_tiny_input():
    with pytest.raises(GeometryError, match="points"):
        segment_planes(np.zeros((5, 3)), 0.3)


def test_wall_points_are_not_a_roof_plane():
    """Façade points under the eaves (ALS at a scan angle) stay unassigned."""
    m = models.gable(length=14, width=9, eave=5, slope=35)
    xyz, face = models.sample_roof(m, 12, 0.03, seed=2)
    rng = np.random.default_rng(0)
    # Two long walls, 14 m x 5 m, 8 pts/m².
    n = 560
    x = rng.uniform(0, 14, n)
    z = rng.uniform(0.2, 4.9, n)
    y = np.where(rng.random(n) < 0.5, 0.0, 9.0) + rng.normal(0, 0.03, n)
    walls = np.column_stack([x, y, z])
    labels, fit, _ = segment_planes(np.vstack([xyz, walls]), estimate_spacing(xyz))
    assert len(fit.planes) == 2
    assert np.allclose(np.degrees(np.arccos(fit.planes[:, 2])), 35, atol=0.5)
    assert np.mean(labels[len(xyz):] < 0) > 0.95


def test_coplanar_dormers_stay_separate():
    """Two dormers in one plane are two planes: a plane must not creep along
    the line where its extension crosses the main slope (hysteresis)."""
    m = models.gable_dormer(positions=(4.0, 12.0), angle=25)
    xyz, face = models.sample_roof(m, 12, 0.04, seed=6)
    labels, fit, _ = segment_planes(xyz, estimate_spacing(xyz))
    slope = np.degrees(np.arccos(fit.planes[:, 2]))
    assert np.sum(np.abs(slope - 10) < 1.5) == 2 and np.sum(np.abs(slope - 40) < 1) == 2
    dormer = np.flatnonzero(np.abs(slope - 10) < 1.5)
    xs = [xyz[labels == k, 0].mean() for k in dormer]
    assert abs(xs[0] - xs[1]) > 5


def test_small_dormer_at_low_density_is_found():
    """A 3 m x 1.9 m dormer at 4 pts/m² (23 points) seeds no region (no
    planar k-NN neighbourhood); the RANSAC rescue among unassigned points
    still finds it."""
    m = models.gable_dormer(width=3.0, angle=-10)
    xyz, face = models.sample_roof(m, 4, 0.04, seed=1)
    labels, fit, _ = segment_planes(xyz, estimate_spacing(xyz))
    slope = np.degrees(np.arccos(fit.planes[:, 2]))
    assert np.sum(np.abs(slope - 10) < 2) == 1
    k = int(np.flatnonzero(np.abs(slope - 10) < 2)[0])
    assert np.mean(face[labels == k] == 2) > 0.8 and np.sum(face[labels == k] == 2) > 0.8 * np.sum(face == 2)


@pytest.mark.parametrize("n_side", [3, 5, 12])
def test_two_neighbourhoods_equal_two_queries(n_side):
    """The k and 2k nearest neighbours are those of two k-d tree queries,
    also where distances tie (a grid with duplicated points) and where every
    point is every point's neighbour."""
    from scipy.spatial import cKDTree

    from rooftrace.roof.segmentation import _two_neighbourhoods

    g = np.mgrid[0:n_side, 0:n_side, 0:2].reshape(3, -1).T.astype(float)
    rng = np.random.default_rng(2)
    xyz = np.vstack([g, g[:5], g + rng.normal(0, 0.2, g.shape)])
    tree = cKDTree(xyz)
    for k in (1, 4, 16):
        k = min(k, len(xyz))
        nn, wide = _two_neighbourhoods(xyz, k)
        assert np.array_equal(nn, tree.query(xyz, k=k)[1].reshape(len(xyz), k))
        assert np.array_equal(wide, tree.query(xyz, k=min(2 * k, len(xyz)))[1].reshape(len(xyz), -1))


@pytest.mark.parametrize("seed", [0, 1])
def test_two_neighbourhoods_of_a_roof_equal_two_queries(seed):
    """On a scanned roof in national-grid coordinates (the grid search's
    case: few ties) and with some points doubled (ties), the neighbours and
    their order are those of two k-d tree queries."""
    from scipy.spatial import cKDTree

    from rooftrace.roof.models import hip, sample_roof
    from rooftrace.roof.segmentation import _two_neighbourhoods

    xyz, _ = sample_roof(hip(), density=10, noise=0.03, seed=seed)
    xyz = xyz + [85000.0, 446000.0, 0.0]
    xyz = np.vstack([xyz, xyz[::37]])
    tree = cKDTree(xyz)
    nn, wide = _two_neighbourhoods(xyz, 16)
    assert np.array_equal(nn, tree.query(xyz, k=16)[1])
    assert np.array_equal(wide, tree.query(xyz, k=32)[1])


def test_components_number_as_scipy():
    """The union-find components give scipy's labels (int32, in order of the smallest node)."""
    from scipy import sparse
    from scipy.sparse import csgraph

    from rooftrace.graph import components

    rng = np.random.default_rng(3)
    for n, m in [(1, 0), (5, 0), (50, 20), (300, 250), (300, 900)]:
        i, j = rng.integers(0, n, m), rng.integers(0, n, m)
        _, want = csgraph.connected_components(sparse.coo_matrix((np.ones(m), (i, j)), shape=(n, n)), directed=False)
        got = components(n, np.column_stack([i, j]))
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_fit_planes_sums_as_bincount():
    """The compiled sums of fit_planes add in point order like np.bincount: centres, normal
    equations and residual sums are bit-equal to the bincount form (here: centres and sigma)."""
    rng = np.random.default_rng(8)
    xyz = rng.normal(size=(500, 3)) * [20, 20, 2] + [84000.0, 447000.0, 10.0]
    labels = rng.integers(-1, 6, len(xyz))
    fit = fit_planes(xyz, labels)
    ok = labels >= 0
    lab, P = labels[ok], xyz[ok]
    n = np.maximum(np.bincount(lab, minlength=6), 1)
    centre = np.stack([np.bincount(lab, P[:, i], minlength=6) / n for i in range(3)], axis=1)
    assert np.array_equal(fit.centre, centre[:, :2])
    dx, dy = P[:, 0] - centre[lab, 0], P[:, 1] - centre[lab, 1]
    res = P[:, 2] - (fit.pqr[lab, 0] * dx + fit.pqr[lab, 1] * dy + fit.pqr[lab, 2])
    assert np.array_equal(fit.sigma, np.sqrt(np.bincount(lab, res * res, minlength=6) / np.maximum(n - 3, 1)))


def test_detail_planes_take_the_chimney_and_leave_the_main_planes():
    """A flat roof with a 1 m² chimney (10.2 m) and a stair house: the first pass leaves the chimney top on no
    plane (under its 2 m²); the second pass makes it a plane of exactly its points, the main labels unchanged."""
    m = models.flat_annex(stair_house=True, angle=21, offset=(85000.0, 447000.0))
    xyz, face = models.sample_roof(m, 16, 0.03, seed=2)
    s = estimate_spacing(xyz)
    labels, fit, tol = segment_planes(xyz, s)
    chimney = (face < 0) & (np.abs(xyz[:, 2] - 10.2) < 0.2)
    assert chimney.sum() >= 12 and (labels[chimney] < 0).all()
    more = detail_planes(xyz, labels, s, distance=tol)
    assert np.array_equal(more[labels >= 0], labels[labels >= 0])
    new = np.unique(more[more > labels.max()])
    assert len(new) == 1 and np.mean(more[chimney] == new[0]) > 0.9 and (chimney[more == new[0]]).all()
    # deterministic, and no second pass finds nothing new where every point is on a plane
    assert np.array_equal(detail_planes(xyz, labels, s, distance=tol), more)
    assert np.array_equal(detail_planes(xyz[~chimney], labels[~chimney], s, distance=tol), labels[~chimney])
    with pytest.raises(ValueError, match="distance"):
        detail_planes(xyz, labels, s, distance=0.0)
    with pytest.raises(ValueError, match="do not match"):
        detail_planes(xyz, labels[:-1], s, distance=tol)


def test_shared_neighbourhoods_give_the_same_planes():
    """The neighbourhoods found once for both passes give the labels each pass finds on its own; the
    neighbourhoods of other points or another k are refused."""
    m = models.flat_annex(stair_house=True, angle=21, offset=(85000.0, 447000.0))
    xyz, _ = models.sample_roof(m, 16, 0.03, seed=2)
    s = estimate_spacing(xyz)
    nb = point_neighbourhoods(xyz, 16)
    labels, fit, tol = segment_planes(xyz, s)
    shared, fit2, _ = segment_planes(xyz, s, neighbourhoods=nb)
    assert np.array_equal(shared, labels) and np.array_equal(fit2.planes, fit.planes)
    more = detail_planes(xyz, labels, s, distance=tol)
    assert more.max() > labels.max()  # the chimney: the shared neighbours are used
    assert np.array_equal(detail_planes(xyz, labels, s, distance=tol, neighbourhoods=nb), more)
    with pytest.raises(ValueError, match="k=8"):
        segment_planes(xyz, s, k=8, neighbourhoods=nb)
    with pytest.raises(ValueError, match="not those of"):
        detail_planes(xyz[1:], labels[1:], s, distance=tol, neighbourhoods=nb)


def test_fit_planes_of_several_labels_equal_one_call_each():
    """One call fitting many labels gives each label's plane bit for bit as a call of its points alone
    (the coplanar merge fits all its candidate pairs at once)."""
    rng = np.random.default_rng(11)
    groups = [rng.normal(size=(n, 3)) * [5, 5, 0.1] + [85000.0 + 10 * i, 447000.0, 10 + i] for i, n in
              enumerate([3, 7, 40, 400, 12])]
    xyz, lab = np.vstack(groups), np.repeat(np.arange(len(groups)), [len(g) for g in groups])
    together = fit_planes(xyz, lab)
    for i, g in enumerate(groups):
        alone = fit_planes(g, np.zeros(len(g), dtype=np.int64))
        for name in ("planes", "pqr", "centre", "cov", "sigma", "n"):
            assert np.array_equal(getattr(together, name)[i], getattr(alone, name)[0], equal_nan=True), name


def test_level_untilted_levels_only_what_the_points_do_not_tilt():
    rng = np.random.default_rng(7)
    xy = rng.uniform(0, 1, (12, 2))
    flat = np.column_stack([xy, 10 + rng.normal(0, 0.03, 12)])
    tilted = np.column_stack([xy + 5, 10 + 0.2 * xy[:, 0] + rng.normal(0, 0.03, 12)])
    xyz, lab = np.vstack([flat, tilted]), np.repeat([0, 1], 12)
    fit = fit_planes(xyz, lab)
    out = level_untilted(xyz, lab, fit, np.array([True, True]))
    assert np.allclose(out.planes[0], [0, 0, 1, -flat[:, 2].mean()]) and out.sigma[0] > 0
    assert np.array_equal(out.planes[1], fit.planes[1])  # 11° is far outside its error ellipse
    assert np.array_equal(level_untilted(xyz, lab, fit, np.array([False, True])).planes[0], fit.planes[0])
    with pytest.raises(ValueError, match="candidates"):
        level_untilted(xyz, lab, fit, np.array([True]))


def test_neighbourhood_normals_equal_the_numpy_covariances():
    """The compiled covariances give the normals and RMS of the numpy form
    (gather, centre, einsum) to the bit, in national-grid coordinates."""
    from scipy.spatial import cKDTree

    from rooftrace.roof.models import gable, sample_roof
    from rooftrace.roof.planes import neighbourhood_normals

    xyz, _ = sample_roof(gable(chimney=True), density=12, noise=0.04, seed=3)
    xyz = xyz + [85000.0, 446000.0, 0.0]
    nn = cKDTree(xyz).query(xyz, k=16)[1]
    nb = xyz[nn]
    nb = nb - nb.mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb) / 16)
    normals, rms, _ = neighbourhood_normals(xyz, nn)
    assert np.array_equal(rms, np.sqrt(np.clip(w[:, 0], 0, None)))
    assert np.array_equal(np.abs(normals), np.abs(v[:, :, 0]))


def test_graph_edges_equal_the_numpy_form():
    """The compiled candidate edges of the region graph are those of the
    numpy form (gathered arrays and einsum), value for value."""
    from rooftrace.roof.models import hip, sample_roof
    from rooftrace.roof.planes import neighbourhood_normals
    from rooftrace.roof.segmentation import _graph_edges

    xyz, _ = sample_roof(hip(chimney=True), density=12, noise=0.04, seed=5)
    xyz = xyz + [85000.0, 446000.0, 0.0]
    normals, rms, nn = neighbourhood_normals(xyz, point_neighbourhoods(xyz, 16).near)
    planar = rms <= 2 * np.median(rms)
    i = np.repeat(np.arange(len(xyz)), 16)
    j = nn.ravel()
    keep = (i != j) & planar[i] & planar[j]
    i, j = i[keep], j[keep]
    cosang = np.einsum("ij,ij->i", normals[i], normals[j])
    off = np.maximum(np.abs(np.einsum("ij,ij->i", normals[i], xyz[j] - xyz[i])),
                     np.abs(np.einsum("ij,ij->i", normals[j], xyz[j] - xyz[i])))
    got = _graph_edges(xyz, normals, rms, planar, nn)
    for a, b in zip(got, (i, j, cosang, off, np.maximum(rms[i], rms[j]))):
        assert np.array_equal(a, b)


def test_plan_hull_areas_match_qhull_and_decide_as_qhull():
    """The compiled hull areas are Qhull's within 1e-9 (national-grid
    coordinates, rounded ones with collinear runs); a test near its
    threshold is decided by Qhull's own area, a degenerate hull by the
    given answer."""
    from scipy.spatial import ConvexHull

    from rooftrace.roof.planes import hull_area_test, plan_hull_areas

    rng = np.random.default_rng(4)
    clouds = [np.round(rng.normal(size=(int(rng.integers(3, 200)), 2)) * rng.uniform(0.2, 10), 1)
              + [85000.0, 446000.0] for _ in range(60)]
    xy = np.vstack(clouds)
    groups = np.repeat(np.arange(len(clouds)), [len(c) for c in clouds])
    areas = plan_hull_areas(xy, groups, len(clouds) + 1)
    qhull = np.array([ConvexHull(c).volume for c in clouds])
    assert np.allclose(areas[:-1], qhull, rtol=1e-9, atol=1e-9) and areas[-1] == 0.0
    c, a = clouds[0], float(qhull[0])
    assert hull_area_test(c, a * (1 + 1e-8), lambda x: x >= a, False)  # Qhull's area decides at the threshold
    assert not hull_area_test(c, a * (1 - 1e-8), lambda x: x > a, True)
    line = np.column_stack([np.arange(5.0), np.arange(5.0)])
    assert plan_hull_areas(line, np.zeros(5, np.int64), 1)[0] == 0.0
    assert hull_area_test(line, 0.0, lambda x: x <= 0.0, True) and hull_area_test(line, 0.0, lambda x: x < 0, True)


def test_fit_planes_equal_the_numpy_form():
    """The compiled plane parameters are those of the numpy expressions
    (einsum solution, residuals, sigma, covariance, normal form) to the bit,
    with a collinear plane and a plane of two points among them."""
    from rooftrace.roof.plane_kernels import normal_sums, residual_sums
    from rooftrace.roof.planes import fit_planes

    rng = np.random.default_rng(6)
    xyz = rng.uniform(0, 10, (300, 3)) + [85000.0, 446000.0, 0.0]
    labels = rng.integers(-1, 5, 300)
    xyz[labels == 3, 1] = xyz[labels == 3, 0] * 0.5  # collinear in plan: no plane
    labels[np.flatnonzero(labels == 4)[2:]] = -1  # two points: no plane
    n, centre, N, u = normal_sums(xyz, labels, 5)
    good = (n >= 3) & (np.abs(np.linalg.det(N[:, :2, :2])) > 1e-9 * np.maximum(N[:, 0, 0] * N[:, 1, 1], 1e-30))
    Ninv = np.full((5, 3, 3), np.nan)
    Ninv[good] = np.linalg.inv(N[good])
    pqr = np.einsum("kij,kj->ki", Ninv, u)
    sigma = np.sqrt(residual_sums(xyz, labels, centre, pqr) / np.maximum(n - 3, 1))
    sigma[~good] = np.nan
    p, q, r = pqr.T
    planes = np.stack([-p, -q, np.ones_like(p), p * centre[:, 0] + q * centre[:, 1] - r], axis=1) / np.sqrt(
        1 + p * p + q * q)[:, None]
    fit = fit_planes(xyz, labels)
    assert good.tolist() == [True, True, True, False, False]
    for got, want in ((fit.pqr, pqr), (fit.sigma, sigma), (fit.cov, Ninv * (sigma**2)[:, None, None]),
                      (fit.planes, planes), (fit.centre, centre[:, :2]), (fit.n, n)):
        assert np.array_equal(got, want, equal_nan=True)


def test_adjacent_labels_are_the_unique_label_pairs():
    """The compiled adjacency gives np.unique's sorted distinct label pairs of the point pairs."""
    from rooftrace.roof.segmentation import _adjacent_labels

    rng = np.random.default_rng(7)
    labels = rng.integers(-1, 9, 500)
    pairs = rng.integers(0, 500, (3000, 2))
    a, b = labels[pairs[:, 0]], labels[pairs[:, 1]]
    m = (a >= 0) & (b >= 0) & (a != b)
    key = np.unique(np.minimum(a[m], b[m]) * 9 + np.maximum(a[m], b[m]))
    assert np.array_equal(_adjacent_labels(labels, pairs, 9), np.stack([key // 9, key % 9], axis=1))
    assert _adjacent_labels(labels, pairs[:0], 9).shape == (0, 2)
