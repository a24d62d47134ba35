import numpy as np
import pytest

from rooftrace.image.linework import (
    angle_difference,
    filter_candidates,
    fit_segments,
    merge_collinear,
    segment_angles,
    segment_lengths,
    select_canny_steger,
)


def _seg(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y1]], float)


def _parallel(offset, length=40.0, angle_deg=0.0, origin=(10.0, 50.0)):
    """A horizontal-ish segment shifted ``offset`` px along the normal of the base direction."""
    a = np.radians(angle_deg)
    u = np.array([np.cos(a), np.sin(a)])
    n = np.array([0.0, 1.0])
    p0 = np.array(origin) + offset * n
    return np.array([p0, p0 + length * u])


def test_fit_segments_splits_an_l_chain_with_subpixel_fit(rng):
    a = np.column_stack([np.arange(0, 30.0), np.full(30, 10.3)])
    b = np.column_stack([np.full(20, 29.0), 10.3 + np.arange(1, 21.0)])
    chain = np.concatenate([a, b]) + rng.normal(0, 0.05, (50, 2))
    segs = fit_segments([chain], 1.0, 5.0)
    assert len(segs) == 2
    ang = np.degrees(segment_angles(segs))
    assert sorted(np.round(ang / 90).astype(int) % 2) == [0, 1]
    horiz = segs[np.argmin(np.abs(np.sin(np.radians(ang))))]
    assert np.abs(horiz[:, 1] - 10.3).max() < 0.1
    # short or sparse chains are dropped
    assert len(fit_segments([chain[:3]])) == 0
    assert len(fit_segments([chain[:8]], min_length=10)) == 0
    with pytest.raises(ValueError, match="tolerance"):
        fit_segments([chain], 0)


def test_fit_segments_keeps_a_straight_chain_whole_despite_bent_ends():
    x = np.arange(0, 60.0)
    y = np.zeros_like(x)
    y[:3] = [1.5, 0.8, 0.2]  # a rounded corner at the start
    segs = fit_segments([np.column_stack([x, y])], 1.0, 5.0)
    assert len(segs) == 1
    assert segment_lengths(segs)[0] > 55


def test_selection_rule_steger_replaces_flanking_canny_pair():
    steger = _parallel(0.0)[None]
    canny = np.array([_parallel(-1.8), _parallel(1.9), _parallel(15.0)])
    segs, src = select_canny_steger(canny, steger)
    assert src == ["canny", "steger"]
    np.testing.assert_allclose(segs[0], canny[2])
    np.testing.assert_allclose(segs[1], steger[0])


@pytest.mark.parametrize(
    "left, right, angle, why",
    [
        (-2.0, 3.5, 0.0, "not equidistant (1.5 px > 1 px)"),
        (-2.5, 2.5, 0.0, "too far apart (5 px > 4 px)"),
        (-1.5, 1.5, 4.0, "not parallel (4 deg > 3 deg)"),
        (0.5, 2.0, 0.0, "both on one side"),
    ],
)
def test_selection_rule_drops_steger_without_valid_pair(left, right, angle, why):
    steger = _parallel(0.0)[None]
    canny = np.array([_parallel(left), _parallel(right, angle_deg=angle)])
    segs, src = select_canny_steger(canny, steger)
    assert src == ["canny", "canny"], why
    np.testing.assert_allclose(segs, canny)


def test_selection_rule_tolerances_are_inclusive_and_configurable():
    steger = _parallel(0.0)[None]
    canny = np.array([_parallel(-1.5), _parallel(2.5)])  # 4 px apart, 1 px unequal
    assert select_canny_steger(canny, steger)[1] == ["steger"]
    assert select_canny_steger(canny, steger, max_separation=3.9)[1] == ["canny", "canny"]
    assert select_canny_steger(canny, steger, equidistance_tol=0.9)[1] == ["canny", "canny"]


def test_selection_rule_needs_overlap_and_handles_empty_inputs():
    steger = _parallel(0.0)[None]
    far = np.array([_parallel(-1.5, origin=(100, 50)), _parallel(1.5, origin=(100, 50))])
    assert select_canny_steger(far, steger)[1] == ["canny", "canny"]
    segs, src = select_canny_steger(np.zeros((0, 2, 2)), steger)
    assert segs.shape == (0, 2, 2) and src == []
    segs, src = select_canny_steger(far, np.zeros((0, 2, 2)))
    assert src == ["canny", "canny"]


def test_merge_collinear_fragments_into_one(rng):
    frags = np.array([_seg(0, 10, 20, 10.5), _seg(25, 10.8, 45, 11.2), _seg(50, 11.0, 70, 11.6)])
    segs, src = merge_collinear(frags, ["canny", "steger", "canny"])
    assert len(segs) == 1 and src == ["merged"]
    assert segs[0, :, 0].min() == pytest.approx(0.0, abs=0.1)
    assert segs[0, :, 0].max() == pytest.approx(70.0, abs=0.1)
    # order does not matter
    perm = rng.permutation(3)
    segs2, _ = merge_collinear(frags[perm][:, ::-1])
    np.testing.assert_allclose(np.sort(segs2[0, :, 0]), np.sort(segs[0, :, 0]), atol=1e-9)


def test_merge_collinear_respects_angle_distance_and_gap():
    base = _seg(0, 0, 30, 0)
    assert len(merge_collinear([base, _seg(35, 3.5, 60, 3.5)])[0]) == 2  # 3.5 px offset
    assert len(merge_collinear([base, _seg(35, 2.5, 60, 2.5)])[0]) == 1
    tilted = np.array([[35, 0], [35 + 25 * np.cos(0.18), 25 * np.sin(0.18)]])  # 10.3 deg
    assert len(merge_collinear([base, tilted], distance_tol=10)[0]) == 2
    assert len(merge_collinear([base, _seg(50, 0, 70, 0)], max_gap=10)[0]) == 2
    assert len(merge_collinear([base, _seg(50, 0, 70, 0)])[0]) == 1
    with pytest.raises(ValueError, match="sources"):
        merge_collinear([base], ["a", "b"])


def test_filter_candidates_length_and_angle():
    ref = _seg(0, 0, 100, 0)
    segs = np.array([
        _seg(0, 2, 16, 2),  # 16 % long: kept
        _seg(0, 2, 14, 2),  # 14 %: dropped
        [[0, 0], [50 * np.cos(np.radians(19)), 50 * np.sin(np.radians(19))]],  # 19 deg: kept
        [[0, 0], [50 * np.cos(np.radians(21)), 50 * np.sin(np.radians(21))]],  # 21 deg: dropped
        _seg(80, 3, 10, 5),  # reversed direction is the same line
    ])
    np.testing.assert_array_equal(filter_candidates(segs, ref), [True, False, True, False, True])


def test_angles_are_undirected():
    assert angle_difference(np.radians(179), np.radians(1)) == pytest.approx(np.radians(2))
    s = np.array([_seg(0, 0, 1, 1), _seg(1, 1, 0, 0)])
    assert segment_angles(s)[0] == pytest.approx(segment_angles(s)[1])
    with pytest.raises(ValueError, match="shape"):
        segment_lengths(np.zeros((3, 3)))


def test_merge_collinear_keeps_side_by_side_parallels_apart():
    roof_edge = _seg(0, 10, 60, 10)
    wall_foot = _seg(2, 12, 58, 12.2)  # 2 px away, overlapping: two lines, not fragments
    segs, src = merge_collinear([roof_edge, wall_foot], ["canny", "canny"])
    assert len(segs) == 2 and src == ["canny", "canny"]
    dup = _seg(5, 10.6, 50, 10.6)  # within 1 px: a duplicate, merged
    assert len(merge_collinear([roof_edge, dup])[0]) == 1
    inside = _seg(20, 12, 30, 12)  # contained entirely: overlap 100 %
    assert len(merge_collinear([roof_edge, inside])[0]) == 2
    assert len(merge_collinear([roof_edge, inside], duplicate_tol=2.5)[0]) == 1


def test_selection_modes():
    steger = _parallel(0.0)[None]
    canny = np.array([_parallel(-1.8), _parallel(1.9), _parallel(15.0)])
    segs, src = select_canny_steger(canny, steger, mode="both")
    assert src == ["canny", "canny", "canny", "steger"]
    segs, src = select_canny_steger(canny, steger, mode="canny")
    assert src == ["canny"] * 3
    with pytest.raises(ValueError, match="mode"):
        select_canny_steger(canny, steger, mode="steger")
