"""Synthetic line-grouping problems with known truth (pixels): a roof, its shifted projection, candidates."""

from __future__ import annotations

import numpy as np

L_SHAPE = np.array([[100, 100], [300, 100], [300, 180], [200, 180], [200, 300], [100, 300]], float)


def ring_lines(vertices: np.ndarray) -> np.ndarray:
    """Sides (n, 2, 2) of a closed ring of vertices (n, 2)."""
    return np.stack([vertices, np.roll(vertices, -1, axis=0)], axis=1)


def ring_pairs(n: int) -> np.ndarray:
    return np.array(sorted((min(k, (k + 1) % n), max(k, (k + 1) % n)) for k in range(n)))


def synthetic_roof(rng: np.random.Generator, truth: np.ndarray = L_SHAPE, shift_px: float = 3.0,
                   max_distractors: int = 3, clutter: int = 5):
    """Truth sides, projected references, candidates per side, index of the true one, Harris corners."""
    true_lines = ring_lines(truth)
    direction = rng.normal(size=2)
    shift = shift_px * direction / np.linalg.norm(direction)
    refs = ring_lines(truth + shift + rng.normal(scale=0.7, size=truth.shape))
    candidates, true_index = [], []
    for line in true_lines:
        d = line[1] - line[0]
        u = d / np.linalg.norm(d)
        n = np.array([-u[1], u[0]])
        good = line + rng.normal(scale=0.3, size=(2, 2))
        good = good + np.array([u * rng.uniform(0, 0.1), -u * rng.uniform(0, 0.1)]) * np.linalg.norm(d)
        cands = [good]
        for _ in range(rng.integers(0, max_distractors + 1)):
            off = rng.choice([-1, 1]) * rng.uniform(4, 9)
            frac = rng.uniform(0.3, 0.8)
            start = rng.uniform(0, 1 - frac)
            a = line[0] + d * start + n * off
            cands.append(np.stack([a, a + d * frac]) + rng.normal(scale=0.3, size=(2, 2)))
        order = rng.permutation(len(cands))
        candidates.append(np.array(cands)[order])
        true_index.append(int(np.argmin(order)))
    corners = np.concatenate([truth + rng.normal(scale=0.5, size=truth.shape),
                              rng.uniform(truth.min() - 30, truth.max() + 30, size=(clutter, 2))])
    return true_lines, refs, candidates, np.array(true_index), corners


def random_problem(rng: np.random.Generator, n_sides: int = 10, max_candidates: int = 4):
    """A random polygon-like problem (no truth needed) for GA vs exact."""
    angles = np.sort(rng.uniform(0, 2 * np.pi, n_sides))
    radius = rng.uniform(60, 120, n_sides)
    verts = np.column_stack([200 + radius * np.cos(angles), 200 + radius * np.sin(angles)])
    refs = ring_lines(verts)
    cands = []
    for line in refs:
        k = rng.integers(1, max_candidates + 1)
        jitter = rng.normal(scale=3.0, size=(k, 2, 2))
        cands.append(line[None] + jitter)
    corners = verts + rng.normal(scale=2.0, size=verts.shape)
    return refs, cands, ring_pairs(n_sides), corners
