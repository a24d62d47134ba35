"""The genetic algorithm: determinism, operators, and reaching the exact minimum."""

from __future__ import annotations

import numpy as np
import pytest

from rooftrace.grouping.exact import exact_minimise
from rooftrace.grouping.ga import GAOptions, deterministic_sampling, genetic_minimise
from rooftrace.grouping.mrf import build_problem
from tests.grouping.common import random_problem, ring_pairs, synthetic_roof


def test_deterministic_sampling_counts():
    f = np.array([5.0, 2.5, 1.5, 1.0])
    idx = deterministic_sampling(f, 10)
    assert len(idx) == 10
    np.testing.assert_array_equal(np.bincount(idx, minlength=4), [5, 3, 1, 1])  # 5, 2.5, 1.5, 1.0
    assert len(deterministic_sampling(np.zeros(3), 5)) == 5


def test_same_seed_same_result_and_monotone_history():
    rng = np.random.default_rng(1)
    refs, cands, pairs, corners = random_problem(rng, n_sides=12)
    p = build_problem(refs, cands, pairs, corners)
    a, b = genetic_minimise(p, seed=7), genetic_minimise(p, seed=7)
    np.testing.assert_array_equal(a.choice, b.choice)
    np.testing.assert_array_equal(a.history, b.history)
    assert np.all(np.diff(a.history) <= 0)
    assert a.energy == pytest.approx(p.energy(a.choice))
    assert all(0 <= c < k for c, k in zip(a.choice, p.n_candidates))


def test_resolved_sizes_follow_the_seed():
    assert GAOptions().resolve(np.ones(10, int)) == (15, 20)
    assert GAOptions().resolve(np.ones(39, int)) == (25, 40)
    assert GAOptions(population=50, generations=5).resolve(np.full(10, 3)) == (50, 5)


def test_ga_reaches_the_exact_minimum_on_95_percent():
    hits, runs = 0, 0
    for seed in range(60):
        rng = np.random.default_rng(1000 + seed)
        refs, cands, pairs, corners = random_problem(rng, n_sides=int(rng.integers(8, 13)), max_candidates=4)
        p = build_problem(refs, cands, pairs, corners)
        exact = exact_minimise(p)
        ga = genetic_minimise(p, seed=seed)
        assert ga.energy >= exact.energy - 1e-9
        hits += ga.energy <= exact.energy + 1e-9
        runs += 1
    assert hits / runs >= 0.95


def test_ga_finds_the_true_lines_on_synthetic_roofs():
    ok = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        _, refs, cands, truth, corners = synthetic_roof(rng)
        ga = genetic_minimise(build_problem(refs, cands, ring_pairs(len(refs)), corners), seed=seed)
        ok += np.mean(ga.choice == truth)
    assert ok / 20 >= 0.95


def test_bad_options():
    with pytest.raises(ValueError, match="ga.crossover_probability"):
        GAOptions(crossover_probability=1.5)
    with pytest.raises(ValueError, match="ga.population"):
        GAOptions(population=1)
