import numpy as np
import pytest
from scipy.spatial import cKDTree

from rooftrace.lidar.features import eigen_features


def test_features_of_a_plane_a_line_and_a_volume(rng):
    plane = np.column_stack([rng.uniform(0, 10, (2000, 2)), np.zeros(2000)]) + [0, 0, 0]
    line = np.column_stack([np.linspace(0, 50, 500), np.zeros(500), np.zeros(500)]) + [100, 0, 0]
    ball = rng.normal(0, 1, (2000, 3)) + [300, 0, 0]
    f = eigen_features(np.vstack([plane, line, ball]), 30, normal_neighbours=10)
    p, ln, b = f[:2000], f[2000:2500], f[2500:]
    assert np.allclose(f[:, :3].sum(axis=1), 1.0)
    assert np.median(p[:, 1]) > 0.5 and np.median(p[:, 2]) < 1e-9
    assert np.median(ln[:, 0]) > 0.99
    assert np.median(b[:, 3]) > 0.9 > 0.75 > np.median(p[:, 3])
    assert np.allclose(np.abs(p[:, 6]), 1.0)  # normals of the horizontal plane are vertical


def test_features_match_numpy_eigenvalues(rng):
    pts = rng.normal(0, [3, 2, 0.5], (300, 3))
    f = eigen_features(pts, 20)
    from scipy.spatial import cKDTree

    _, idx = cKDTree(pts).query(pts[:5], k=20)
    for i in range(5):
        w = np.linalg.eigvalsh(np.cov(pts[idx[i]].T, bias=True))[::-1]
        assert f[i, :3] == pytest.approx([(w[0] - w[1]) / w[0], (w[1] - w[2]) / w[0], w[2] / w[0]], abs=1e-9)


def _entropy(pts: np.ndarray) -> float:
    w = np.linalg.eigvalsh(np.cov(pts.T, bias=True))[::-1]
    lps = np.array([(w[0] - w[1]) / w[0], (w[1] - w[2]) / w[0], max(w[2], 0) / w[0]])
    return float(-np.sum(np.where(lps > 0, lps * np.log(np.where(lps > 0, lps, 1)), 0)))


def test_adaptive_takes_the_size_of_lowest_entropy(rng):
    pts = np.vstack([np.column_stack([rng.uniform(0, 6, (400, 2)), rng.normal(0, 0.03, 400)]),
                     rng.normal(0, 1, (400, 3)) + [3, 3, 3]])
    f = eigen_features(pts, 40, min_neighbours=10, neighbour_step=10)
    _, idx = cKDTree(pts).query(pts[::97], k=40)
    for row, i in zip(idx, range(0, len(pts), 97)):
        best = min(_entropy(pts[row[:k]]) for k in (10, 20, 30, 40))
        assert f[i, 3] == pytest.approx(best, abs=1e-7)


def test_adaptive_with_one_size_is_the_fixed_neighbourhood(rng):
    pts = rng.normal(0, [3, 2, 0.5], (300, 3))
    assert np.allclose(eigen_features(pts, 20, min_neighbours=20), eigen_features(pts, 20), atol=1e-9)


def test_adaptive_keeps_a_low_roof_by_a_wall_planar_and_a_crown_volumetric(rng):
    # a 3 m x 4 m flat roof 2.5 m up, against the 8 m wall of the house behind it,
    # and a crown: a 60-point neighbourhood (4 m² at 15 pts/m²) reaches up the wall
    shed = np.column_stack([rng.uniform(0, 3, 180), rng.uniform(0, 4, 180), 2.5 + rng.normal(0, 0.02, 180)])
    wall = np.column_stack([np.full(300, -0.05), rng.uniform(0, 4, 300), rng.uniform(2.5, 8, 300)])
    crown = rng.normal(0, 1, (600, 3)) * [1.5, 1.5, 1.2] + [6.5, 2, 5]
    pts = np.vstack([shed, wall, crown])
    fixed = eigen_features(pts, 60)
    adaptive = eigen_features(pts, 60, min_neighbours=10)
    edge = shed[:, 0] < 1.0  # roof points within 1 m of the wall
    assert np.median(fixed[:180][edge, 3]) > 0.8  # looks like vegetation to the thesis' N
    assert np.median(adaptive[:180][edge, 3]) < 0.6
    assert np.median(adaptive[480:, 3]) > 0.75  # the crown stays volumetric
    assert np.all(adaptive[:, 3] <= fixed[:, 3] + 1e-9)  # N is one of the sizes tried


def test_bad_adaptive_sizes_raise():
    pts = np.random.default_rng(0).normal(size=(50, 3))
    with pytest.raises(ValueError, match="min_neighbours"):
        eigen_features(pts, 20, min_neighbours=30)
    with pytest.raises(ValueError, match="neighbour_step"):
        eigen_features(pts, 20, min_neighbours=10, neighbour_step=0)


def test_a_roof_scanned_in_lines_is_linear_only_at_small_sizes(rng):
    # scan lines 1 m apart, points 0.15 m apart along them (about 7 pts/m²):
    # the 10 nearest points lie on one line, the 40 nearest span several
    x, y = np.meshgrid(np.arange(0, 12, 0.15), np.arange(0, 12, 1.0))
    pts = np.column_stack([x.ravel(), y.ravel(), rng.normal(0, 0.02, x.size)])
    f, lin = eigen_features(pts, 40, min_neighbours=10, return_linearity=True)
    inner = (np.abs(pts[:, :2] - 6) < 4).all(axis=1)
    assert np.median(f[inner, 0]) > 0.9  # the lowest-entropy size is a piece of one line
    assert np.median(lin[inner]) < 0.7  # the N-point neighbourhood is a plane
    fixed, lin_fixed = eigen_features(pts, 40, return_linearity=True)
    assert np.array_equal(lin_fixed, fixed[:, 0])


def test_normals_are_numbas_eigh_to_the_bit(rng):
    import numba

    from rooftrace.lidar.features import _eigh3, _eigh_workspace

    @numba.njit
    def both(s):
        ws = _eigh_workspace()
        ours, ref = np.empty((len(s), 12)), np.empty((len(s), 12))
        for i in range(len(s)):
            a, b, c, d, e, f = s[i]
            _eigh3(a, b, c, d, e, f, ws)
            ours[i, :9], ours[i, 9:] = ws[2], ws[3]
            w, v = np.linalg.eigh(np.array([[a, d, e], [d, b, f], [e, f, c]]))
            ref[i, :9], ref[i, 9:] = v.T.ravel(), w
        return ours, ref

    p = rng.normal(0, [1, 1, 0.02], (3000, 12, 3))
    p[:500, :, 2] = 0.0  # flat: a zero eigenvalue
    p[500:600] = p[500:600, :1]  # one point repeated: all zero
    p[600:700, :, 1] = p[600:700, :, 0]  # a line in plan
    p = p - p.mean(axis=1, keepdims=True)
    s = np.stack([(p[..., 0] ** 2).sum(1), (p[..., 1] ** 2).sum(1), (p[..., 2] ** 2).sum(1),
                  (p[..., 0] * p[..., 1]).sum(1), (p[..., 0] * p[..., 2]).sum(1), (p[..., 1] * p[..., 2]).sum(1)], 1)
    ours, ref = both(s)
    assert np.array_equal(ours, ref)
