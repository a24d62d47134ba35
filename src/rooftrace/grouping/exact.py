"""Exact minimisers of the grouping energy, to check the genetic algorithm.

Two of them:

- :func:`brute_force_minimise` enumerates every labelling (in vectorised
  chunks) - the reference, for problems of up to about a million labellings;
- :func:`exact_minimise` is min-sum variable elimination (bucket elimination,
  Dechter 1999) with a min-fill order.  The energy is a sum of unary and
  pairwise terms on the roof's line graph; an outline ring has tree width 2
  and ridges add little, so elimination is exact and fast for roofs far
  beyond brute force.  It gives up (returns None) when an intermediate table
  would exceed ``max_table``.

References
----------
Dechter R. (1999). Bucket elimination: a unifying framework for reasoning.
Artificial Intelligence 113(1-2), 41-85. doi:10.1016/S0004-3702(99)00059-4
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rooftrace.grouping.mrf import GroupingProblem

__all__ = ["ExactResult", "exact_minimise", "brute_force_minimise"]


@dataclass(frozen=True)
class ExactResult:
    """The global minimum: ``choice`` (M,) int and its ``energy``; ``method`` names the solver."""

    choice: np.ndarray
    energy: float
    method: str


def brute_force_minimise(problem: GroupingProblem, max_configurations: int = 2**20,
                         chunk: int = 2**16) -> ExactResult | None:
    """Enumerate every labelling; None when there are more than ``max_configurations``.

    Ties go to the first labelling in lexicographic order (last side fastest).
    """
    k = np.asarray(problem.n_candidates, int)
    total = int(np.prod(k)) if len(k) else 1
    if total > max_configurations:
        return None
    best_e, best_c = np.inf, np.zeros(len(k), int)
    for start in range(0, total, chunk):
        flat = np.arange(start, min(total, start + chunk))
        choices = np.stack(np.unravel_index(flat, k), axis=1) if len(k) else np.zeros((len(flat), 0), int)
        e = np.atleast_1d(problem.energy(choices))
        i = int(np.argmin(e))
        if e[i] < best_e:
            best_e, best_c = float(e[i]), choices[i].copy()
    return ExactResult(best_c, float(problem.energy(best_c)), "brute_force")


def _min_fill_order(m: int, edges: set[tuple[int, int]]) -> list[int]:
    adj = {v: set() for v in range(m)}
    for a, b in edges:
        adj[a].add(b)
        adj[b].add(a)
    order = []
    remaining = set(range(m))
    while remaining:
        def fill(v: int) -> tuple[int, int, int]:
            nb = list(adj[v] & remaining)
            missing = sum(1 for i in range(len(nb)) for j in range(i + 1, len(nb)) if nb[j] not in adj[nb[i]])
            return missing, len(nb), v

        v = min(remaining, key=fill)
        nb = list(adj[v] & remaining)
        for i in range(len(nb)):
            for j in range(i + 1, len(nb)):
                adj[nb[i]].add(nb[j])
                adj[nb[j]].add(nb[i])
        remaining.remove(v)
        order.append(v)
    return order


def _expand(scope: tuple[int, ...], table: np.ndarray, target: tuple[int, ...]) -> np.ndarray:
    """View ``table`` over ``scope`` as broadcastable over ``target`` (a superset)."""
    perm = sorted(range(len(scope)), key=lambda a: target.index(scope[a]))
    t = np.transpose(table, perm)
    shape = [1] * len(target)
    for a in perm:
        shape[target.index(scope[a])] = table.shape[a]
    return t.reshape(shape)


def exact_minimise(problem: GroupingProblem, max_table: int = 2**22) -> ExactResult | None:
    """Global minimum by min-sum variable elimination; None when a table would exceed ``max_table``.

    Parameters
    ----------
    problem : GroupingProblem
    max_table : int, default 2**22
        Largest intermediate table (entries) allowed.

    Returns
    -------
    ExactResult or None

    Examples
    --------
    >>> import numpy as np
    >>> from rooftrace.grouping.mrf import build_problem
    >>> refs = np.array([[[0, 0], [10, 0]], [[10, 0], [10, 10]]], float)
    >>> cands = [np.concatenate([refs[:1] + [0, 4], refs[:1]]), np.concatenate([refs[1:] + [3, 0], refs[1:]])]
    >>> exact_minimise(build_problem(refs, cands, np.array([[0, 1]]))).choice.tolist()
    [1, 1]
    """
    k = np.asarray(problem.n_candidates, int)
    m = len(k)
    factors: list[tuple[tuple[int, ...], np.ndarray]] = [((s,), np.asarray(u, float))
                                                         for s, u in enumerate(problem.unary)]
    for (s, t), tab in zip(problem.pairs, problem.pair_tables):
        factors.append(((int(s), int(t)), np.asarray(tab, float)))
    edges = {(int(s), int(t)) for s, t in problem.pairs}
    order = _min_fill_order(m, edges)
    # argmin tables to back-substitute: (variable, scope of the others, table of best values)
    trace: list[tuple[int, tuple[int, ...], np.ndarray]] = []
    constant = 0.0
    for v in order:
        bucket = [f for f in factors if v in f[0]]
        factors = [f for f in factors if v not in f[0]]
        others = tuple(sorted({x for scope, _ in bucket for x in scope if x != v}))
        target = (v,) + others
        size = int(np.prod([k[x] for x in target]))
        if size > max_table:
            return None
        total = np.zeros([k[x] for x in target])
        for scope, table in bucket:
            total = total + _expand(scope, table, target)
        trace.append((v, others, np.argmin(total, axis=0)))
        reduced = total.min(axis=0)
        if others:
            factors.append((others, reduced))
        else:
            constant += float(reduced)
    for _scope, table in factors:  # only constants can remain
        constant += float(np.sum(table))
    choice = np.zeros(m, int)
    for v, others, arg in reversed(trace):
        choice[v] = int(arg[tuple(choice[x] for x in others)]) if others else int(arg)
    return ExactResult(choice, float(problem.energy(choice)), "variable_elimination")
