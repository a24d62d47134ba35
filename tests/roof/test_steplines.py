"""Height steps as lines fitted to the two levels' points (``roof.steplines``)."""

import numpy as np
import pytest
import shapely

from rooftrace.roof.faces import hidden_under, points_off_their_faces
from rooftrace.roof.steplines import _least_misfit_cut, fit_step_boundaries, separating_line

PLANES = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])  # upper level 8 m, lower 5 m


def _brute_force(t_up, t_lo, w_up, w_lo):
    """The least misfit of a threshold on one axis, every cut between sorted projections tried."""
    t = np.sort(np.concatenate([t_up, t_lo]))
    cuts = np.r_[t[0] - 1, (t[1:] + t[:-1]) / 2, t[-1] + 1]
    return min(w_up[t_up > c].sum() + w_lo[t_lo < c].sum() for c in cuts)


@pytest.mark.parametrize("seed", range(6))
def test_separating_line_is_the_least_misfit_threshold(seed):
    """Along a fixed direction the 1-D search is exact: its misfit is the brute force's over every cut, and
    the line lies in the middle of the widest gap among the best cuts."""
    rng = np.random.default_rng(seed)
    up = rng.normal([0.0, 0.0], 0.6, (40, 2))
    lo = rng.normal([1.0, 0.3], 0.6, (35, 2))
    wu, wl = rng.uniform(0.5, 3, len(up)), rng.uniform(0.5, 3, len(lo))
    n, c, misfit, margin = separating_line(up, lo, wu, wl, normal=np.array([1.0, 0.0]), spread=0.0, step=1.0)
    # with no spread only the refinement's tenth of a degree turns the line: compare on its own direction
    assert misfit == pytest.approx(_brute_force(up @ n, lo @ n, wu, wl))
    t_up, t_lo = up @ n, lo @ n
    assert misfit == pytest.approx(wu[t_up > c].sum() + wl[t_lo < c].sum())
    t = np.concatenate([t_up, t_lo])
    assert np.abs(t - c).min() == pytest.approx(margin)



def _least_misfit_cut_numpy(t, is_lo, w):
    """The numpy form the compiled kernel replaced: stable sort, cumulative sums, first widest best cut."""
    order = np.argsort(t, axis=1, kind="stable")
    ts = np.take_along_axis(t, order, axis=1)
    lo_s, w_s = is_lo[order], w[order]
    before = np.concatenate([np.zeros((len(t), 1)), np.cumsum(np.where(lo_s, w_s, 0.0), axis=1)], axis=1)
    after = np.concatenate([np.cumsum(np.where(~lo_s, w_s, 0.0)[:, ::-1], axis=1)[:, ::-1], np.zeros((len(t), 1))],
                           axis=1)
    cost = before + after
    gap = np.concatenate([np.zeros((len(t), 1)), np.diff(ts, axis=1), np.zeros((len(t), 1))], axis=1)
    score = np.where(cost <= cost.min() + 1e-9, gap, -1.0)
    a, i = np.unravel_index(int(np.argmax(score)), score.shape)
    lo_t = ts[a, i - 1] if i > 0 else ts[a, 0] - 1.0
    hi_t = ts[a, i] if i < ts.shape[1] else ts[a, -1] + 1.0
    return a, cost[a, i], lo_t, hi_t, gap[a, i]


@pytest.mark.parametrize("seed", range(8))
def test_the_compiled_cut_is_the_numpy_cut_bit_for_bit(seed):
    """The kernel gives exactly the numpy form's cut (the run's outputs stay hash-identical): the same stable
    order among tied projections (points on a lattice), the same sums in the same order, the same first
    widest cut among the least-misfit ones."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60))
    xy = np.round(rng.normal(0.0, 1.0, (n, 2)), 1) if seed % 2 else rng.normal(0.0, 1.0, (n, 2))
    angles = np.radians(np.arange(-20.0, 21.0, 2.0)) + rng.uniform(-1, 1)
    t = np.column_stack([np.cos(angles), np.sin(angles)]) @ xy.T
    is_lo = rng.random(n) < 0.5
    w = np.round(rng.uniform(0.1, 3.0, n), 1)
    got, want = _least_misfit_cut(t, is_lo, w), _least_misfit_cut_numpy(t, is_lo, w)
    assert [float(x) for x in got] == [float(x) for x in want]

def test_separating_line_separates_and_gives_way_where_the_levels_interleave():
    """Two rows 0.4 m apart are split in the middle; one upper point among the lower ones is left on the
    wrong side (the least misfit), unless its weight is larger than the lower points' it would pass."""
    y = np.arange(0.0, 4.0, 0.5)
    up = np.column_stack([np.full(len(y), 3.8), y])
    lo = np.column_stack([np.full(len(y), 4.2), y])
    n, c, misfit, margin = separating_line(up, lo)
    assert misfit == 0 and margin == pytest.approx(0.2)
    assert (up @ n < c).all() and (lo @ n > c).all()
    stray = np.vstack([up, [[4.6, 2.0]]])
    lo_far = np.vstack([lo, np.column_stack([np.full(len(y), 5.0), y])])
    n, c, misfit, _ = separating_line(stray, lo_far)
    assert misfit == 1.0 and stray[-1] @ n > c


def _staircase_faces():
    left = shapely.Polygon([(0, 0), (4, 0), (4, 1), (4.5, 1), (4.5, 3), (4, 3), (4, 4), (0, 4)])
    return [left, shapely.box(0, 0, 8, 4).difference(left)]


def test_a_step_boundary_is_the_line_between_the_levels():
    """A raster staircase that puts a row of the lower level under the upper face becomes the straight line
    between the rows: every labelled point under its own plane's face, the faces tile the outline."""
    faces = _staircase_faces()
    rng = np.random.default_rng(1)
    y = rng.uniform(0.1, 3.9, 60)
    x = np.where(np.arange(60) % 2, rng.uniform(3.3, 3.95, 60), rng.uniform(4.05, 4.7, 60))
    labels = (x > 4).astype(int)
    xyz = np.column_stack([x, y, np.where(labels == 0, 8.0, 5.0)])
    assert points_off_their_faces(faces, [0, 1], xyz, labels, PLANES, radius=1.0).any()
    polys, ids = fit_step_boundaries(faces, [0, 1], xyz, labels, PLANES, step_height=0.5, band=1.0, run_tolerance=0.5)
    assert ids == [0, 1]
    assert not points_off_their_faces(polys, ids, xyz, labels, PLANES, radius=1.0).any()
    assert sum(p.area for p in polys) == pytest.approx(32.0)
    assert shapely.union_all(polys).area == pytest.approx(32.0)
    assert len(shapely.get_coordinates(polys[0])) < len(shapely.get_coordinates(faces[0]))


def test_where_no_line_separates_the_levels_the_raster_boundary_stays():
    """The staircase holds an upper point that lies among the lower level's points: every line would misplace
    a point the raster placed right, so the faces are kept as they are."""
    faces = _staircase_faces()
    y = np.arange(0.25, 4.0, 0.5)
    xyz = np.vstack([np.column_stack([np.full(len(y), 3.8), y, np.full(len(y), 8.0)]),
                     np.column_stack([np.full(len(y), 4.2), y, np.full(len(y), 5.0)]),
                     [[4.35, 2.0, 8.0], [4.6, 2.0, 5.0], [4.6, 1.5, 5.0]]])
    labels = np.r_[np.zeros(len(y), int), np.ones(len(y), int), 0, 1, 1]
    # the upper point at x = 4.35 sits in the staircase's bump among lower points (x = 4.2 and 4.6)
    keep = ~((xyz[:, 0] == 4.2) & (xyz[:, 1] > 1) & (xyz[:, 1] < 3))
    xyz, labels = xyz[keep], labels[keep]
    before = points_off_their_faces(faces, [0, 1], xyz, labels, PLANES, radius=1.0)
    polys, ids = fit_step_boundaries(faces, [0, 1], xyz, labels, PLANES, step_height=0.5, band=1.0, run_tolerance=0.5)
    after = points_off_their_faces(polys, ids, xyz, labels, PLANES, radius=1.0)
    assert not (after & ~before).any()
    assert all(a.equals(b) for a, b in zip(polys, faces))


def test_a_lower_point_under_the_eave_is_hidden_by_the_upper_level_only():
    """A lower point with an upper point 0.1 m away and 3 m higher is hidden under that level; a wall's
    points (another plane, or none) and points farther than ``within`` do not hide it."""
    xyz = np.array([[4.1, 1.0, 5.0], [4.0, 1.0, 8.0], [6.0, 1.0, 5.0], [6.05, 1.0, 7.0], [8.0, 1.0, 5.0]])
    labels = np.array([1, 0, 1, -1, 1])
    hidden = hidden_under(xyz, labels, np.array([0, 2, 4]), np.array([0, 0, 0]), 0.2, 0.5)
    assert hidden.tolist() == [True, False, False]
    assert not hidden_under(xyz, labels, np.array([0]), np.array([0]), 0.05, 0.5).any()


def test_a_lower_point_under_the_eave_does_not_stop_the_upper_level_s_claim():
    """The upper level's edge row (x = 4.2, 4.35) lies under the lower face with a lower-level return between
    them and the upper face (x = 4.3, 3 m under them: under the eave).  Protected, it stops the wedge of the
    farther one (the nearer one passes with a narrow wedge); as a point under the eave (``hidden_within``) it
    does not, and only it is left under the other level."""
    from rooftrace.roof.faces import claim_points

    outline = shapely.box(0, 0, 8, 4)
    faces = [shapely.box(0, 0, 4, 4), shapely.box(4, 0, 8, 4)]
    xyz = np.array([[3.8, 2.0, 8.0], [4.2, 2.0, 8.0], [4.35, 2.0, 8.0], [4.3, 2.0, 5.0], [6.0, 2.0, 5.0],
                    [6.0, 3.0, 5.0]])
    labels = np.array([0, 0, 0, 1, 1, 1])
    kw = dict(radius=1.0, width=0.4)
    polys, ids = claim_points(faces, [0, 1], outline, xyz, labels, PLANES, **kw)
    assert points_off_their_faces(polys, ids, xyz, labels, PLANES, radius=1.0).tolist() == [0, 0, 1, 0, 0, 0]
    polys, ids = claim_points(faces, [0, 1], outline, xyz, labels, PLANES, hidden_within=0.1, **kw)
    off = points_off_their_faces(polys, ids, xyz, labels, PLANES, radius=1.0)
    assert off.tolist() == [0, 0, 0, 1, 0, 0]
    # the exception the invariant names
    assert not points_off_their_faces(polys, ids, xyz, labels, PLANES, radius=1.0, hidden_within=0.1).any()
    assert shapely.union_all(polys).area == pytest.approx(32.0)
