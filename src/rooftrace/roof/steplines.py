"""Step boundaries placed by the points: a fitted line between two roof levels instead of the raster's staircase.

Where two faces whose planes differ by more than ``step_height`` share a
boundary (a height step: a wall stands there), the face partition draws
that boundary from a raster of half the point spacing, refined where a cell
holds points of both levels, simplified only where no point crosses it; an
edge row of the upper level still falls a cell or two under the lower face
where the levels' points lie closer than a cell.  Here each such boundary
is cut into straight runs, and each run is replaced by the line that
separates the two levels' labelled points near it best
(:func:`separating_line`: the least misfit, each point weighted by the
height error it would get on the wrong side; of the lines with the least
misfit the one with the widest margin).  The runs' lines are joined at
their crossings; the ends stay on the boundary's nodes, so the other faces
are untouched.  The lens between the old boundary and the new one changes
level; the new faces are kept only where the boundary moves no labelled
point from under a face that fits it (within ``max_dz``) to under one that
does not (where the two levels' points interleave so that no line
separates them the raster's boundary stays: mended points do not buy
misplaced ones), and only where both faces stay one polygon without new
holes, on the centimetre lattice of the models too.  A lower level's
return under the upper level's eave (:func:`rooftrace.roof.faces.hidden_under`)
takes no part: no 2.5D roof can put it under its own plane.
"""

from __future__ import annotations

import logging

import numpy as np
import shapely
from numba import njit
from scipy.spatial import cKDTree

from rooftrace.roof.faces import attached_points, eaves, hidden_under, points_in_faces
from rooftrace.roof.planes import plane_height

__all__ = ["separating_line", "fit_step_boundaries"]

log = logging.getLogger(__name__)


def separating_line(xy_upper: np.ndarray, xy_lower: np.ndarray, w_upper: np.ndarray | None = None,
                    w_lower: np.ndarray | None = None, *, normal: np.ndarray | None = None, spread: float = 20.0,
                    step: float = 2.0) -> tuple[np.ndarray, float, float, float]:
    """The line that separates two point sets in plan with the least weighted misfit, and the widest margin.

    For each direction of the line's normal (within ``spread`` degrees of
    ``normal``, every ``step`` degrees, then refined to a tenth of that
    around the best) the points are projected on the normal; there the
    best threshold is a 1-D problem, solved exactly by a sort and two
    cumulative sums: the misfit of a threshold is the weight of the upper
    points beyond it plus that of the lower points before it.  Of the
    thresholds with the least misfit, the middle of the widest gap between
    consecutive projections is taken.

    Parameters
    ----------
    xy_upper, xy_lower : ndarray of shape (N, 2), (M, 2)
        Plan positions (m) of the points that should lie on either side.
    w_upper, w_lower : ndarray, optional
        Weight of each point on the wrong side (e.g. the height error it
        would get, m); default 1.
    normal : ndarray of shape (2,), optional
        Expected direction from the upper side to the lower; default: from
        the upper points' mean to the lower points'.
    spread : float
        Largest angle (degrees) between the line's normal and ``normal``.
    step : float
        Angle step (degrees) of the coarse search.

    Returns
    -------
    normal : ndarray of shape (2,)
        Unit normal ``n`` of the line ``{p : p · n = c}``; the upper side has ``p · n < c``.
    c : float
        Offset (m).
    misfit : float
        Weight of the points on the wrong side.
    margin : float
        Half the gap (m) between the nearest projections on either side of the line.

    Examples
    --------
    >>> up = np.array([[0.0, 0.0], [0.0, 1.0], [0.9, 0.5]])
    >>> lo = np.array([[2.0, 0.0], [2.0, 1.0], [1.1, 0.5]])
    >>> n, c, misfit, margin = separating_line(up, lo)
    >>> (np.round(n, 3) + 0.0).tolist(), round(c, 3), misfit, round(margin, 3)
    ([1.0, 0.0], 1.0, 0.0, 0.1)
    """
    up = np.asarray(xy_upper, dtype=np.float64).reshape(-1, 2)
    lo = np.asarray(xy_lower, dtype=np.float64).reshape(-1, 2)
    if not len(up) or not len(lo):
        raise ValueError("both sides need points")
    wu = np.ones(len(up)) if w_upper is None else np.asarray(w_upper, dtype=np.float64)
    wl = np.ones(len(lo)) if w_lower is None else np.asarray(w_lower, dtype=np.float64)
    if normal is None:
        normal = lo.mean(axis=0) - up.mean(axis=0)
    base = float(np.arctan2(normal[1], normal[0]))
    centre = np.concatenate([up, lo]).mean(axis=0)  # projections about the centre: no cancellation far from 0
    xy = np.concatenate([up, lo]) - centre
    w = np.concatenate([wu, wl])
    is_lo = np.r_[np.zeros(len(up), bool), np.ones(len(lo), bool)]

    def best(angles: np.ndarray):
        n = np.column_stack([np.cos(angles), np.sin(angles)])
        a, cost, lo_t, hi_t, gap = _least_misfit_cut(n @ xy.T, is_lo, w)
        return angles[a], cost, 0.5 * (lo_t + hi_t), 0.5 * gap

    coarse = base + np.radians(np.arange(-spread, spread + step / 2, step))
    theta, _, _, _ = best(coarse)
    fine = theta + np.radians(np.arange(-step, step + step / 20, step / 10))
    theta, misfit, c, margin = best(fine)
    n = np.array([np.cos(theta), np.sin(theta)])
    return n, float(c + n @ centre), misfit, margin


@njit(cache=True)
def _least_misfit_cut(t, is_lo, w):  # pragma: no cover - compiled
    """The cut of the least misfit over the rows of projections ``t`` (A directions, N points), of those the widest.

    Per row the points sorted by projection (stably); the misfit of the cut
    before sorted position i (0 .. N) is the weight of the lower points
    (``is_lo``) before it plus that of the upper points from it on; the gap
    it sits in is the difference of its two neighbouring projections (none
    for an outer cut: it does not separate).  Of the cuts whose misfit is
    within 1e-9 of the least over all rows, the first (row by row) with the
    widest gap is taken.  Returns its row, misfit, the projections either
    side of it (one unit beyond the last point for an outer cut) and its gap.
    """
    n_dir, n = t.shape
    ts = np.empty((n_dir, n))
    cost = np.empty((n_dir, n + 1))
    gap = np.zeros((n_dir, n + 1))
    least = np.inf
    for a in range(n_dir):
        order = np.argsort(t[a], kind="mergesort")
        for k in range(n):
            ts[a, k] = t[a, order[k]]
        # sums in the order of cumulative sums: from the first point for the lower weights, from the last for the
        # upper ones
        acc = 0.0
        cost[a, 0] = 0.0
        for k in range(n):
            if is_lo[order[k]]:
                acc = acc + w[order[k]]
            cost[a, k + 1] = acc
        acc = 0.0
        for k in range(n - 1, -1, -1):
            if not is_lo[order[k]]:
                acc = acc + w[order[k]]
            cost[a, k] = cost[a, k] + acc
        for k in range(1, n):
            gap[a, k] = ts[a, k] - ts[a, k - 1]
        for k in range(n + 1):
            if cost[a, k] < least:
                least = cost[a, k]
    best_a, best_i, score = 0, 0, -np.inf
    for a in range(n_dir):
        for k in range(n + 1):
            sc = gap[a, k] if cost[a, k] <= least + 1e-9 else -1.0
            if sc > score:
                best_a, best_i, score = a, k, sc
    lo_t = ts[best_a, best_i - 1] if best_i > 0 else ts[best_a, 0] - 1.0
    hi_t = ts[best_a, best_i] if best_i < n else ts[best_a, n - 1] + 1.0
    return best_a, cost[best_a, best_i], lo_t, hi_t, gap[best_a, best_i]


def _in_box(xy: np.ndarray, bounds, pad: float = 0.0) -> np.ndarray:
    """Indices of the points ``xy`` in the box ``bounds`` grown by ``pad`` (m)."""
    x0, y0, x1, y1 = bounds
    return np.flatnonzero((xy[:, 0] >= x0 - pad) & (xy[:, 0] <= x1 + pad) & (xy[:, 1] >= y0 - pad)
                          & (xy[:, 1] <= y1 + pad))


def _one_piece(g, before) -> bool:
    """Whether ``g`` is one polygon with no more holes than ``before``, also on the models' centimetre lattice."""
    if shapely.get_type_id(g) != 3 or g.is_empty or not g.is_valid:
        return False
    coarse = shapely.set_precision(g, 0.01)
    holes = shapely.get_num_interior_rings(before)
    return (shapely.get_num_geometries(coarse) == 1 and shapely.get_type_id(coarse) == 3
            and shapely.get_num_interior_rings(g) <= holes and shapely.get_num_interior_rings(coarse) <= holes)


def _polygonal(g):
    """The polygonal part of ``g`` (an overlay of faces that touch also gives their shared lines)."""
    parts = shapely.get_parts(g)
    parts = parts[(shapely.get_type_id(parts) == 3) & (shapely.area(parts) > 0)]
    return shapely.union_all(parts) if len(parts) else shapely.Polygon()


def _crossing(n1, c1, n2, c2):
    """The crossing of the lines ``p · n1 = c1`` and ``p · n2 = c2`` (None when nearly parallel)."""
    det = n1[0] * n2[1] - n1[1] * n2[0]
    if abs(det) < np.sin(np.radians(10.0)):
        return None
    return np.array([(c1 * n2[1] - c2 * n1[1]) / det, (n1[0] * c2 - n2[0] * c1) / det])


def _in_band(xy: np.ndarray, a: np.ndarray, u: np.ndarray, length: float, band: float) -> np.ndarray:
    """Which of ``xy`` lie within ``band`` of the run from ``a`` along ``u`` (``length`` m, ends widened by band / 2)."""
    r = xy - a
    t, off = r @ u, r @ np.array([-u[1], u[0]])
    return (t >= -band / 2) & (t <= length + band / 2) & (np.abs(off) <= band)


def _foot(p, n, c):
    """The foot of point ``p`` on the line ``x · n = c``."""
    return p - (p @ n - c) * n


def _new_boundary(piece, up_xy, lo_xy, w_up, w_lo, *, band: float, run_tolerance: float):
    """The fitted boundary (vertices, (V, 2)) that replaces ``piece`` between its two ends (None: none).

    ``piece`` is cut into straight runs (Douglas-Peucker at
    ``run_tolerance``); each run with points of both levels within ``band``
    gets its :func:`separating_line`, a run without keeps its chord.  The
    lines are joined at their crossings (near-parallel lines through the
    feet of the run's shared vertex) and the boundary's ends stay where
    they are, joined to the first and last line by their feet.
    """
    v = shapely.get_coordinates(shapely.simplify(piece, run_tolerance))
    if len(v) < 2:
        return None
    lines = []
    for a, b in zip(v[:-1], v[1:]):
        d = b - a
        length = float(np.hypot(*d))
        if length < 1e-9:
            continue
        u = d / length
        nrm = np.array([-u[1], u[0]])
        mu = _in_band(up_xy, a, u, length, band)
        ml = _in_band(lo_xy, a, u, length, band)
        if mu.any() and ml.any():
            # the run's normal pointing from the upper level's side to the lower's
            hint = nrm if (lo_xy[ml] - a).mean(axis=0) @ nrm >= (up_xy[mu] - a).mean(axis=0) @ nrm else -nrm
            n, c, _, _ = separating_line(up_xy[mu], lo_xy[ml], w_up[mu], w_lo[ml], normal=hint)
            lines.append((n, c))
        else:
            lines.append((nrm, float(nrm @ a)))
    if not lines:
        return None
    pts = [v[0], _foot(v[0], *lines[0])]
    for k in range(len(lines) - 1):
        x = _crossing(*lines[k], *lines[k + 1])
        joint = v[k + 1]
        if x is not None and np.hypot(*(x - joint)) <= band:
            pts.append(x)
        else:
            pts.extend([_foot(joint, *lines[k]), _foot(joint, *lines[k + 1])])
    pts.extend([_foot(v[-1], *lines[-1]), v[-1]])
    pts = np.asarray(pts)
    keep = np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-6]
    return pts[keep]


def fit_step_boundaries(polys: list, plane_ids: list, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
                        step_height: float, band: float, run_tolerance: float, hidden_within: float = 0.0,
                        rise: float | None = None, overhanging: np.ndarray | None = None,
                        max_dz: float = 0.1) -> tuple[list, list]:
    """Faces whose height steps run along lines fitted to the two levels' points.

    Every boundary shared by two faces whose planes are more than
    ``step_height`` (m) apart all along it is replaced, between its two
    ends, by lines separating the upper level's labelled points within
    ``band`` (m) of it from the lower level's (:func:`separating_line`,
    each point weighted by the height difference of the two planes there).
    The region between the old and the new boundary changes level.

    What it guarantees, on any data: the faces still tile what they tiled,
    in the same number and order, each one polygon with no new hole (also
    on the models' centimetre lattice); no boundary but the step boundaries
    moves (their ends, where a third face or the outline meets them, stay);
    and a new boundary is kept only when it moves no labelled point (nor a
    point on no plane standing on one, with ``rise``) that lay under a face
    within ``max_dz`` (m) of its own plane to under one that is not, and
    mends at least one or has fewer vertices.  Where the two levels'
    points interleave so that no line separates them, the least-misfit
    line would misplace some: the raster's boundary then stays (and
    :func:`rooftrace.roof.faces.claim_points` takes what it can).

    Parameters
    ----------
    polys : list of shapely Polygon
        Faces (2D) tiling the roof outline.
    plane_ids : list of int
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` on none (those take no part).
    planes : ndarray of shape (K, 4)
    step_height : float
        Smallest height difference (m) of the two planes along a boundary that makes it a step.
    band : float
        Points within this plan distance (m) of a straight run of the boundary decide its line.
    run_tolerance : float
        Douglas-Peucker tolerance (m) that cuts a boundary into straight runs.
    hidden_within : float
        A point of the lower level with a point of the upper level within
        this plan distance (m) standing more than ``step_height`` higher is
        hidden from above (:func:`hidden_under`: a return under the upper
        level's eave) and takes no part, neither in the fit nor in the count
        (not under a plane steeper than :data:`rooftrace.roof.faces.EAVES_SLOPE`:
        a wall has no eave; nor under one not ``overhanging``).
    overhanging : ndarray of shape (K,), bool, optional
        The planes whose points may hide a lower level's (default: all).
    rise : float or None
        A point on no plane takes part as a point of the plane it stands on,
        at most ``rise`` (m) above it (as in
        :func:`rooftrace.roof.faces.partition_outline`); None: only labelled points.
    max_dz : float
        Height difference (m) between two planes at a point under which either is its own.

    Returns
    -------
    polygons : list of shapely Polygon
    plane_ids : list of int

    Examples
    --------
    >>> import shapely
    >>> planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])  # upper level 8 m, lower 5 m
    >>> left = shapely.Polygon([(0, 0), (4, 0), (4, 1), (4.5, 1), (4.5, 3), (4, 3), (4, 4), (0, 4)])  # a staircase
    >>> faces = [left, shapely.box(0, 0, 8, 4).difference(left)]
    >>> x = np.repeat([3.7, 3.9, 4.1, 4.3], 8)  # the upper level up to x = 3.9, the lower from 4.1
    >>> xyz = np.column_stack([x, np.tile(np.arange(0.25, 4, 0.5), 4), np.where(x < 4, 8.0, 5.0)])
    >>> labels = np.where(x < 4, 0, 1)
    >>> polys, ids = fit_step_boundaries(faces, [0, 1], xyz, labels, planes, step_height=0.5, band=1.0,
    ...                                  run_tolerance=0.5)
    >>> [round(p.area, 6) for p in polys], ids
    ([16.0, 16.0], [0, 1])
    """
    faces = list(polys)
    pids = np.asarray(plane_ids, dtype=np.int64)
    if len(faces) < 2:
        return faces, list(plane_ids)
    labels = np.asarray(labels)
    sel = labels >= 0
    P, lab = np.asarray(xyz, dtype=np.float64)[sel], labels[sel]
    if not len(P):
        return faces, list(plane_ids)
    if rise is not None and (~sel).any():
        # the points on no plane that stand on one (a coping, a gutter) count as its points, as in the partition
        extra, on = attached_points(np.asarray(xyz, dtype=np.float64)[~sel], P, lab, planes, 8, max_dz, rise)
        P, lab = np.vstack([P, extra]), np.concatenate([lab, on])
    roofish = eaves(planes) if overhanging is None else eaves(planes) & np.asarray(overhanging, dtype=bool)
    xy = P[:, :2]
    tree = cKDTree(xy)
    own_z = plane_height(planes[lab], xy)
    arr = np.asarray(faces, dtype=object)
    # (face, plane) of every labelled point under a face more than max_dz off its plane: only a pair of faces
    # one of which holds a point of the other's plane can gain
    at, f = points_in_faces(arr, xy)
    off = np.abs(plane_height(planes[pids[f]], xy[at]) - own_z[at]) > max_dz
    wrong_in = set(zip(f[off].tolist(), lab[at[off]].tolist()))
    changed: set[int] = set()
    i, j = shapely.STRtree(arr).query(arr, predicate="intersects")
    keep = (i < j) & (pids[i] != pids[j])
    for fi, fj in zip(i[keep].tolist(), j[keep].tolist()):
        A, B = faces[fi], faces[fj]
        a, b = int(pids[fi]), int(pids[fj])
        if (fj, a) not in wrong_in and (fi, b) not in wrong_in and fi not in changed and fj not in changed:
            continue
        shared = shapely.line_merge(shapely.intersection(A.boundary, B.boundary))
        for piece in shapely.get_parts(shared):
            if shapely.get_type_id(piece) != 1 or piece.length < band:
                continue
            dense = shapely.get_coordinates(shapely.segmentize(piece, band / 4))
            dz = plane_height(planes[None, [a, b]], dense[:, None, :])
            if not (np.abs(dz[:, 0] - dz[:, 1]) > step_height).all():
                continue  # a crease along part of it (a dormer's cheek), or no step at all
            up, lo = (a, b) if np.median(dz[:, 0] - dz[:, 1]) > 0 else (b, a)
            near = _in_box(xy, piece.bounds, band)
            near = near[(lab[near] == up) | (lab[near] == lo)]
            in_a = shapely.contains_xy(A, xy[near, 0], xy[near, 1])
            mine = in_a | shapely.contains_xy(B, xy[near, 0], xy[near, 1])
            near, in_a = near[mine], in_a[mine]
            # only a boundary with a point of either level on the wrong side is redrawn (the arc simplification
            # already straightened the others as far as the points allow)
            wrong = (lab[near] == a) != in_a
            if not wrong.any():
                continue
            # the lower level's returns under the upper level's eave take no part
            hide = hidden_within if roofish[up] else 0.0
            if hide > 0:
                low = np.flatnonzero(lab[near] == lo)
                under = np.zeros(len(near), dtype=bool)
                under[low] = hidden_under(P, lab, near[low], up, hide, step_height, tree)
                near, wrong = near[~under], wrong[~under]
                if not wrong.any():
                    continue
            zu, zl = plane_height(planes[None, [up, lo]], xy[near][:, None, :]).T
            w = np.abs(zu - zl)
            is_up = lab[near] == up
            new = _new_boundary(piece, xy[near][is_up], xy[near][~is_up], w[is_up], w[~is_up], band=band,
                                   run_tolerance=run_tolerance)
            if new is None:
                continue
            line = shapely.LineString(new)
            if not line.is_simple or shapely.equals(line, piece) or shapely.hausdorff_distance(line, piece) > band:
                log.debug("step %d|%d: fitted line not simple or off the band", a, b)
                continue
            lens = shapely.union_all(shapely.polygonize(shapely.get_parts(shapely.union(piece, line))).geoms)
            if lens.is_empty or lens.area <= 0:
                continue
            # the labelled points whose face changes (in the lens), before and after; tested before the faces are
            # cut (a boundary that misplaces a point is refused whatever the faces would be)
            cand = _in_box(xy, lens.bounds)
            cand = cand[shapely.contains_xy(lens, xy[cand, 0], xy[cand, 1])]
            cand = cand[~((lab[cand] == lo) & hidden_under(P, lab, cand, up, hide, step_height, tree))]
            in_a = shapely.contains_xy(A, xy[cand, 0], xy[cand, 1])
            mine = in_a | shapely.contains_xy(B, xy[cand, 0], xy[cand, 1])  # a third face's part of the lens stays
            cand, in_a = cand[mine], in_a[mine]
            z_a, z_b = plane_height(planes[None, [a, b]], xy[cand][:, None, :]).T
            before = np.where(in_a, z_a, z_b)
            after = np.where(in_a, z_b, z_a)
            fit_before = np.abs(before - own_z[cand]) <= max_dz
            fit_after = np.abs(after - own_z[cand]) <= max_dz
            mended, misplaced = fit_after & ~fit_before, fit_before & ~fit_after
            # mended points do not buy misplaced ones: where the levels interleave the raster's boundary stays
            if misplaced.any():
                log.debug("step %d|%d: kept (%d points mended, %d misplaced)", a, b, mended.sum(), misplaced.sum())
                continue
            gain_a, gain_b = _polygonal(shapely.intersection(lens, B)), _polygonal(shapely.intersection(lens, A))
            newA = _polygonal(shapely.union(_polygonal(shapely.difference(A, lens)), gain_a))
            newB = _polygonal(shapely.union(_polygonal(shapely.difference(B, lens)), gain_b))
            if not (_one_piece(newA, A) and _one_piece(newB, B)):
                log.debug("step %d|%d: a face would fall apart", a, b)
                continue
            area = A.area + B.area
            if abs(newA.area + newB.area - area) > 1e-6 * max(area, 1.0):
                continue
            simpler = len(shapely.get_coordinates(newA)) + len(shapely.get_coordinates(newB)) < (
                len(shapely.get_coordinates(A)) + len(shapely.get_coordinates(B)))
            if mended.any() or simpler:
                faces[fi], faces[fj] = A, B = newA, newB
                changed.update((fi, fj))
            else:
                log.debug("step %d|%d: kept (nothing mended, no vertex saved)", a, b)
    return faces, list(plane_ids)
