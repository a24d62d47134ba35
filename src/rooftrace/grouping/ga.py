"""The genetic algorithm of Marcato & Dal Poz (§2.3) that minimises the grouping energy.

A chromosome holds one gene group per side/ridge; the uniqueness rule (one
candidate per side) makes each group a one-hot block, stored here as the
index of its 1 (an integer vector of length M), which is the same thing with
no invalid states to repair.  Per generation (Goldberg 1989):

1. fitness of the whole population in one vectorised call
   (:meth:`GroupingProblem.energy`); fitness = ``U_worst - U`` plus a small
   floor so that every individual keeps a chance (linear scaling for
   minimisation; the seed maximises "aptidão" without giving its form);
2. deterministic-sampling selection: individual i gets ``floor(e_i)`` copies,
   ``e_i = n f_i / Σ f``; the remaining places go to the largest fractional
   parts of ``e_i``;
3. elitism: the best individual is copied unchanged; the other n - 1 are
   bred;
4. random pairs; with probability p_c one-point crossover whose cut is at a
   side boundary (never inside a gene group);
5. inversion mutation within a side: with probability p_m per side, the 1 of
   the group moves to another candidate of that side (uniform);
6. a fixed number of generations; the result is the best individual seen.

Population size and generations default to the seed's settings scaled with
the problem (15/20 for up to 12 lines as in its buildings 1-2, 25/40 beyond,
as for its 39-line building), see :class:`GAOptions`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rooftrace.grouping.mrf import GroupingProblem

__all__ = ["GAOptions", "GAResult", "genetic_minimise", "deterministic_sampling"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GAOptions:
    """Parameters of the genetic algorithm (Marcato & Dal Poz §2.3 and §3).

    Attributes
    ----------
    population : int or None, default None
        Individuals per generation. None: 15 for up to 12 sides, 25 beyond
        (Marcato & Dal Poz §3: 15 for its 9- and 11-line roofs, 25 for 39 lines),
        raised to ``4 · Σ_s (K_s - 1)`` for roofs with many ambiguous sides
        (ours: the paper's roofs had 1-3 candidates per side).
    generations : int or None, default None
        Generations. None: 20 for up to 12 sides, 40 beyond (Marcato & Dal Poz §3),
        raised likewise to ``2 · Σ_s (K_s - 1)``.
    crossover_probability : float, default 0.7
        p_c (Marcato & Dal Poz §3).
    mutation_probability : float, default 0.01
        p_m per side (Marcato & Dal Poz §3).
    elitism : bool, default True
        Copy the best individual into the next generation (Marcato & Dal Poz §2.3).
    """

    section = "ga"

    population: int | None = None
    generations: int | None = None
    crossover_probability: float = 0.7
    mutation_probability: float = 0.01
    elitism: bool = True

    def __post_init__(self) -> None:
        if self.population is not None and (not isinstance(self.population, int) or self.population < 2):
            raise ValueError(f"ga.population must be an int >= 2, got {self.population!r}")
        if self.generations is not None and (not isinstance(self.generations, int) or self.generations < 0):
            raise ValueError(f"ga.generations must be an int >= 0, got {self.generations!r}")
        for name in ("crossover_probability", "mutation_probability"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"ga.{name} must be in [0, 1], got {v!r}")

    def resolve(self, n_candidates: np.ndarray) -> tuple[int, int]:
        """(population, generations) for a problem with these candidate counts."""
        m = len(n_candidates)
        freedom = int(np.sum(np.asarray(n_candidates) - 1))
        pop = self.population if self.population is not None else max(15 if m <= 12 else 25, 4 * freedom)
        gen = self.generations if self.generations is not None else max(20 if m <= 12 else 40, 2 * freedom)
        return int(pop), int(gen)


@dataclass(frozen=True)
class GAResult:
    """Best labelling found.

    Attributes
    ----------
    choice : ndarray of shape (M,) int
        Chosen candidate per side.
    energy : float
        U(choice).
    history : ndarray of shape (generations + 1,)
        Best energy so far after each generation (non-increasing).
    population, generations : int
        The resolved sizes.
    """

    choice: np.ndarray
    energy: float
    history: np.ndarray
    population: int
    generations: int


def deterministic_sampling(fitness: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` parents by deterministic sampling (Goldberg 1989, p. 121).

    Each individual gets ``floor(e_i)`` copies, ``e_i = n f_i / Σ f``; the
    places left go to the largest fractional parts (ties by index).

    Examples
    --------
    >>> deterministic_sampling(np.array([3.0, 1.0, 0.0, 0.0]), 4).tolist()
    [0, 0, 0, 1]
    """
    f = np.asarray(fitness, float)
    total = f.sum()
    expected = np.full(len(f), n / len(f)) if total <= 0 else n * f / total
    copies = np.floor(expected).astype(int)
    left = n - copies.sum()
    if left > 0:
        order = np.argsort(-(expected - copies), kind="stable")
        copies[order[:left]] += 1
    return np.repeat(np.arange(len(f)), copies)[:n]


def _fitness(energy: np.ndarray) -> np.ndarray:
    spread = float(energy.max() - energy.min())
    floor = 0.05 * spread if spread > 0 else 1.0
    return energy.max() - energy + floor


def genetic_minimise(problem: GroupingProblem, options: GAOptions | None = None, seed: int = 0,
                     initial: np.ndarray | None = None) -> GAResult:
    """Minimise the grouping energy with the genetic algorithm of Marcato & Dal Poz §2.3.

    Parameters
    ----------
    problem : GroupingProblem
    options : GAOptions, optional
    seed : int, default 0
        Seed of the random generator; the same seed gives the same result.
    initial : ndarray of shape (n0, M) int, optional
        Individuals to put in the first generation (the rest is random).

    Returns
    -------
    GAResult

    Examples
    --------
    >>> import numpy as np
    >>> from rooftrace.grouping.mrf import build_problem
    >>> refs = np.array([[[0, 0], [10, 0]], [[10, 0], [10, 10]]], float)
    >>> cands = [np.concatenate([refs[:1] + [0, 4], refs[:1]]), np.concatenate([refs[1:] + [3, 0], refs[1:]])]
    >>> genetic_minimise(build_problem(refs, cands, np.array([[0, 1]])), seed=1).choice.tolist()
    [1, 1]
    """
    options = options or GAOptions()
    k = np.asarray(problem.n_candidates, int)
    m = len(k)
    rng = np.random.default_rng(seed)
    n, generations = options.resolve(k)
    if m == 0:
        return GAResult(np.zeros(0, int), problem.energy(np.zeros(0, int)), np.zeros(1), n, generations)
    pop = np.floor(rng.random((n, m)) * k).astype(int)
    if initial is not None:
        init = np.asarray(initial, int).reshape(-1, m)[:n]
        pop[: len(init)] = init
    energy = problem.energy(pop)
    best = int(np.argmin(energy))
    best_choice, best_energy = pop[best].copy(), float(energy[best])
    history = [best_energy]
    multi = k > 1
    for _ in range(generations):
        n_bred = n - 1 if options.elitism else n
        parents = pop[deterministic_sampling(_fitness(energy), n_bred)]
        parents = parents[rng.permutation(n_bred)]
        children = parents.copy()
        if m > 1:
            for a in range(0, n_bred - 1, 2):
                if rng.random() < options.crossover_probability:
                    cut = int(rng.integers(1, m))  # a side boundary: genes [0, cut) | [cut, m)
                    children[a, cut:], children[a + 1, cut:] = parents[a + 1, cut:], parents[a, cut:]
        mutate = (rng.random(children.shape) < options.mutation_probability) & multi[None, :]
        if mutate.any():
            rows, cols = np.nonzero(mutate)
            # move the side's 1 to another of its candidates: add 1..K-1 modulo K
            step = 1 + np.floor(rng.random(len(cols)) * (k[cols] - 1)).astype(int)
            children[rows, cols] = (children[rows, cols] + step) % k[cols]
        pop = np.concatenate([best_choice[None, :], children]) if options.elitism else children
        energy = problem.energy(pop)
        i = int(np.argmin(energy))
        if energy[i] < best_energy:
            best_choice, best_energy = pop[i].copy(), float(energy[i])
        history.append(best_energy)
    return GAResult(best_choice, best_energy, np.array(history), n, generations)
