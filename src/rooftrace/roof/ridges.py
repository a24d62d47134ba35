"""Ridge, hip and valley lines: intersections of adjacent roof planes.

For an adjacent pair of planes the 3D intersection line is exact; what the
points give is its extent.  The shared-boundary midpoints lying within
``line_tolerance`` of the line (in plan) are projected on it and their range
is the first extent.  Each end then snaps to the nearest of

- a *junction*: the point common to the pair's planes and a third plane
  adjacent to one of them (three planes meet in one point, so lines sharing a
  junction end exactly together), or
- the *outline*: where the line crosses the roof outline,

if one is within ``snap`` metres along the line, and the line is clipped to
the outline.

Kinds (the usual roof vocabulary):

- ``ridge``: convex meeting (the roof is the lower of the two planes) whose
  line is horizontal within ``ridge_max_slope``;
- ``hip``: convex meeting along an inclined line;
- ``valley``: concave meeting (the roof is the higher of the two planes).

Step edges (height jumps between roof levels) are not intersections; they
come from the faces (:func:`rooftrace.roof.faces.step_edges`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.spatial import cKDTree
from shapely.geometry import LineString

from rooftrace.roof.adjacency import Adjacency

__all__ = ["IntersectionLines", "intersect_planes", "triple_point", "intersection_lines"]

log = logging.getLogger(__name__)


@dataclass
class IntersectionLines:
    """Ridge, hip and valley lines of one roof.

    Attributes
    ----------
    lines : list of shapely LineString (3D, two vertices)
    kinds : list of str
    pairs : list of tuple of int
        The two planes of each line.
    convex : list of int
        +1 convex (ridge, hip), -1 concave (valley).
    """

    lines: list = field(default_factory=list)
    kinds: list = field(default_factory=list)
    pairs: list = field(default_factory=list)
    convex: list = field(default_factory=list)


def intersect_planes(pa: np.ndarray, pb: np.ndarray, near: np.ndarray | None = None, min_angle: float = 1.0):
    """Line common to two planes.

    Parameters
    ----------
    pa, pb : ndarray of shape (4,)
        Planes ``(a, b, c, d)``, unit normals.
    near : ndarray of shape (3,), optional
        The returned point is the line's point closest to this one.
    min_angle : float
        Planes closer than this (deg) in orientation are parallel: no line.

    Returns
    -------
    (point, direction) or None
        ``point`` (3,) on both planes; ``direction`` (3,) scaled so that its
        plan part has unit length (a parameter step of 1 is 1 m in plan).
        None for parallel planes or a vertical line.
    """
    na, nb = pa[:3], pb[:3]
    u = np.cross(na, nb)
    if np.linalg.norm(u) < np.sin(np.radians(min_angle)):
        return None
    uh = np.hypot(u[0], u[1])
    if uh < 1e-9:
        return None
    u = u / uh
    A = np.stack([na, nb])
    rhs = -np.array([pa[3], pb[3]])
    c = np.zeros(3) if near is None else np.asarray(near, dtype=float)
    # Least-norm correction from ``near`` onto both planes.
    x = c + A.T @ np.linalg.solve(A @ A.T, rhs - A @ c)
    return x, u


def triple_point(pa: np.ndarray, pb: np.ndarray, pc: np.ndarray, min_det: float = 1e-3):
    """Point common to three planes, or None when they do not meet in one point."""
    A = np.stack([pa[:3], pb[:3], pc[:3]])
    if abs(np.linalg.det(A)) < min_det:
        return None
    return np.linalg.solve(A, -np.array([pa[3], pb[3], pc[3]]))


def _inside_intervals(outline, spans: list) -> list:
    """Parameter intervals inside the outline of each plan line ``x0 + t u``, ``spans`` of ``(x0, u, t0, t1)``.

    Each line is tried from ``t0 - 1`` to ``t1 + 1``; the lines are cut by
    the outline in one call.
    """
    out = [[] for _ in spans]
    if not spans:
        return out
    ends = np.array([[x0[:2] + (t0 - 1.0) * u[:2], x0[:2] + (t1 + 1.0) * u[:2]] for x0, u, t0, t1 in spans])
    parts, of = shapely.get_parts(shapely.intersection(shapely.linestrings(ends), outline), return_index=True)
    keep = (np.isin(shapely.get_type_id(parts), (1, 2)) & ~shapely.is_empty(parts))
    keep[keep] = shapely.length(parts[keep]) > 0
    for g, k in zip(parts[keep], of[keep]):
        x0, u = spans[k][0], spans[k][1]
        t = (np.asarray(g.coords)[:, :2] - x0[:2]) @ u[:2]
        out[k].append((t.min(), t.max()))
    return out


def _supported_runs(tree, lab, lines: list, tol: float) -> list:
    """Stretch of ``[t0, t1]`` of each line ``(a, b, x0, u, t0, t1)`` with
    plane ``a`` on one side of the line and ``b`` on the other (nearest
    labelled points at ``tol / 2``).

    From the first to the last supported sample when at least half of that
    stretch is supported, else the longest run (gaps up to ``tol / 2``
    bridged); None when no sample is supported.  The samples of all lines
    are looked up in one query.
    """
    step = tol / 4
    samples, offsets = [], []
    for _, _, x0, u, t0, t1 in lines:
        ts = np.arange(t0, t1 + step / 2, step) if t1 > t0 else np.array([t0])
        side = np.array([-u[1], u[0]]) * (tol / 2)
        pts = x0[:2] + ts[:, None] * u[:2]
        samples.append(ts)
        offsets.append((pts + side, pts - side))
    if not lines:
        return []
    _, il = tree.query(np.concatenate([o[0] for o in offsets]))
    _, ir = tree.query(np.concatenate([o[1] for o in offsets]))
    cut = np.cumsum([len(ts) for ts in samples])[:-1]
    runs = []
    for (a, b, *_), ts, ll, lr in zip(lines, samples, np.split(lab[il], cut), np.split(lab[ir], cut)):
        ok = ((ll == a) & (lr == b)) | ((ll == b) & (lr == a))
        if not ok.any():
            runs.append(None)
            continue
        idx = np.flatnonzero(ok)
        # Trim the unsupported ends; if the rest is mostly supported keep it
        # whole (a dormer next to a ridge breaks the support locally) ...
        if ok[idx[0] : idx[-1] + 1].mean() >= 0.5:
            runs.append((float(ts[idx[0]]), float(ts[idx[-1]])))
            continue
        # ... else the longest run, splitting where supported samples are more
        # than 2 steps apart.
        breaks = np.flatnonzero(np.diff(idx) > 2)
        starts = np.r_[idx[0], idx[breaks + 1]]
        ends = np.r_[idx[breaks], idx[-1]]
        k = int(np.argmax(ends - starts))
        runs.append((float(ts[starts[k]]), float(ts[ends[k]])))
    return runs


def intersection_lines(
    planes: np.ndarray,
    adj: Adjacency,
    outline,
    *,
    line_tolerance: float,
    snap: float,
    ridge_max_slope: float = 5.0,
    min_length: float = 1.0,
    xyz: np.ndarray | None = None,
    labels: np.ndarray | None = None,
) -> IntersectionLines:
    """Ridge, hip and valley lines of adjacent plane pairs.

    Parameters
    ----------
    planes : ndarray of shape (K, 4)
    adj : Adjacency
    outline : shapely Polygon
        Roof outline in plan (Z ignored).
    line_tolerance : float
        Largest plan distance (m) of a shared-boundary midpoint from the
        intersection line for it to belong to the line.
    snap : float
        Largest move (m, along the line) of an end to a junction or the outline.
    ridge_max_slope : float
        Convex lines flatter than this (deg) are ridges, steeper ones hips.
    min_length : float
        Shorter lines (m, in plan) are dropped.
    xyz, labels : ndarray of shape (N, 3) and (N,), optional
        The labelled points.  When given, the line is first trimmed to its
        longest stretch where the nearest points at ``line_tolerance / 2`` on
        its two sides belong to its two planes (before snapping); this rejects
        lines between planes that only touch at a junction and stops lines
        where a dormer's top turns into its cheeks.
    """
    out = IntersectionLines()
    outline = shapely.force_2d(outline)
    K = len(planes)
    # Which planes take part in some intersection, for the junctions.
    lines = []
    for (a, b), mids in zip(adj.pairs, adj.midpoints):
        c2 = mids.mean(axis=0)
        near = np.array([c2[0], c2[1], -(planes[a, 0] * c2[0] + planes[a, 1] * c2[1] + planes[a, 3]) / planes[a, 2]])
        res = intersect_planes(planes[a], planes[b], near)
        if res is None:
            continue
        x0, u = res
        off = mids - x0[:2]
        t = off @ u[:2]
        perp = np.abs(off[:, 0] * u[1] - off[:, 1] * u[0])
        on = perp <= line_tolerance
        if on.sum() < 3:
            continue
        t0, t1 = t[on].min(), t[on].max()
        if t1 - t0 < min_length / 2:
            continue
        lines.append([a, b, x0, u, t0, t1])
    neighbours = [set() for _ in range(K)]
    for a, b, *_ in lines:
        neighbours[a].add(b)
        neighbours[b].add(a)
    conv = {(int(a), int(b)): c for (a, b), c in zip(adj.pairs, adj.convexity)}
    on_outline = []
    tree = None
    if xyz is not None and labels is not None and (labels >= 0).any():
        sel = labels >= 0
        tree, lab = cKDTree(np.asarray(xyz)[sel, :2]), np.asarray(labels)[sel]
    if tree is not None:
        kept = []
        for (a, b, x0, u, _, _), run in zip(lines, _supported_runs(tree, lab, lines, line_tolerance)):
            if run is None or run[1] - run[0] < min_length / 2:
                log.debug("line %d-%d rejected: planes not on both sides", a, b)
                continue
            kept.append([a, b, x0, u, *run])
        lines = kept
    inside = _inside_intervals(outline, [(x0, u, t0 - snap, t1 + snap) for _, _, x0, u, t0, t1 in lines])
    for (a, b, x0, u, t0, t1), intervals in zip(lines, inside):
        cands = []
        for c in (neighbours[a] | neighbours[b]) - {a, b}:
            p = triple_point(planes[a], planes[b], planes[c])
            if p is not None and np.all(np.isfinite(p)):
                cands.append((p[:2] - x0[:2]) @ u[:2])
        for lo, hi in intervals:
            cands.extend([lo, hi])
        cands = np.asarray(cands)
        # An end never snaps past the middle of the line (no flips).
        mid = (t0 + t1) / 2
        lo_c, hi_c = cands[cands < mid], cands[cands > mid]
        if len(lo_c) and np.abs(lo_c - t0).min() <= snap:
            t0 = lo_c[np.argmin(np.abs(lo_c - t0))]
        if len(hi_c) and np.abs(hi_c - t1).min() <= snap:
            t1 = hi_c[np.argmin(np.abs(hi_c - t1))]
        # Clip to the outline: one line per inside piece (a ridge crossing a
        # courtyard is two lines).
        cv = 1 if conv[(int(a), int(b))] > 0 else -1
        incline = np.degrees(np.arctan(abs(u[2])))  # |u_xy| = 1
        kind = "valley" if cv < 0 else ("ridge" if incline <= ridge_max_slope else "hip")
        for lo, hi in intervals:
            s0, s1 = max(lo, t0), min(hi, t1)
            if s1 - s0 < min_length:
                continue
            out.lines.append(LineString([x0 + s0 * u, x0 + s1 * u]))
            out.kinds.append(kind)
            out.pairs.append((int(a), int(b)))
            out.convex.append(cv)
            on_outline.append((abs(s0 - lo) < 1e-9, abs(s1 - hi) < 1e-9))
    _merge_junctions(out, planes, on_outline, line_tolerance / 2)
    log.debug("%d intersection lines from %d adjacent pairs", len(out.lines), len(adj))
    return out


def _merge_junctions(out: IntersectionLines, planes: np.ndarray, on_outline: list, tol: float) -> None:
    """Make line ends that meet inside the roof one point.

    Ends within ``tol`` (m, plan) of each other and not on the outline form a
    junction; with three or more planes involved it becomes their
    least-squares point (the exact common point of three planes).  Lines
    meeting at four planes (the centre of an L-shaped hip roof) then share
    one end instead of ends a few centimetres apart.
    """
    if len(out.lines) < 2:
        return
    from rooftrace.graph import components

    ends = np.array([np.asarray(g.coords)[[0, -1]] for g in out.lines]).reshape(-1, 3)
    free = ~np.asarray(on_outline, dtype=bool).ravel()
    idx = np.flatnonzero(free)
    if len(idx) < 2:
        return
    ij = cKDTree(ends[idx, :2]).query_pairs(tol, output_type="ndarray")
    if len(ij) == 0:
        return
    n = len(idx)
    comp = components(n, ij)
    coords = ends.copy()
    for c in np.unique(comp):
        members = idx[comp == c]
        if len(members) < 2:
            continue
        pl = sorted({k for m in members for k in out.pairs[m // 2]})
        if len(pl) < 3:
            continue
        A = planes[pl, :3]
        x, *_ = np.linalg.lstsq(A, -planes[pl, 3], rcond=None)
        if np.linalg.norm(x[:2] - ends[members, :2].mean(axis=0)) > tol:
            continue
        coords[members] = x
    coords = coords.reshape(-1, 2, 3)
    out.lines = [LineString(c) for c in coords]
