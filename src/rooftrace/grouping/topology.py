"""Topology of a roof polyhedron's lines: outline sides, ridges, junctions, adjacency.

Seed 000 assumes that the projected LiDAR roof is topologically right and only
needs better geometry; the topology fixes (1) which lines are neighbours in
the MRF (eq. 7, 9, 11, 12: ``N_i`` is the set of candidates of the adjacent
sides and ridges) and (2) how the selected image lines are put back together
(§2.4: two lines meet at their intersection, three or more at a
least-squares point).

A *line* is one outline side (ring edge ``v_k -> v_{k+1}``) or one ridge.
A *junction* is a point where line ends meet.  Each member of a junction is a
``(line, end)`` pair, ``end`` in {0, 1}; ``end = -1`` marks a line that only
*passes through* the junction (a ridge ending on the interior of an outline
side, as at a gable): that line constrains the point but keeps its own ends.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.cluster.hierarchy import DisjointSet

from rooftrace.errors import GeometryError

__all__ = ["Junction", "RoofTopology", "roof_topology"]


@dataclass(frozen=True)
class Junction:
    """A point where lines meet.

    Attributes
    ----------
    members : tuple of (int, int)
        ``(line, end)``; ``end`` -1 for a line passing through (T-junction).
    point : ndarray of shape (3,)
        Object-space position in the input (LiDAR) roof.
    vertex : int
        Index of the outline vertex (over all rings, in ring order) or -1.
    """

    members: tuple[tuple[int, int], ...]
    point: np.ndarray
    vertex: int = -1


@dataclass(frozen=True)
class RoofTopology:
    """The lines of one roof and how they meet.

    Attributes
    ----------
    lines : ndarray of shape (M, 2, 3)
        Object-space end points, outline sides first (ring by ring, exterior
        first), then ridges.
    kinds : tuple of str
        ``'outline'`` or ``'ridge'`` per line.
    ring_sizes : tuple of int
        Number of sides (= vertices) of each outline ring.
    ridge_index : ndarray of shape (R,)
        Index of each kept input ridge in ``lines`` (-1 for a dropped,
        degenerate ridge).
    junctions : tuple of Junction
        Outline vertices first (same order as the ring vertices), then
        ridge-only junctions and free ridge ends.
    pairs : ndarray of shape (P, 2) int
        Adjacent lines ``i < j`` (they share a junction).
    """

    lines: np.ndarray
    kinds: tuple[str, ...]
    ring_sizes: tuple[int, ...]
    ridge_index: np.ndarray
    junctions: tuple[Junction, ...]
    pairs: np.ndarray

    @property
    def n_lines(self) -> int:
        return len(self.lines)

    @property
    def n_outline(self) -> int:
        return int(sum(self.ring_sizes))


def _ring_coords(ring) -> np.ndarray:
    """Vertices of a closed ring without the closing repeat, consecutive duplicates removed, (n, 3)."""
    xyz = shapely.get_coordinates(ring, include_z=True)
    if np.isnan(xyz[:, 2]).any():
        xyz[:, 2] = 0.0
    if len(xyz) > 1 and np.allclose(xyz[0], xyz[-1]):
        xyz = xyz[:-1]
    keep = np.ones(len(xyz), bool)
    keep[1:] = np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1) > 1e-9
    xyz = xyz[keep]
    if len(xyz) > 1 and np.linalg.norm(xyz[0, :2] - xyz[-1, :2]) <= 1e-9:
        xyz = xyz[:-1]
    return xyz


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planimetric distance from p (2,) to segments a-b (S, 2) and the parameter t in [0, 1]."""
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0, 1)
    return np.linalg.norm(a + t[:, None] * ab - p, axis=1), t


def roof_topology(outline, ridges=(), tolerance: float = 1.0) -> RoofTopology:
    """Build the line topology of one roof from its 3D outline and ridges.

    Parameters
    ----------
    outline : shapely Polygon (with z)
        Roof outline; every ring edge is a side. Z missing -> 0.
    ridges : sequence of shapely LineString (with z)
        Ridges of the roof (only their end points are used: a ridge is one
        straight line).
    tolerance : float, default 1.0
        Planimetric distance (m) under which a ridge end joins an outline
        vertex, another ridge end, or an outline side (T-junction).

    Returns
    -------
    RoofTopology

    Raises
    ------
    GeometryError
        An outline ring with fewer than 3 distinct vertices.

    Notes
    -----
    Ridge ends are first clustered (within ``tolerance``); a cluster then
    joins the nearest outline vertex within ``tolerance`` (hip roofs), else
    the nearest outline side (gables, T-junction), else it stays a ridge
    junction (where the main ridge meets the hips) or a free end.

    Examples
    --------
    >>> from shapely import Polygon, LineString
    >>> roof = Polygon([(0, 0, 3), (10, 0, 3), (10, 6, 3), (0, 6, 3)])
    >>> topo = roof_topology(roof, [LineString([(0, 3, 5), (10, 3, 5)])])
    >>> topo.kinds, topo.pairs.tolist()
    (('outline', 'outline', 'outline', 'outline', 'ridge'), [[0, 1], [0, 3], [1, 2], [1, 4], [2, 3], [3, 4]])
    """
    if outline is None or outline.is_empty or outline.geom_type != "Polygon":
        raise GeometryError("roof_topology needs one non-empty Polygon")
    rings = [_ring_coords(outline.exterior)] + [_ring_coords(r) for r in outline.interiors]
    rings = [r for i, r in enumerate(rings) if i == 0 or len(r) >= 3]
    if len(rings[0]) < 3:
        raise GeometryError("outline ring has fewer than 3 distinct vertices")
    lines: list[np.ndarray] = []
    junction_members: list[list[tuple[int, int]]] = []
    points: list[np.ndarray] = []
    vertex_ids: list[int] = []
    base = 0
    for ring in rings:
        n = len(ring)
        for k in range(n):
            lines.append(np.stack([ring[k], ring[(k + 1) % n]]))
        for k in range(n):
            junction_members.append([(base + (k - 1) % n, 1), (base + k, 0)])
            points.append(ring[k])
            vertex_ids.append(base + k)
        base += n
    n_outline = base
    vertices = np.concatenate(rings)
    seg_a = np.array([ln[0, :2] for ln in lines])
    seg_b = np.array([ln[1, :2] for ln in lines])

    ridge_index = np.full(len(ridges), -1, int)
    ends: list[tuple[int, int, np.ndarray]] = []
    for r, ridge in enumerate(ridges):
        if ridge is None or ridge.is_empty:
            continue
        xyz = shapely.get_coordinates(ridge, include_z=True)
        if np.isnan(xyz[:, 2]).any():
            xyz[:, 2] = 0.0
        seg = np.stack([xyz[0], xyz[-1]])
        if np.linalg.norm(seg[1, :2] - seg[0, :2]) < 1e-6:
            continue  # a vertical or point "ridge" has no image line
        ridge_index[r] = len(lines)
        lines.append(seg)
        ends += [(ridge_index[r], 0, seg[0]), (ridge_index[r], 1, seg[1])]

    # cluster ridge ends that meet (main ridge with hips)
    clusters = DisjointSet(range(len(ends)))
    for a in range(len(ends)):
        for b in range(a + 1, len(ends)):
            if ends[a][0] != ends[b][0] and np.linalg.norm(ends[a][2][:2] - ends[b][2][:2]) <= tolerance:
                clusters.merge(a, b)
    for group in clusters.subsets():
        group = sorted(group)
        members = [(ends[g][0], ends[g][1]) for g in group]
        centre = np.mean([ends[g][2] for g in group], axis=0)
        dv = np.linalg.norm(vertices[:, :2] - centre[:2], axis=1)
        if len(dv) and dv.min() <= tolerance:
            junction_members[int(np.argmin(dv))] += members
            continue
        ds, t = _point_segment(centre[:2], seg_a, seg_b)
        inner = (t > 0.02) & (t < 0.98)
        ds = np.where(inner, ds, np.inf)
        if np.isfinite(ds).any() and ds.min() <= tolerance:
            members.append((int(np.argmin(ds)), -1))
        junction_members.append(members)
        points.append(centre)
        vertex_ids.append(-1)

    junctions = tuple(Junction(tuple(m), np.asarray(p, float), v)
                      for m, p, v in zip(junction_members, points, vertex_ids))
    pairs = {(min(a, b), max(a, b)) for j in junctions for a, _ in j.members for b, _ in j.members if a != b}
    pairs_arr = np.array(sorted(pairs), int).reshape(-1, 2)
    return RoofTopology(np.array(lines, float).reshape(-1, 2, 3), tuple(["outline"] * n_outline
                        + ["ridge"] * (len(lines) - n_outline)), tuple(len(r) for r in rings),
                        ridge_index, junctions, pairs_arr)
