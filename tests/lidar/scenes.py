"""Small constructed LiDAR scenes with exact per-point truth for the detection tests."""

from __future__ import annotations

import numpy as np

GROUND, BUILDING, TREE, WIRE = 2, 6, 5, 1


def _ground_z(xy: np.ndarray, slope: float) -> np.ndarray:
    return 10.0 + slope * xy[:, 0]


def scene(
    rng: np.random.Generator,
    *,
    size: float = 60.0,
    density: float = 8.0,
    slope: float = 0.05,
    noise: float = 0.03,
    boxes: tuple = ((15.0, 15.0, 14.0, 10.0, 6.0),),
    courtyards: tuple = (),
    gables: tuple = (),
    trees: tuple = (),
    wire: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample a scene; returns ``xyz`` (N, 3) and the true class per point.

    boxes: (x0, y0, width, depth, height) flat roofs; courtyards: (x0, y0,
    outer, inner, height) square rings; gables: (x0, y0, width, depth,
    eave height, ridge height) with the ridge along x; trees: (cx, cy,
    crown radius, crown base, crown top).  Heights are above the local ground.
    """
    n = rng.poisson(density * size * size)
    xy = rng.uniform(0, size, (n, 2))
    g = _ground_z(xy, slope)
    z = g.copy()
    label = np.full(n, GROUND)
    for x0, y0, w, d, h in boxes:
        m = (xy[:, 0] >= x0) & (xy[:, 0] <= x0 + w) & (xy[:, 1] >= y0) & (xy[:, 1] <= y0 + d)
        # a flat roof on a slope: level at the ground height of its centre
        z[m] = 10.0 + slope * (x0 + w / 2) + h
        label[m] = BUILDING
    for x0, y0, outer, inner, h in courtyards:
        r = (xy - [x0 + outer / 2, y0 + outer / 2])
        m = (np.abs(r).max(axis=1) <= outer / 2) & (np.abs(r).max(axis=1) > inner / 2)
        z[m] = 10.0 + slope * (x0 + outer / 2) + h
        label[m] = BUILDING
    for x0, y0, w, d, eave, ridge in gables:
        m = (xy[:, 0] >= x0) & (xy[:, 0] <= x0 + w) & (xy[:, 1] >= y0) & (xy[:, 1] <= y0 + d)
        t = 1 - np.abs(xy[m, 1] - (y0 + d / 2)) / (d / 2)
        z[m] = 10.0 + slope * (x0 + w / 2) + eave + (ridge - eave) * t
        label[m] = BUILDING
    z = z + rng.normal(0, noise, n)
    parts_xyz = [np.column_stack([xy, z])]
    parts_lab = [label]
    for cx, cy, r, base, top in trees:
        # crowns are volumes: several returns per pulse, spread in height
        k = rng.poisson(density * np.pi * r * r * 2.5)
        u = rng.normal(size=(k, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        rad = r * rng.uniform(0, 1, k) ** (1 / 3)
        c = np.array([cx, cy, 0.0])
        p = c + u * rad[:, None] * [1, 1, (top - base) / (2 * r)]
        p[:, 2] += _ground_z(p[:, :2], slope) + (base + top) / 2
        parts_xyz.append(p)
        parts_lab.append(np.full(k, TREE))
        # the ground below the crown is still reached by last returns
    if wire:
        k = int(size * 2 * density ** 0.5)
        x = np.linspace(1, size - 1, k)
        p = np.column_stack([x, np.full(k, size - 5.0), _ground_z(np.column_stack([x, x]), slope) + 12.0])
        p += rng.normal(0, 0.02, p.shape)
        parts_xyz.append(p)
        parts_lab.append(np.full(k, WIRE))
    return np.concatenate(parts_xyz), np.concatenate(parts_lab)


def f1(pred: np.ndarray, truth: np.ndarray) -> float:
    tp = np.sum(pred & truth)
    return float(2 * tp / max(pred.sum() + truth.sum(), 1))
