"""Closed-cycle DP against brute force on tiny candidate grids (issue 8)."""

import numpy as np
import pytest

from rooftrace.snake.dp import brute_force_cycle, cycle_dp, cycle_energy


def _tables(rng, n, k):
    return rng.normal(size=(n, k)), rng.normal(size=(n, k, k)), rng.normal(size=(n, k, k, k))


@pytest.mark.parametrize("n", [3, 4, 5, 6])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_dp_matches_brute_force(n, k):
    rng = np.random.default_rng(100 * n + k)
    for _ in range(4):
        u, p, t = _tables(rng, n, k)
        labels, e = cycle_dp(u, p, t)
        _, e_ref = brute_force_cycle(u, p, t)
        assert e == pytest.approx(e_ref, abs=1e-12)
        assert cycle_energy(labels, u, p, t) == pytest.approx(e, abs=1e-12)
        assert labels.shape == (n,) and labels.min() >= 0 and labels.max() < k


def test_dp_wraparound_terms_matter():
    # only the closing pair P_{n-1}(v_{n-1}, v_0) and the wrapping triplet carry
    # information: an implementation that drops them picks the wrong labels
    n, k = 5, 3
    u, p, t = np.zeros((n, k)), np.zeros((n, k, k)), np.zeros((n, k, k, k))
    p[n - 1] = 1.0
    p[n - 1, 2, 1] = -5.0
    t[0] = 1.0
    t[0, 2, 1, 0] = -3.0
    labels, e = cycle_dp(u, p, t)
    assert labels[n - 1] == 2 and labels[0] == 1 and labels[1] == 0
    assert e == pytest.approx(-8.0)


def test_dp_is_invariant_to_cyclic_relabelling():
    rng = np.random.default_rng(7)
    u, p, t = _tables(rng, 6, 3)
    _, e = cycle_dp(u, p, t)
    s = 2  # start the cycle at another vertex: same problem, same minimum
    _, e2 = cycle_dp(np.roll(u, -s, 0), np.roll(p, -s, 0), np.roll(t, -s, 0))
    assert e2 == pytest.approx(e, abs=1e-12)


def test_dp_deterministic_on_ties():
    n, k = 4, 3
    z = (np.zeros((n, k)), np.zeros((n, k, k)), np.zeros((n, k, k, k)))
    labels, e = cycle_dp(*z)
    assert e == 0.0 and labels.tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize(
    "shapes, match",
    [(((2, 3), (2, 3, 3), (2, 3, 3, 3)), "n >= 3"),
     (((4, 3), (4, 3, 2), (4, 3, 3, 3)), "pair must have shape"),
     (((4, 3), (4, 3, 3), (4, 3, 3)), "triple must have shape")],
)
def test_dp_rejects_bad_tables(shapes, match):
    with pytest.raises(ValueError, match=match):
        cycle_dp(*(np.zeros(s) for s in shapes))


def test_dp_rejects_nan():
    u = np.zeros((3, 2))
    u[1, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        cycle_dp(u, np.zeros((3, 2, 2)), np.zeros((3, 2, 2, 2)))
