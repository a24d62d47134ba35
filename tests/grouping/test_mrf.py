"""Each energy term of seed 000 (eq. 6-13) on hand-computed cases, and the table-based energy."""

from __future__ import annotations

import numpy as np
import pytest

from rooftrace.grouping.exact import brute_force_minimise
from rooftrace.grouping.mrf import (
    MRFOptions,
    build_problem,
    corner_term,
    length_term,
    orientation_term,
    proximity_term,
    rectangularity_term,
)
from tests.grouping.common import ring_pairs, synthetic_roof

H = np.array([[0.0, 0.0], [10.0, 0.0]])  # horizontal reference
V = np.array([[10.0, 0.0], [10.0, 10.0]])  # vertical reference


def _rot(line, deg, centre=None):
    c = line.mean(axis=0) if centre is None else centre
    a = np.radians(deg)
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (line - c) @ r.T + c


def test_length_favours_long_candidates():
    cands = np.array([H, H * 0.5, H * 2])
    np.testing.assert_allclose(length_term(H, cands), [1.0, 2.0, 0.5])


def test_proximity_is_half_the_sum_of_end_distances():
    ci = np.array([H + [0, 2], H + [0, -1]])  # distances (2, 2) and (1, 1)
    cj = np.array([V + [3, 0]])  # distances (3, 3)
    np.testing.assert_allclose(proximity_term(H, ci, V, cj), [[0.5 * (4 + 6)], [0.5 * (2 + 6)]])
    # distance to the infinite line: sliding along the reference changes nothing
    np.testing.assert_allclose(proximity_term(H, ci + [50, 0], V, cj), proximity_term(H, ci, V, cj))


def test_orientation_sigmoid_values():
    ci = np.array([H, _rot(H, 10), _rot(H, 170), _rot(H, 30)])
    cj = np.array([V])
    s = orientation_term(H, ci, V, cj, beta=20.0)[:, 0]
    t = np.radians(10.0)
    expected = 2 / (1 + np.exp(-20 * t * t)) - 1
    np.testing.assert_allclose(s[:3], [0.0, expected, expected], atol=1e-12)  # 170° is 10° off (θ0 = 0 or 180)
    assert s[3] > s[1] and 0 <= s[3] < 1
    # θ = θ_i + θ_j: two 5° errors are one 10° error
    s2 = orientation_term(H, np.array([_rot(H, 5)]), V, np.array([_rot(V, 5)]), beta=20.0)
    np.testing.assert_allclose(s2[0, 0], expected)


def test_rectangularity_zero_for_parallel_and_orthogonal():
    ci = np.array([H])
    cj = np.array([V, H + [0, 5], _rot(V, 45), _rot(V, 30)])
    np.testing.assert_allclose(rectangularity_term(ci, cj)[0], [0, 0, 1, np.sin(np.radians(120))], atol=1e-12)


def test_corner_distance_to_nearest_harris_corner():
    ci, cj = np.array([H]), np.array([V])  # meet at (10, 0)
    assert corner_term(ci, cj, np.array([[10.0, 0.0], [50, 50]]))[0, 0] == pytest.approx(0, abs=1e-9)
    assert corner_term(ci, cj, np.array([[13.0, 4.0]]))[0, 0] == pytest.approx(5.0)
    # no corner nearby, or none at all: the cap
    assert corner_term(ci, cj, np.array([[80.0, 80.0]]), max_distance=10)[0, 0] == pytest.approx(10.0)
    assert corner_term(ci, cj, None, max_distance=7)[0, 0] == pytest.approx(7.0)
    # weighted by |sin| of the angle: a 30° pair counts half; parallel lines give ~0
    cj30 = np.array([_rot(np.array([[10.0, 0.0], [20.0, 0.0]]), 30, centre=np.array([10.0, 0.0]))])
    assert corner_term(ci, cj30, np.array([[13.0, 4.0]]))[0, 0] == pytest.approx(2.5)
    assert corner_term(ci, np.array([H + [0, 3]]), np.array([[0.0, 0.0]]))[0, 0] == pytest.approx(0.0, abs=1e-9)


def test_energy_tables_match_the_weighted_terms(rng):
    _, refs, cands, _, corners = synthetic_roof(rng)
    opts = MRFOptions(w_length=0.1, w_proximity=0.3, w_orientation=0.2, w_rectangularity=0.15, w_corner=0.25)
    p = build_problem(refs, cands, ring_pairs(len(refs)), corners, opts)
    for _ in range(20):
        c = np.array([rng.integers(k) for k in p.n_candidates])
        terms = p.term_values(c)
        total = sum(w * terms[name] for w, name in zip(opts.weights, terms))
        assert p.energy(c) == pytest.approx(total)
    pop = np.stack([[rng.integers(k) for k in p.n_candidates] for _ in range(7)])
    np.testing.assert_allclose(p.energy(pop), [p.energy(c) for c in pop])


def test_pairwise_terms_count_each_pair_from_both_sides():
    refs = np.array([H, V])
    cands = [np.array([H + [0, 1]]), np.array([V + [1, 0]])]
    p = build_problem(refs, cands, np.array([[1, 0]]), None, MRFOptions(0, 1, 0, 0, 0))
    assert p.energy([0, 0]) == pytest.approx(2 * 0.5 * (2 + 2))


def test_true_lines_are_the_minimum_on_synthetic_roofs():
    hits = 0
    for seed in range(40):
        r = np.random.default_rng(seed)
        _, refs, cands, truth, corners = synthetic_roof(r)
        best = brute_force_minimise(build_problem(refs, cands, ring_pairs(len(refs)), corners))
        hits += np.array_equal(best.choice, truth)
    assert hits >= 36


def test_bad_arguments():
    with pytest.raises(ValueError, match="at least one candidate"):
        build_problem(np.array([H, V]), [np.array([H]), np.zeros((0, 2, 2))], np.array([[0, 1]]))
    with pytest.raises(ValueError, match="pairs"):
        build_problem(np.array([H, V]), [np.array([H]), np.array([V])], np.array([[0, 2]]))
    with pytest.raises(ValueError, match="2 reference"):
        build_problem(np.array([H, V]), [np.array([H])], np.array([[0, 1]]))
    with pytest.raises(ValueError, match="mrf.w_corner"):
        MRFOptions(w_corner=-1)
    with pytest.raises(ValueError, match="mrf.beta"):
        MRFOptions(beta=0)


def test_penalties_add_to_the_unary_energy():
    refs = np.array([[[0, 0], [10, 0]], [[10, 0], [10, 10]]], float)
    cands = [refs[:1] + [0, 1], np.concatenate([refs[1:], refs[1:] + [3, 0]])]
    plain = build_problem(refs, cands, np.array([[0, 1]]))
    pen = build_problem(refs, cands, np.array([[0, 1]]), penalties=[np.zeros(1), np.array([5.0, 0.0])])
    assert pen.energy([0, 0]) == pytest.approx(plain.energy([0, 0]) + 5.0)
    assert pen.energy([0, 1]) == pytest.approx(plain.energy([0, 1]))
    with pytest.raises(ValueError, match="penalties"):
        build_problem(refs, cands, np.array([[0, 1]]), penalties=[np.zeros(1), np.zeros(1)])
