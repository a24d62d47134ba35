"""Ground filtering by progressive TIN densification, and height above ground.

Axelsson (2000) as used in the thesis (Santos 2019, §3.2): the lowest point of
each cell of a coarse grid seeds a TIN; a point joins the ground when its
distance to the plane of the TIN facet below it and the angles from the point
to the facet's three vertices are both under the iteration thresholds; the
TIN is rebuilt and the test repeated until nothing is added.

Three choices keep this fast on city blocks (850k points in a few seconds):
the TIN is Shewchuk's Triangle with our own point location
(:mod:`rooftrace.lidar.ground_tin`; 47 s -> 2 s on a 1.2 M-point scene against
Qhull), the densification runs on the lowest point of each small cell
(about ``max(1 m, 3·s_avg)`` wide; the ground is never above the lowest
point of its cell), and every accepted point of a round is added at once.  Every point of the cloud is
then labelled from the final TIN: ground when its height above the TIN is at
most ``ground_tolerance``.

:func:`grid_minimum_ground` is the baseline a user might script (lowest point
per cell plus a height threshold), kept for the benchmark.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from rooftrace.errors import GeometryError
from rooftrace.lidar._kernels import column_max, column_min, dense_cells, dense_unique, lowest_per_group
from rooftrace.lidar.ground_tin import locate, serpentine_order, triangulate

__all__ = ["GroundOptions", "progressive_tin", "tin_height", "grid_minimum_ground"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GroundOptions:
    """Options of the ground filter (TOML table ``[ground]``).

    Attributes
    ----------
    seed_cell : float, default 30.0
        Side (m) of the seed grid; must exceed the largest building so that
        every cell reaches the ground (thesis §3.2; LAStools "city" uses 25 m).
    iteration_distance : float, default 1.4
        Largest distance (m) from a point to the plane of its TIN facet
        (Axelsson 2000; DESIGN stage 3).
    iteration_angle : float, default 6.0
        Largest angle (deg) between the facet plane and the lines from the
        point to the facet's vertices (Axelsson 2000).
    candidate_cell : float or None
        Side (m) of the cells whose lowest point takes part in the
        densification.  ``None``: ``max(1.0, 3·s_avg)``.
    ground_tolerance : float or None
        Largest height (m) above the final TIN of a ground point.  ``None``:
        ``max(0.2, 5·sigma_H)``.
    max_iterations : int, default 40
        Upper bound on densification rounds.
    converged_fraction : float, default 0.001
        The densification of a block (see ``converged_block``) stops when a
        round adds in it at most this fraction of the TIN vertices it holds
        (0 gives Axelsson's "until nothing is added"; the last rounds add a
        handful of points at a full re-triangulation each).
    converged_block : float or None
        Side (m) of the square blocks that converge on their own.  ``None``:
        ``2·seed_cell``.  A rule over the whole cloud would make the ground
        of one place depend on how much data lies elsewhere, so a tile and
        the whole cloud would stop at different rounds; blocks anchored at
        the run's origin converge alike in both.
    facet_rounds : int, default 0
        During the first ``facet_rounds`` rounds only the best candidate of
        each facet is added (Axelsson's rule); afterwards every accepted
        candidate is, which needs far fewer rounds.
    """

    section: ClassVar[str] = "ground"
    seed_cell: float = 30.0
    iteration_distance: float = 1.4
    iteration_angle: float = 6.0
    candidate_cell: float | None = None
    ground_tolerance: float | None = None
    max_iterations: int = 40
    facet_rounds: int = 0
    converged_fraction: float = 0.001
    converged_block: float | None = None

    def __post_init__(self) -> None:
        for name in ("seed_cell", "iteration_distance", "iteration_angle", "candidate_cell", "ground_tolerance",
                     "converged_block"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"ground.{name} must be > 0, got {v}")
        if not 0 < self.iteration_angle < 90:
            raise ValueError(f"ground.iteration_angle must be in (0, 90) deg, got {self.iteration_angle}")
        if self.max_iterations < 1:
            raise ValueError(f"ground.max_iterations must be >= 1, got {self.max_iterations}")


def _cell_keys(xy: np.ndarray, origin: np.ndarray, cell: float) -> np.ndarray:
    ij = np.floor((xy - origin) / cell).astype(np.int64)
    return ij[:, 0] * (int(ij[:, 1].max(initial=0)) + 1) + ij[:, 1]


def _lowest_per_cell(xyz: np.ndarray, origin: np.ndarray, cell: float) -> np.ndarray:
    """Index of the lowest point in each occupied cell (ties: lowest index), by ascending cell key."""
    cells, inv = dense_unique(_cell_keys(xyz[:, :2], origin, cell))
    return lowest_per_group(np.ascontiguousarray(xyz[:, 2]), inv, len(cells))


def _border(lo: np.ndarray, hi: np.ndarray, step: float) -> np.ndarray:
    """Border vertices of the TIN: the corners of ``[lo, hi]`` and the multiples of ``step`` along its sides.

    With the four corners alone, the facets between the outermost seeds and
    the border reach to the far corners, so the ground near an edge would
    depend on how far the data extends; vertices every ``step`` keep those
    facets local (and the same in a tile as in the whole cloud: multiples
    of ``step`` in the frame anchored at the run's origin).
    """
    xs = step * np.arange(np.ceil(lo[0] / step), np.floor(hi[0] / step) + 1)
    ys = step * np.arange(np.ceil(lo[1] / step), np.floor(hi[1] / step) + 1)
    xs = xs[(xs > lo[0]) & (xs < hi[0])]
    ys = ys[(ys > lo[1]) & (ys < hi[1])]
    pts = [[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]]
    pts += [[x, lo[1]] for x in xs] + [[x, hi[1]] for x in xs] + [[lo[0], y] for y in ys] + [[hi[0], y] for y in ys]
    return np.asarray(pts, np.float64)


def _corner_heights(corners: np.ndarray, ground: np.ndarray, k: int = 12) -> np.ndarray:
    """Height of each border vertex from a plane fitted to its ``k`` nearest ground points (within their height range)."""
    k = min(k, len(ground))
    near = np.asarray(cKDTree(ground[:, :2]).query(corners, k=k)[1]).reshape(len(corners), k)
    z = np.empty(len(corners))
    for i, idx in enumerate(near):  # a few hundred border vertices at most
        p = ground[idx]
        a = np.column_stack([p[:, :2] - corners[i], np.ones(len(p))])
        coef, *_ = np.linalg.lstsq(a, p[:, 2], rcond=None)
        z[i] = np.clip(coef[2], p[:, 2].min() - 1.0, p[:, 2].max() + 1.0) if len(p) >= 3 else p[:, 2].min()
    return z


def tin_height(tin_xyz: np.ndarray, query_xy: np.ndarray) -> np.ndarray:
    """Height of a TIN below query points (linear in each triangle).

    Parameters
    ----------
    tin_xyz : ndarray of shape (M, 3), float64
        TIN vertices (m), distinct in (x, y), in a local frame.
    query_xy : ndarray of shape (N, 2), float64
        Query positions in the same frame.

    Returns
    -------
    ndarray of shape (N,), float64
        Interpolated height; NaN outside the TIN's convex hull.

    Examples
    --------
    >>> v = np.array([[0, 0, 1.0], [10, 0, 2.0], [0, 10, 3.0], [10, 10, 4.0]])
    >>> tin_height(v, np.array([[5.0, 5.0], [20.0, 20.0]])).tolist()
    [2.5, nan]
    """
    order, tris, nbrs = triangulate(tin_xyz[:, :2])
    v = np.ascontiguousarray(tin_xyz[order], np.float64)
    walk = serpentine_order(query_xy, 10.0)
    q = np.ascontiguousarray(query_xy[walk], np.float64)
    z = np.empty(len(query_xy))
    z[walk] = _interpolate(v, tris, locate(v[:, :2], tris, nbrs, q), q)
    return z


@njit(cache=True)
def _interpolate(v, tris, simplex, q):  # pragma: no cover - compiled
    # barycentric interpolation, one pass (gathering the three vertices of
    # 10^6 queries with numpy took longer than the point location)
    z = np.full(len(q), np.nan)
    for k in range(len(q)):
        t = simplex[k]
        if t < 0:
            continue
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        det = (v[b, 1] - v[c, 1]) * (v[a, 0] - v[c, 0]) + (v[c, 0] - v[b, 0]) * (v[a, 1] - v[c, 1])
        l0 = ((v[b, 1] - v[c, 1]) * (q[k, 0] - v[c, 0]) + (v[c, 0] - v[b, 0]) * (q[k, 1] - v[c, 1])) / det
        l1 = ((v[c, 1] - v[a, 1]) * (q[k, 0] - v[c, 0]) + (v[a, 0] - v[c, 0]) * (q[k, 1] - v[c, 1])) / det
        z[k] = l0 * v[a, 2] + l1 * v[b, 2] + (1.0 - l0 - l1) * v[c, 2]
    return z


def progressive_tin(
    xyz: np.ndarray,
    mean_spacing: float,
    sigma_h: float,
    options: GroundOptions | None = None,
    *,
    exclude: np.ndarray | None = None,
    origin: tuple[float, float] | None = None,
    bounds: tuple[float, float, float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Classify ground points by progressive TIN densification.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Coordinates (m) in a projected CRS.
    mean_spacing : float
        s_avg (m), see :func:`rooftrace.lidar.spacing.mean_spacing`.
    sigma_h : float
        Height precision (m), see :func:`rooftrace.lidar.spacing.height_precision`.
    options : GroundOptions, optional
        Thresholds; defaults when omitted.
    exclude : ndarray of shape (N,), bool, optional
        Points that take no part (noise); they get a height above ground but
        are never ground.
    origin : (float, float), optional
        Corner (m) the candidate and seed grids and the local frame are
        anchored at.  Default: the lowest x and y of the usable points.  A
        tiled run passes the corner of the whole input, so that a tile and
        the whole cloud pick the same lowest point in every cell.
    bounds : (xmin, ymin, xmax, ymax), optional
        Extent (m) the TIN's border is laid around, 1 m outside.  Default:
        the bounding box of the usable points.  A tile passes its extent
        clipped to the whole input's, so that along the data's true edges
        it has the border of the whole cloud.

    Returns
    -------
    ground : ndarray of shape (N,), bool
        Ground points.
    hag : ndarray of shape (N,), float64
        Height above the final TIN (m), for every point.
    params : dict
        Resolved ``candidate_cell``, ``ground_tolerance``, the number of
        rounds and of TIN vertices.

    Notes
    -----
    A candidate ``p`` inside facet ``(v0, v1, v2)`` with unit upward normal
    ``n`` is accepted when ``|n·(p − v0)| < iteration_distance`` and
    ``arcsin(|n·(p − v0)| / |p − v_k|) < iteration_angle`` for k = 0, 1, 2.
    The border (1 m outside ``bounds``: its corners and a vertex every
    ``seed_cell`` along its sides) are TIN vertices with the
    height of the nearest seed, so every point lies inside the TIN.

    References
    ----------
    Axelsson, P. (2000). DEM generation from laser scanner data using
    adaptive TIN models. IAPRS 33(B4), 110-117.
    """
    # the border refit makes one small LAPACK call per border vertex; a
    # multi-threaded BLAS turns each into a thread rendezvous
    with threadpool_limits(limits=1, user_api="blas"):
        return _progressive_tin(xyz, mean_spacing, sigma_h, options, exclude, origin, bounds)


def _progressive_tin(xyz, mean_spacing, sigma_h, options, exclude, origin, bounds):
    opt = options or GroundOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    if n < 3:
        raise GeometryError(f"ground filter needs at least 3 points, got {n}")
    usable = np.ones(n, bool) if exclude is None else ~np.asarray(exclude, bool)
    idx_usable = np.flatnonzero(usable)
    if len(idx_usable) < 3:
        raise GeometryError("ground filter: fewer than 3 points left after removing noise")
    cand_cell = opt.candidate_cell or max(1.0, 3.0 * mean_spacing)
    tol = opt.ground_tolerance or max(0.2, 5.0 * sigma_h)
    anchor = column_min(xyz[idx_usable, :2]) if origin is None else np.asarray(origin, np.float64)
    # the TIN works in a frame near zero (small rounding).  Heights are left as they are: a
    # shift that depends on the data (the lowest z of a tile) would round
    # differently in a tile and in the whole cloud
    local = xyz - np.array([anchor[0], anchor[1], 0.0])
    pts = local[idx_usable]

    cand = _lowest_per_cell(pts, np.zeros(2), cand_cell)
    cand = cand[serpentine_order(pts[cand, :2], 10.0, start=0.0)]
    cxyz = pts[cand]
    seeds = np.unique(_lowest_per_cell(cxyz, np.zeros(2), opt.seed_cell))
    if bounds is None:
        lo, hi = column_min(pts[:, :2]) - 1.0, column_max(pts[:, :2]) + 1.0
    else:
        lo = np.asarray(bounds[:2], np.float64) - anchor - 1.0
        hi = np.asarray(bounds[2:], np.float64) - anchor + 1.0
    corners = _border(lo, hi, opt.seed_cell)
    nearest = np.asarray(cKDTree(cxyz[seeds, :2]).query(corners)[1])
    corner_xyz = np.column_stack([corners, cxyz[seeds[nearest], 2]])

    is_ground = np.zeros(len(cxyz), bool)
    is_ground[seeds] = True
    tan_angle = np.tan(np.radians(opt.iteration_angle))
    # per block: 0 densifying, 1 densifying after the border refit, 2 done
    block_side = opt.converged_block or 2.0 * opt.seed_cell
    bij = np.floor(cxyz[:, :2] / block_side).astype(np.int64)
    block = dense_cells(bij)
    n_blocks = int(block.max(initial=-1)) + 1
    phase = np.zeros(n_blocks, np.int64)
    corner_block = block[seeds[nearest]]  # a border vertex follows the block of its seed
    rounds = 0
    for rounds in range(1, opt.max_iterations + 1):
        tin = np.concatenate([corner_xyz, cxyz[is_ground]])
        order, tris, nbrs = triangulate(tin[:, :2])
        tin = tin[order]
        todo = np.flatnonzero(~is_ground)
        if len(todo) == 0:
            break
        p = cxyz[todo]  # in serpentine order: short walks
        simplex = locate(tin[:, :2], tris, nbrs, p[:, :2])
        ok = simplex >= 0
        todo, p, simplex = todo[ok], p[ok], simplex[ok]
        v = tin[tris[simplex]]  # (k, 3, 3)
        normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        dist = np.abs(np.einsum("ij,ij->i", normal, p - v[:, 0]))
        # sin(angle) = dist / |p - v_k|; compare tangents to avoid arcsin
        reach = np.linalg.norm(p[:, None, :] - v, axis=2).min(axis=1)
        sin_max = dist / np.maximum(reach, 1e-9)
        angle_ok = sin_max < tan_angle / np.sqrt(1 + tan_angle**2)
        accept = np.flatnonzero((dist < opt.iteration_distance) & angle_ok)
        if rounds <= opt.facet_rounds:
            # Axelsson adds, per facet and round, only the candidate closest to
            # it: a car roof inside a large seed facet loses to the street
            order = np.lexsort((dist[accept], simplex[accept]))
            accept = accept[order]
            first = np.ones(len(accept), bool)
            first[1:] = simplex[accept[1:]] != simplex[accept[:-1]]
            accept = accept[first]
        accept = accept[phase[block[todo[accept]]] < 2]
        added = np.bincount(block[todo[accept]], minlength=n_blocks)
        vertices = np.bincount(block[is_ground], minlength=n_blocks)
        log.debug("ground round %d: %d TIN vertices, %d added", rounds, len(tin), len(accept))
        is_ground[todo[accept]] = True
        converged = (phase < 2) & (added <= opt.converged_fraction * vertices)
        # the border vertices took the height of the nearest seed, up to a
        # seed cell away: on a slope that tilts the border facets.  Once the
        # ground of their block is dense, extrapolate them from the nearby
        # ground instead and go on densifying.
        refit = converged[corner_block] & (phase[corner_block] == 0)
        if refit.any():
            corner_xyz[refit, 2] = _corner_heights(corners[refit], cxyz[is_ground])
        phase[converged] += 1
        if (phase == 2).all():
            break

    tin = np.concatenate([corner_xyz, cxyz[is_ground]])
    hag = local[:, 2] - tin_height(tin, local[:, :2])
    # outside the padded hull cannot happen for usable points; excluded ones may lie outside
    hag = np.where(np.isfinite(hag), hag, local[:, 2] - np.nanmin(tin[:, 2]))
    ground = usable & (hag <= tol)
    params = {
        "candidate_cell": cand_cell,
        "ground_tolerance": tol,
        "seed_cell": opt.seed_cell,
        "iteration_distance": opt.iteration_distance,
        "iteration_angle": opt.iteration_angle,
        "rounds": rounds,
        "tin_vertices": int(len(tin)),
    }
    return ground, hag, params


def grid_minimum_ground(xyz: np.ndarray, cell: float = 25.0, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Baseline ground filter: a point is ground when within ``threshold`` of its cell's lowest point.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Coordinates (m).
    cell : float, default 25.0
        Grid cell side (m).
    threshold : float, default 0.5
        Height (m) above the cell minimum still counted as ground.

    Returns
    -------
    ground : ndarray of shape (N,), bool
    hag : ndarray of shape (N,), float64
        Height above the cell's lowest point (m).

    Examples
    --------
    >>> p = np.array([[0, 0, 0.0], [1, 1, 0.3], [2, 2, 5.0]])
    >>> grid_minimum_ground(p)[0].tolist()
    [True, True, False]
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    key = _cell_keys(xyz[:, :2], column_min(xyz[:, :2]), cell)
    _, inv = np.unique(key, return_inverse=True)
    zmin = np.full(inv.max() + 1, np.inf)
    np.minimum.at(zmin, inv, xyz[:, 2])
    hag = xyz[:, 2] - zmin[inv]
    return hag <= threshold, hag
