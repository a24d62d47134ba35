"""The roof edge from the boundary points: beyond roof points by the sampling step, at wall points."""

import numpy as np
import pytest

from rooftrace.contour.edge import EdgeContext, edge_shift
from rooftrace.contour.outline import trace_outline

W, D, Z = 12.0, 8.0, 9.0  # a flat roof over a 12 m x 8 m box with flush walls (a parapet): edge = wall line


def _flat_box(seed: int, walls: bool, density: float = 12.0):
    """Random (Poisson) roof points, flush walls scanned from the side, and the ground beyond the scan shadow."""
    rng = np.random.default_rng(seed)
    n = rng.poisson(density * W * D)
    roof = np.column_stack([rng.uniform(0, W, n), rng.uniform(0, D, n), Z + rng.normal(0, 0.02, n)])
    wall = []
    if walls:
        for (x0, y0), (x1, y1) in (((0, 0), (W, 0)), ((W, 0), (W, D)), ((W, D), (0, D)), ((0, D), (0, 0))):
            m = int(1.5 * density * np.hypot(x1 - x0, y1 - y0) * 0.3)  # a strip of facade 0.3 m deep in plan
            t = rng.uniform(0, 1, m)
            wall.append(np.column_stack([x0 + t * (x1 - x0) + rng.normal(0, 0.03, m),
                                         y0 + t * (y1 - y0) + rng.normal(0, 0.03, m), rng.uniform(0.5, Z - 0.8, m)]))
    building = np.vstack([roof, *wall])
    g = rng.uniform([-6, -6], [W + 6, D + 6], (int(density * (W + 12) * (D + 12)), 2))
    # the ground in the walls' scan shadow (up to 0.6 m out) is not seen
    outside = (g[:, 0] < -0.6) | (g[:, 0] > W + 0.6) | (g[:, 1] < -0.6) | (g[:, 1] > D + 0.6)
    return building, g[outside]


def test_wall_points_on_the_boundary_are_the_edge():
    xy = np.column_stack([np.arange(0, 10, 0.5), np.zeros(20)])
    normal = np.array([0.0, -1.0])
    ground = xy - [0, 0.6]
    assert edge_shift(xy, np.zeros(20), normal, 0.5, EdgeContext(ground), fallback=0.4)[0] == pytest.approx(0.2)
    assert edge_shift(xy, np.zeros(20), normal, 0.5, EdgeContext(ground, walls=xy), fallback=0.4)[0] == 0.0
    # with no other point known, the wall points still say where the edge is
    assert edge_shift(xy, np.zeros(20), normal, 0.5, EdgeContext(None, walls=xy), fallback=0.4) == (0.0, False)
    # a minority of wall points does not move the median
    some = EdgeContext(ground, walls=xy[:5])
    assert edge_shift(xy, np.zeros(20), normal, 0.5, some, fallback=0.4)[0] == pytest.approx(0.2)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_flat_roof_with_flush_walls_has_no_outward_bias(seed):
    building, ground = _flat_box(seed, walls=True)
    outline = trace_outline(building, mean_spacing=1 / np.sqrt(12.0), context_xy=ground)
    bias = (outline.polygon.area - W * D) / (2 * (W + D))
    # the walls' plan scatter is 3 cm; half the sampling step (the shift beyond roof points) would be 6-12 cm
    assert abs(bias) < 0.04, bias
    assert outline.status == "ok"


def test_roof_without_walls_still_moves_out_by_the_sampling_step():
    biases = []
    for seed in (1, 2, 3):
        building, ground = _flat_box(seed, walls=False)
        outline = trace_outline(building, mean_spacing=1 / np.sqrt(12.0), context_xy=ground)
        biases.append((outline.polygon.area - W * D) / (2 * (W + D)))
    # the outermost random roof points lie inside the edge; the shift takes the outline back out to it
    assert abs(np.mean(biases)) < 0.05, biases
