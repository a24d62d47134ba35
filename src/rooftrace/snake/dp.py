"""Exact minimisation of a closed polygon snake by dynamic programming.

Why our own: Amini et al.'s DP for snakes is textbook but not in any library,
and the snake of Dal Poz & Fazan is a *closed* polygon with a *second-order*
(triplet) right-angle term.  With the energy

    E = sum_i U_i(v_i) + sum_i P_i(v_i, v_{i+1}) + sum_i T_i(v_{i-1}, v_i, v_{i+1})

(indices modulo n), the state of the chain DP is a pair of consecutive
vertices.  The cycle is closed exactly by fixing the candidates of v_0 and
v_1, running the chain DP over v_2 .. v_{n-1}, adding the terms that wrap
around, and keeping the best over all fixed pairs: O(n K^5) for K candidates
per vertex, exact for the given candidate sets.  The tables are arrays over
candidate pairs and triplets (built vectorised by ``energy``); the recursion
runs in numba because its K^5 inner loop would otherwise need K^4-element
temporaries per step.
"""

from __future__ import annotations

import itertools

import numpy as np
from numba import njit

__all__ = ["cycle_dp", "cycle_energy", "brute_force_cycle"]


def _check(unary, pair, triple):
    unary = np.ascontiguousarray(unary, dtype=np.float64)
    pair = np.ascontiguousarray(pair, dtype=np.float64)
    triple = np.ascontiguousarray(triple, dtype=np.float64)
    if unary.ndim != 2:
        raise ValueError(f"unary must have shape (n, K), got {unary.shape}")
    n, k = unary.shape
    if n < 3:
        raise ValueError(f"a closed polygon needs n >= 3 vertices, got {n}")
    if k < 1:
        raise ValueError("every vertex needs at least one candidate")
    if pair.shape != (n, k, k):
        raise ValueError(f"pair must have shape {(n, k, k)}, got {pair.shape}")
    if triple.shape != (n, k, k, k):
        raise ValueError(f"triple must have shape {(n, k, k, k)}, got {triple.shape}")
    if not (np.isfinite(unary).all() and np.isfinite(pair).all() and np.isfinite(triple).all()):
        raise ValueError("energy tables must be finite")
    return unary, pair, triple


@njit(cache=True)
def _cycle_dp(m, close, unary, pair, triple):  # pragma: no cover - compiled
    # m[i, q, r, p] = T_{i-1}(p, q, r) + P_{i-1}(q, r) + U_i(r): the cost of
    # stepping from state (v_{i-2}=p, v_{i-1}=q) to (v_{i-1}=q, v_i=r);
    # p is the last axis so the innermost loop reads contiguous memory.
    n, k = unary.shape
    best = np.inf
    labels = np.zeros(n, np.int64)
    cost = np.empty((k, k))  # cost[x, y]: x = v_i, y = v_{i-1}
    new = np.empty((k, k))
    back = np.zeros((n, k, k), np.int64)
    for a in range(k):
        for b in range(k):
            start = unary[0, a] + unary[1, b] + pair[0, a, b]
            for x in range(k):
                for y in range(k):
                    cost[x, y] = np.inf
            # i = 2: the only predecessor state is (v_0=a, v_1=b)
            for r in range(k):
                cost[r, b] = start + m[2, b, r, a]
            for i in range(3, n):
                for q in range(k):
                    row = cost[q]
                    for r in range(k):
                        bv = np.inf
                        bp = 0
                        for p in range(k):
                            v = row[p] + m[i, q, r, p]
                            if v < bv:
                                bv = v
                                bp = p
                        new[r, q] = bv
                        back[i, r, q] = bp
                for r in range(k):
                    for q in range(k):
                        cost[r, q] = new[r, q]
            # close the cycle: P_{n-1}(v_{n-1}, a), T_{n-1}(v_{n-2}, v_{n-1}, a), T_0(v_{n-1}, a, b)
            for x in range(k):
                for y in range(k):
                    c = cost[x, y]
                    if c == np.inf:
                        continue
                    v = c + close[x, a] + triple[n - 1, y, x, a] + triple[0, x, a, b]
                    if v < best:
                        best = v
                        labels[0] = a
                        labels[1] = b
                        labels[n - 1] = x
                        if n > 3:
                            labels[n - 2] = y
                            for i in range(n - 1, 2, -1):
                                labels[i - 2] = back[i, labels[i], labels[i - 1]]
    return labels, best


def cycle_dp(unary: np.ndarray, pair: np.ndarray, triple: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact minimum of a closed-polygon energy over per-vertex candidate sets.

    Parameters
    ----------
    unary : ndarray of shape (n, K)
        U_i(v_i): energy of candidate v_i of vertex i.
    pair : ndarray of shape (n, K, K)
        ``pair[i, a, b]`` = P_i(v_i = a, v_{i+1} = b), the side from vertex i
        to vertex i+1 (mod n).
    triple : ndarray of shape (n, K, K, K)
        ``triple[i, p, c, q]`` = T_i(v_{i-1} = p, v_i = c, v_{i+1} = q).

    Returns
    -------
    labels : ndarray of shape (n,), int64
        Chosen candidate of each vertex.  Ties go to the candidate found
        first (lowest v_0, then v_1 index), so the result is deterministic.
    energy : float
        The minimum of E.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> u, p, t = rng.random((4, 2)), rng.random((4, 2, 2)), rng.random((4, 2, 2, 2))
    >>> labels, e = cycle_dp(u, p, t)
    >>> bool(np.isclose(e, brute_force_cycle(u, p, t)[1]))
    True
    """
    unary, pair, triple = _check(unary, pair, triple)
    n, k = unary.shape
    # fold pair and unary terms into the step table once (vectorised)
    m = np.zeros((n, k, k, k))
    for i in range(2, n):
        # (p, q, r) -> (q, r, p)
        step = triple[i - 1] + pair[i - 1][None, :, :] + unary[i][None, None, :]
        m[i] = np.transpose(step, (1, 2, 0))
    close = np.ascontiguousarray(pair[n - 1])
    labels, best = _cycle_dp(m, close, unary, pair, triple)
    return labels, float(best)


def cycle_energy(labels: np.ndarray, unary: np.ndarray, pair: np.ndarray, triple: np.ndarray) -> float:
    """E of one labelling (n,) under the tables of :func:`cycle_dp`."""
    lab = np.asarray(labels, int)
    n = len(lab)
    idx = np.arange(n)
    nxt, prv = np.roll(lab, -1), np.roll(lab, 1)
    return float(unary[idx, lab].sum() + pair[idx, lab, nxt].sum() + triple[idx, prv, lab, nxt].sum())


def brute_force_cycle(unary: np.ndarray, pair: np.ndarray, triple: np.ndarray) -> tuple[np.ndarray, float]:
    """Minimum by enumerating all K^n labellings: the reference for tests (tiny problems only)."""
    unary, pair, triple = _check(unary, pair, triple)
    n, k = unary.shape
    if k**n > 2_000_000:
        raise ValueError(f"brute force over {k}^{n} labellings is too large")
    best, best_lab = np.inf, None
    for lab in itertools.product(range(k), repeat=n):
        e = cycle_energy(np.array(lab), unary, pair, triple)
        if e < best:
            best, best_lab = e, np.array(lab)
    return best_lab, float(best)
