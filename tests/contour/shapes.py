"""Point samples of known roof shapes (exact truth) for the contour tests."""

from __future__ import annotations

import numpy as np
import shapely

RECT = shapely.box(0, 0, 20, 12)
L_SHAPE = shapely.Polygon([(0, 0), (20, 0), (20, 6), (10, 6), (10, 12), (0, 12)])
COURTYARD = shapely.box(0, 0, 20, 16).difference(shapely.box(5, 5, 13, 11))
CIRCLE = shapely.Point(0, 0).buffer(8, quad_segs=128)
STADIUM = shapely.box(0, 0, 14, 10).union(shapely.Point(14, 5).buffer(5, quad_segs=128))


def sample(polygon, density: float = 10.0, seed: int = 0, jitter: float = 0.25, z: float = 10.0,
           density_right: float | None = None) -> np.ndarray:
    """Jittered-grid points inside ``polygon``, ``density`` pts/m² (``density_right`` right of the centre)."""
    rng = np.random.default_rng(seed)
    parts = []
    x0, y0, x1, y1 = polygon.bounds
    xm = 0.5 * (x0 + x1)
    for dens, (a, b) in ((density, (x0, xm if density_right else x1)), (density_right, (xm, x1))):
        if not dens:
            continue
        s = 1 / np.sqrt(dens)
        g = np.mgrid[a:b:s, y0 - 1:y1 + 1:s].reshape(2, -1).T + rng.uniform(0, s, (1, 2))
        g = g + rng.uniform(-jitter * s, jitter * s, g.shape)
        g = g[(g[:, 0] >= a) & (g[:, 0] < b)]
        parts.append(g[shapely.contains_xy(polygon, g[:, 0], g[:, 1])])
    xy = np.concatenate(parts)
    return np.column_stack([xy, z + 0.05 * rng.normal(size=len(xy))])


def courtyard_blocks(n_side: int = 1, size: float = 80.0, wing: float = 12.0, street: float = 10.0) -> shapely.Polygon:
    """``n_side`` × ``n_side`` square blocks around courtyards, joined across the streets by 3 m wide passages."""
    parts = []
    for i in range(n_side):
        for j in range(n_side):
            x, y = i * (size + street), j * (size + street)
            parts.append(shapely.box(x, y, x + size, y + size).difference(
                shapely.box(x + wing, y + wing, x + size - wing, y + size - wing)))
            if i:
                parts.append(shapely.box(x - street - 1, y + size / 2, x + 1, y + size / 2 + 3))
            if j:
                parts.append(shapely.box(x + size / 2, y - street - 1, x + size / 2 + 3, y + 1))
    return shapely.union_all(parts)


def sample_random(polygon, density: float = 3.0, seed: int = 0, z: float = 10.0) -> np.ndarray:
    """Uniformly random (Poisson) points inside ``polygon``: irregular sampling, as where AHN strips overlap."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array(polygon.bounds[:2]), np.array(polygon.bounds[2:])
    xy = rng.uniform(lo, hi, (rng.poisson(density * np.prod(hi - lo)), 2))
    xy = xy[shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])]
    return np.column_stack([xy, z + 0.05 * rng.normal(size=len(xy))])
