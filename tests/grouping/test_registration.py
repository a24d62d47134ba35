import numpy as np
import pytest

from rooftrace.grouping.registration import RoofShift, estimate_shift, shift_references

SQUARE = np.array([[[0, 0], [40, 0]], [[40, 0], [40, 30]], [[40, 30], [0, 30]], [[0, 30], [0, 0]]], float)
OUT = np.array([[0, -1], [1, 0], [0, 1], [-1, 0]], float)


def _candidates(t, b, seed=0, distractor=3.0, noise=0.2):
    rng = np.random.default_rng(seed)
    true = SQUARE + t + OUT[:, None] * b
    cands = []
    for s in range(4):
        edge = true[s] + OUT[s] * rng.normal(0, noise)
        cands.append(np.stack([edge, edge + OUT[s] * distractor]))  # the edge and a wall foot beyond it
    return cands


def test_common_shift_and_growth_are_recovered_despite_a_line_beyond_each_side():
    est = estimate_shift(SQUARE, _candidates([2.5, -3.0], 1.8), OUT, [np.ones(2, bool)] * 4)
    assert est.n_sides == 4
    np.testing.assert_allclose(est.translation, [2.5, -3.0], atol=0.4)
    assert abs(est.growth - 1.8) < 0.4 and 0 < est.variance < 1


def test_seed_free_and_order_free():
    cands = _candidates([1.0, 2.0], 1.0, seed=3)
    a = estimate_shift(SQUARE, cands, OUT, [np.ones(2, bool)] * 4)
    b = estimate_shift(SQUARE, [c[::-1] for c in cands], OUT, [np.ones(2, bool)] * 4)
    np.testing.assert_allclose(a.translation, b.translation)


def test_too_few_or_parallel_sides_give_no_estimate():
    cands = _candidates([1.0, 1.0], 0.0)
    usable = [np.ones(2, bool), np.zeros(2, bool), np.ones(2, bool), np.zeros(2, bool)]
    assert estimate_shift(SQUARE, cands, OUT, usable).n_sides == 0  # two parallel sides only
    ridges = np.full_like(OUT, np.nan)
    assert estimate_shift(SQUARE, cands, ridges, [np.ones(2, bool)] * 4).n_sides == 0


def test_shift_is_weighed_by_the_camera_prior():
    est = RoofShift(np.array([3.0, -1.0]), 1.0, 4, 0.5)
    np.testing.assert_array_equal(est.shrunk(0.0).translation, [0, 0])  # a camera known exactly
    np.testing.assert_allclose(est.shrunk(4.5).translation, [2.7, -0.9])
    moved = shift_references(SQUARE, est)
    np.testing.assert_allclose(moved - SQUARE, np.broadcast_to([3.0, -1.0], SQUARE.shape))


def test_lines_at_the_expected_wall_foot_are_flagged():
    from rooftrace.grouping.registration import beyond_wall

    est = RoofShift(np.array([1.0, 0.0]), 1.0, 4, 0.3)
    edge = SQUARE[1] + [1.0, 0.0] + OUT[1] * 1.0  # east side: roof edge where the estimate puts it
    cands = [SQUARE[0][None], np.stack([edge, edge + OUT[1] * 3.0]), SQUARE[2][None], SQUARE[3][None]]
    width = np.array([0.0, 3.0, 0.0, 0.0])  # only the east wall shows, 3 px wide
    far = beyond_wall(SQUARE, cands, OUT, width, est, [np.ones(len(c), bool) for c in cands])
    assert far[1].tolist() == [False, True] and not any(f.any() for f in far[::2])
    none = beyond_wall(SQUARE, cands, OUT, width, RoofShift(np.zeros(2), 0.0, 0), [np.ones(len(c), bool) for c in cands])
    assert not any(f.any() for f in none)


def test_growth_is_re_estimated_with_the_shrunk_translation():
    # the roof's lines lie 1.5 px outside the projections and the camera is exact: t = 0 and b = 1.5,
    # whatever the joint estimate made of the two (three sides facing two directions barely separate them)
    cands = _candidates([0.0, 0.0], 1.5, seed=4, noise=0.1)
    usable = [np.ones(2, bool), np.ones(2, bool), np.zeros(2, bool), np.ones(2, bool)]
    est = estimate_shift(SQUARE, cands, OUT, usable)
    fixed = est.shrunk(0.0)
    np.testing.assert_array_equal(fixed.translation, [0.0, 0.0])
    assert fixed.growth == pytest.approx(1.5, abs=0.15)
    assert len(fixed.offsets) == est.n_sides == 3
    assert RoofShift(np.zeros(2), 0.7, 0).shrunk(1.0).growth == 0.7  # no inliers kept: the growth as it was
