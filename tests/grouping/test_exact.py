"""Variable elimination against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from rooftrace.grouping.exact import brute_force_minimise, exact_minimise
from rooftrace.grouping.mrf import build_problem
from tests.grouping.common import random_problem


@pytest.mark.parametrize("seed", range(12))
def test_elimination_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    refs, cands, pairs, corners = random_problem(rng, n_sides=int(rng.integers(3, 9)), max_candidates=4)
    # chords make the graph more than a ring (ridges joining outline vertices)
    extra = [(0, len(refs) // 2), (1, len(refs) - 1)] if len(refs) > 4 else []
    pairs = np.unique(np.sort(np.concatenate([pairs, np.array(extra, int).reshape(-1, 2)]), axis=1), axis=0)
    p = build_problem(refs, cands, pairs, corners)
    ve, bf = exact_minimise(p), brute_force_minimise(p)
    assert ve.energy == pytest.approx(bf.energy, abs=1e-9)
    assert p.energy(ve.choice) == pytest.approx(ve.energy)


def test_limits_give_none():
    rng = np.random.default_rng(3)
    refs, cands, pairs, corners = random_problem(rng, n_sides=8, max_candidates=4)
    cands = [np.concatenate([c, c + 1, c + 2]) for c in cands]
    p = build_problem(refs, cands, pairs, corners)
    assert brute_force_minimise(p, max_configurations=100) is None
    assert exact_minimise(p, max_table=10) is None
    assert exact_minimise(p) is not None


def test_single_side_and_no_pairs():
    refs = np.array([[[0, 0], [10, 0]]], float)
    p = build_problem(refs, [np.array([[[0, 0], [5, 0]], [[0, 0], [10, 0]]], float)], np.zeros((0, 2), int))
    assert exact_minimise(p).choice.tolist() == [1]
    assert brute_force_minimise(p).choice.tolist() == [1]
