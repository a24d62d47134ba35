"""Alpha shape with an adaptive alpha, gap repair and ring tracing (thesis ch. 4).

Only Delaunay edges can be alpha edges, so the mesh's edges are the
candidates.  Two readings of the shape are built:

- ``boundary = "triangle"`` (default): the shape is the union of the Delaunay
  triangles whose circumradius is at most the triangle's alpha (the
  regular part of the alpha complex); its boundary edges are the edges
  between a triangle inside and one outside.  Each triangle is judged once,
  so the boundary always closes into rings.  For S3 a triangle's alpha is
  the mean of its corners' ps_avg (the thesis' per-edge mean of eq. 4.6,
  taken over the triangle).
- ``boundary = "edge"`` (the thesis, eq. 4.1-4.3): the emptiness of the two
  alpha circles through each edge, one KD-tree nearest-neighbour query per
  circle, then the gap repair of §4.3.2.  With one alpha per edge (S3) the
  three edges of a triangle judge it with three alphas; where they disagree
  the boundary breaks, and an outer ring with a gap the repair cannot close
  is deleted chain by chain: a 65 000-point block lost its outer ring and
  came out as a courtyard-sized sliver (docs/design-notes.md, "Outline
  coverage").

Either way the side that is outside orients every boundary edge with the
roof on its left: outer rings come out counter-clockwise, courtyards
clockwise.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import cKDTree

from rooftrace.contour.spacing import PlanMesh, building_alpha
from rooftrace.errors import GeometryError

__all__ = [
    "AlphaOptions",
    "AlphaShape",
    "alpha_shape",
    "alpha_reach",
    "boundary_edges",
    "triangle_boundary",
    "repair_boundary",
    "trace_rings",
]

log = logging.getLogger(__name__)

STRATEGIES = ("global", "building", "point")
BOUNDARIES = ("triangle", "edge")


@dataclass(frozen=True)
class AlphaOptions:
    """Options of the alpha-shape stage (TOML table ``[alpha]``).

    Attributes
    ----------
    strategy : {'global', 'building', 'point'}
        S1: one alpha for the cloud (``alpha`` or the cloud's mean spacing);
        S2: per building, the mean Delaunay edge length after removing edges
        longer than mean + ``long_edge_sigma`` * std (thesis §4.2, eq. 4.4);
        S3: per edge, the mean of its end points' spacings ps_avg, each the
        mean length of the Delaunay edges wholly inside a circle of
        ``radius`` around the point (thesis §4.3.1, eq. 4.5-4.6).
        Default chosen by measurement (docs/design-notes.md, "Roof outlines").
    alpha : float or None
        Alpha radius in metres for S1; None = the mean spacing passed by the
        caller (the cloud's s_avg), else the building's mean Delaunay edge length.
    radius : float
        R of S3 in metres (thesis §6.3.1: 3 m; results insensitive for 1-5 m).
    long_edge_sigma : float
        Long-edge cut of S2 in standard deviations (thesis §4.2.1: 3).
    min_hole_area : float
        Courtyards smaller than this (m²) are filled; default Ar_min = 4 m²
        (thesis Table 6.1), the smallest building worth mapping.
    scale : float
        Multiplies every alpha of the chosen strategy (1 = the thesis).
        Scan patterns leave wider gaps along roof edges than inside, and the
        union of triangles drops an obtuse triangle at the edge that the
        thesis' edge test keeps; 1.5 bridges both and measured best with the
        triangle boundary (1.25 with the edge test; docs/design-notes.md,
        "Outline coverage").
    boundary : {'triangle', 'edge'}
        How the shape is read from the alphas (module docstring):
        ``triangle`` = union of the Delaunay triangles with circumradius
        at most their alpha (closed by construction; default, chosen by
        measurement in docs/design-notes.md, "Outline coverage"), ``edge``
        = the thesis' empty-circle test per edge with its gap repair.
    seen_through : bool
        With the triangle boundary, no triangle holding a point that is not
        roof and lies below the roof (given by the caller, e.g. ground in a
        passage or a light well) is part of the shape: the enlarged alpha
        bridges gaps of up to 3 spacings, and where the laser reached the
        ground in one the roof is not there (docs/design-notes.md, "Why the
        Delft run lost area F").
    """

    section = "alpha"

    strategy: str = "point"
    alpha: float | None = None
    radius: float = 3.0
    long_edge_sigma: float = 3.0
    min_hole_area: float = 4.0
    scale: float = 1.5
    boundary: str = "triangle"
    seen_through: bool = True

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise ValueError(f"alpha.strategy must be one of {', '.join(STRATEGIES)}, not {self.strategy!r}")
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"alpha.boundary must be one of {', '.join(BOUNDARIES)}, not {self.boundary!r}")
        if self.alpha is not None and not self.alpha > 0:
            raise ValueError(f"alpha.alpha must be > 0 m, not {self.alpha}")
        if not self.radius > 0:
            raise ValueError(f"alpha.radius must be > 0 m, not {self.radius}")
        if not self.scale > 0:
            raise ValueError(f"alpha.scale must be > 0, not {self.scale}")
        if self.min_hole_area < 0:
            raise ValueError(f"alpha.min_hole_area must be >= 0 m², not {self.min_hole_area}")


@dataclass
class AlphaShape:
    """Result of :func:`alpha_shape`.

    Attributes
    ----------
    rings : list of ndarray of int
        Point indices of each closed ring (first vertex not repeated), roof on
        the left: the outer ring counter-clockwise first, then the holes
        (clockwise).  Indices refer to the input points.
    alpha : float
        Alpha in metres (the median of the per-edge values for S3).
    strategy : str
    spacing : ndarray of shape (N,) float64
        Local mean spacing per point (ps_avg for S3, else the unscaled alpha everywhere).
    dropped_area : float
        Area (m²) of the other outer rings, left out (parts that fell apart).
    gap_fill : float
        90th percentile over the Delaunay edges of length / (2 alpha): how
        nearly the sampling's own gaps fill the alpha disk (about 0.5-0.65 on
        AHN3, 0.86 between the demo's scan lines at alpha scale 1).
    scale : float
        The factor the spacings were multiplied by (``options.scale`` times
        the caller's ``alpha_scale``): ``spacing * scale`` is each point's
        alpha radius, metres.
    """

    rings: list[np.ndarray]
    alpha: float
    strategy: str
    spacing: np.ndarray
    dropped_area: float = 0.0
    gap_fill: float = float("nan")
    scale: float = 1.0


def boundary_edges(xy: np.ndarray, edges: np.ndarray, alpha: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
    """Directed alpha-boundary edges, roof on the left (eq. 4.1-4.3).

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
    edges : ndarray of shape (E, 2) int
        Candidate (Delaunay) edges.
    alpha : float or ndarray of shape (E,)
        Alpha radius per edge, metres.

    Returns
    -------
    ndarray of shape (B, 2) int64
        ``(from, to)`` point indices.  An edge with exactly one empty circle
        is a boundary edge; with two it is a dangling "extra" edge and is
        dropped (it bounds no area).
    """
    alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (len(edges),))
    pi, pj = xy[edges[:, 0]], xy[edges[:, 1]]
    d = pj - pi
    s2 = np.einsum("ij,ij->i", d, d)
    ok = (s2 <= 4.0 * alpha**2) & (s2 > 0)
    d, pi, a, s2 = d[ok], pi[ok], alpha[ok], s2[ok]
    h = np.sqrt(np.maximum(a**2 / s2 - 0.25, 0.0))
    mid = pi + 0.5 * d
    perp = np.column_stack([d[:, 1], -d[:, 0]]) * h[:, None]  # right of i->j (eq. 4.1)
    tree = tree if tree is not None else cKDTree(xy)
    centres = np.concatenate([mid + perp, mid - perp])
    dist, _ = tree.query(centres, k=1, workers=-1 if len(centres) > 20000 else 1)  # threads cost more on small sets
    # p_i and p_j lie on the circle; anything strictly closer is inside
    empty = dist >= np.concatenate([a, a]) * (1.0 - 1e-9)
    right_empty, left_empty = empty[: len(a)], empty[len(a):]
    e = edges[ok]
    fwd = right_empty & ~left_empty
    rev = left_empty & ~right_empty
    return np.concatenate([e[fwd], e[rev][:, ::-1]]).astype(np.int64)


def triangle_boundary(xy: np.ndarray, triangles: np.ndarray, neighbours: np.ndarray, alpha: np.ndarray,
                      seen_through: np.ndarray | None = None, sampling: np.ndarray | None = None) -> np.ndarray:
    """Directed boundary edges of the union of the triangles with circumradius <= alpha, inside on the left.

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
    triangles : ndarray of shape (T, 3) int
        Delaunay triangles, counter-clockwise.
    neighbours : ndarray of shape (T, 3) int
        The triangle across the edge opposite each corner, -1 on the hull
        (``scipy.spatial.Delaunay.neighbors``).
    alpha : float or ndarray of shape (T,)
        Alpha radius per triangle, metres.
    seen_through : ndarray of shape (M, 2) float64, optional
        Plan coordinates (metres) of points that are not roof and lie below
        it: a triangle wider than ``sampling`` holding one is not roof (the
        laser reached the ground there: a passage, a light well between
        roofs).
    sampling : float or ndarray of shape (T,), optional
        Circumradius (m) up to which a triangle is the sampling's own and
        stays whatever it holds (a split return at the edge, noise); default
        0, every triangle.

    Returns
    -------
    ndarray of shape (B, 2) int64
        ``(from, to)`` point indices; every vertex has as many edges in as out.

    Examples
    --------
    >>> xy = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    >>> tri = np.array([[0, 1, 2], [0, 2, 3]]); nb = np.array([[-1, 1, -1], [-1, -1, 0]])
    >>> sorted(map(tuple, triangle_boundary(xy, tri, nb, 1.0).tolist()))  # circumradius 0.71 m: both inside
    [(0, 1), (1, 2), (2, 3), (3, 0)]
    >>> triangle_boundary(xy, tri, nb, 0.5).tolist()
    []
    """
    a, b, c = xy[triangles[:, 0]], xy[triangles[:, 1]], xy[triangles[:, 2]]
    la, lb, lc = np.hypot(*(b - c).T), np.hypot(*(c - a).T), np.hypot(*(a - b).T)
    area2 = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        solid = la * lb * lc <= 2.0 * area2 * np.broadcast_to(alpha, (len(triangles),))  # R = abc / (4 area)
    if seen_through is not None and len(seen_through) and solid.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            wide = solid & ~(la * lb * lc <= 2.0 * area2 * np.broadcast_to(
                0.0 if sampling is None else sampling, (len(triangles),)))
        if wide.any():
            solid[_holding(xy, triangles, wide, np.asarray(seen_through, dtype=np.float64).reshape(-1, 2))] = False
    out = []
    for k in range(3):
        across = neighbours[:, k]
        keep = solid & ~np.where(across >= 0, solid[np.maximum(across, 0)], False)
        out.append(np.column_stack([triangles[keep, (k + 1) % 3], triangles[keep, (k + 2) % 3]]))
    return np.concatenate(out).astype(np.int64)


def _holding(xy: np.ndarray, triangles: np.ndarray, candidates: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Indices of the ``candidates`` triangles (a boolean mask) that hold at least one of ``points`` (boundary included)."""
    index = np.flatnonzero(candidates)
    a, b, c = (xy[triangles[index, k]] for k in range(3))
    # a point in a triangle lies in its circumcircle: one nearest-neighbour query per triangle keeps the
    # exact test (shapely) to the few triangles near a point
    ab, ac = b - a, c - a
    d = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (ac[:, 1] * (ab ** 2).sum(axis=1) - ab[:, 1] * (ac ** 2).sum(axis=1)) / d
        uy = (ab[:, 0] * (ac ** 2).sum(axis=1) - ac[:, 0] * (ab ** 2).sum(axis=1)) / d
    radius = np.hypot(ux, uy)
    centres = a + np.column_stack([ux, uy])
    tree = cKDTree(points)
    dist, _ = tree.query(centres)
    near = np.flatnonzero(~(dist > radius * (1.0 + 1e-9)))  # NaN (a degenerate triangle) stays a candidate
    if len(near) == 0:
        return near
    finite = np.isfinite(radius[near])
    if finite.all():
        # only the points in those circles can be in the triangles (the ground of a whole block is
        # many more; making each a shapely point cost more than the test)
        inner = tree.query_ball_point(centres[near], radius[near] * (1.0 + 1e-9) + 1e-12, return_sorted=False)
        points = points[np.unique(np.concatenate([np.asarray(i, dtype=np.int64) for i in inner]))]
    _, hit = shapely.STRtree(shapely.polygons(xy[triangles[index[near]]])).query(
        shapely.points(points), predicate="intersects")
    return index[near[np.unique(hit)]]


def repair_boundary(directed: np.ndarray, edges: np.ndarray, lengths: np.ndarray, n: int) -> np.ndarray:
    """Close gaps and delete extra segments (thesis §4.3.2).

    A chain end (a vertex with an incoming but no outgoing boundary edge) is
    joined to a chain start when a Delaunay edge connects them, shortest
    first; whatever still dangles afterwards is deleted, repeatedly, until
    every vertex has both an incoming and an outgoing edge.
    """
    directed = np.unique(directed, axis=0) if len(directed) else directed.reshape(0, 2)
    indeg = np.bincount(directed[:, 1], minlength=n)
    outdeg = np.bincount(directed[:, 0], minlength=n)
    is_end = (indeg > 0) & (outdeg == 0)
    is_start = (outdeg > 0) & (indeg == 0)
    if is_end.any() and is_start.any():
        a, b = edges[:, 0], edges[:, 1]
        cand = np.concatenate([np.column_stack([a, b])[is_end[a] & is_start[b]],
                               np.column_stack([b, a])[is_end[b] & is_start[a]]])
        clen = np.concatenate([lengths[is_end[a] & is_start[b]], lengths[is_end[b] & is_start[a]]])
        used_end = np.zeros(n, bool)
        used_start = np.zeros(n, bool)
        joins = []
        for k in np.argsort(clen, kind="stable"):  # few candidates: the dangling ends only
            u, w = cand[k]
            if not used_end[u] and not used_start[w]:
                used_end[u] = used_start[w] = True
                joins.append((u, w))
        if joins:
            directed = np.concatenate([directed, np.asarray(joins, dtype=np.int64)])
    while len(directed):
        indeg = np.bincount(directed[:, 1], minlength=n)
        outdeg = np.bincount(directed[:, 0], minlength=n)
        keep = (outdeg[directed[:, 1]] > 0) & (indeg[directed[:, 0]] > 0)
        if keep.all():
            break
        directed = directed[keep]
    return directed


def trace_rings(xy: np.ndarray, directed: np.ndarray) -> list[np.ndarray]:
    """Follow directed boundary edges into closed rings.

    At a vertex with several outgoing edges the walk takes the first one
    clockwise from the edge it came along, which keeps the roof on the left
    and splits rings that touch at a vertex instead of crossing them.
    The repair can leave two chains from one vertex to another; a walk that
    took the wrong one comes back to a vertex it has left already and finds
    no free edge there.  It then goes back to the last vertex of the walk
    with a free edge and goes on from there, leaving that chain out (before,
    the whole ring was dropped: the outer ring of a 2 000 m² Delft block).
    Chains that cannot close are dropped.
    """
    if len(directed) == 0:
        return []
    order = np.lexsort((directed[:, 1], directed[:, 0]))
    directed = directed[order]
    starts = np.searchsorted(directed[:, 0], np.arange(len(xy) + 1))
    used = np.zeros(len(directed), bool)
    rings = []
    for first in range(len(directed)):
        if used[first]:
            continue
        used[first] = True
        ring = [directed[first, 0]]
        prev, cur = directed[first]
        while cur != ring[0]:
            lo, hi = starts[cur], starts[cur + 1]
            free = [k for k in range(lo, hi) if not used[k]]
            if not free:
                # back at a vertex this walk left already: the walk took the
                # wrong one of two chains leaving an earlier vertex; go back
                # to the last vertex with a free edge and leave that chain out
                j = _last_free(ring, starts, used) if cur in ring else 0
                if j < 1:
                    ring = None
                    break
                prev, cur = ring[j - 1], ring[j]
                del ring[j:]
                continue
            if len(free) == 1:
                k = free[0]
            else:
                back = np.arctan2(*(xy[prev] - xy[cur])[::-1])
                outs = np.array([np.arctan2(*(xy[directed[k, 1]] - xy[cur])[::-1]) for k in free])
                turn = (back - outs) % (2 * np.pi)
                turn[turn == 0] = 2 * np.pi  # going straight back is the last resort
                k = free[int(np.argmin(turn))]
            used[k] = True
            ring.append(cur)
            prev, cur = cur, directed[k, 1]
        if ring is not None and len(ring) >= 3:
            rings.append(np.asarray(ring, dtype=np.int64))
    return rings


def _last_free(ring: list, starts: np.ndarray, used: np.ndarray) -> int:
    """Index of the last vertex of ``ring`` that still has an unused outgoing edge; 0 if none."""
    for j in range(len(ring) - 1, 0, -1):
        v = ring[j]
        if not used[starts[v]:starts[v + 1]].all():
            return j
    return 0


def _signed_area(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def alpha_shape(xy: np.ndarray, options: AlphaOptions | None = None, *, mean_spacing: float | None = None,
                alpha_scale: float = 1.0, seen_through: np.ndarray | None = None,
                mesh: PlanMesh | None = None) -> AlphaShape:
    """Outer ring and courtyards of one building's points.

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
        Planimetric coordinates (metres) of one building, without duplicates.
    options : AlphaOptions, optional
    mean_spacing : float, optional
        The cloud's s_avg, used as alpha by S1 when ``options.alpha`` is None.
    alpha_scale : float, default 1
        Multiplies every alpha (used by callers to retry a shape that broke up).
    seen_through : ndarray of shape (M, 2) float64, optional
        Plan coordinates (metres) of points that are not roof and lie below
        the roof around them (ground in a passage or a light well): no
        triangle holding one is part of the shape (``boundary = "triangle"``
        only; :func:`triangle_boundary`).
    mesh : PlanMesh, optional
        The Delaunay mesh of ``xy`` (and its spacings), when the caller
        traces several shapes from the same points.

    Returns
    -------
    AlphaShape
        ``rings[0]`` is the outer ring (the largest by area); holes smaller
        than ``options.min_hole_area`` or outside it are left out.

    Raises
    ------
    GeometryError
        ``too_few_points``, ``collinear`` or ``no_ring`` (no closed boundary).

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.mgrid[0:10:0.5, 0:6:0.5].reshape(2, -1).T
    >>> shape = alpha_shape(xy, AlphaOptions(strategy="building"))
    >>> len(shape.rings), len(shape.rings[0]), round(shape.alpha, 3)
    (1, 60, 0.849)
    """
    options = options or AlphaOptions()
    xy = np.asarray(xy, dtype=np.float64)
    mesh = mesh if mesh is not None else PlanMesh(xy)
    if len(mesh.xy) != len(xy):
        raise ValueError(f"alpha_shape: a mesh of {len(mesh.xy)} points for {len(xy)} points")
    edges, lengths, triangles, neighbours = mesh.edges, mesh.lengths, mesh.triangles, mesh.neighbours
    spacing = _spacing(options, mesh, mean_spacing)
    if options.strategy == "point":
        alpha = 0.5 * (spacing[edges[:, 0]] + spacing[edges[:, 1]])
        alpha_value = float(np.median(alpha))
    else:
        alpha_value = float(spacing[0])
        alpha = np.full(len(edges), alpha_value)
    alpha_scale = alpha_scale * options.scale
    alpha = alpha * alpha_scale
    if options.boundary == "triangle":
        # the alpha the points' own spacing gives (the thesis' x 1) bridges the sampling; only what the
        # enlargement bridges beyond it is cut where the ground was seen
        own = spacing[triangles].mean(axis=1)
        directed = triangle_boundary(xy, triangles, neighbours, own * alpha_scale, seen_through, own)
    else:
        directed = boundary_edges(xy, edges, alpha, cKDTree(xy))
        directed = repair_boundary(directed, edges, lengths, len(xy))
    rings = trace_rings(xy, directed)
    areas = np.array([_signed_area(xy[r]) for r in rings])
    outer = [r for r, a in zip(rings, areas) if a > 0]
    if not outer:
        raise GeometryError("no_ring")
    outer_areas = areas[areas > 0]
    main = outer[int(np.argmax(outer_areas))]
    shell = shapely.Polygon(xy[main])
    holes = [r for r, a in zip(rings, areas) if a < 0 and -a >= options.min_hole_area
             and shell.contains(shapely.Point(xy[r].mean(axis=0)))]
    log.debug("alpha shape: %d rings traced, outer of %.1f m², %d holes kept", len(rings), outer_areas.max(), len(holes))
    dropped = float(outer_areas.sum() - outer_areas.max())
    gap_fill = float(np.percentile(lengths / (2.0 * alpha), 90))
    return AlphaShape([main, *holes], alpha_value * alpha_scale, options.strategy, spacing, dropped, gap_fill,
                      alpha_scale)



def _spacing(options: AlphaOptions, mesh: PlanMesh, mean_spacing: float | None) -> np.ndarray:
    """The strategy's spacing per point (metres): ps_avg (S3), or the one alpha of S1 or S2 everywhere."""
    if options.strategy == "point":
        return mesh.point_spacing(options.radius)
    if options.strategy == "global" and (options.alpha is not None or mean_spacing is not None):
        alpha_value = float(options.alpha if options.alpha is not None else mean_spacing)
    else:
        alpha_value = building_alpha(mesh.lengths, options.long_edge_sigma)
    return np.full(len(mesh.xy), alpha_value)


def alpha_reach(mesh: PlanMesh, options: AlphaOptions | None = None, *, mean_spacing: float | None = None,
                alpha_scale: float = 1.0) -> float:
    """How far from every point the shape :func:`alpha_shape` traces with these arguments can reach, metres.

    The largest alpha radius of any triangle: a triangle of the shape has a
    circumradius at most its alpha, and every place inside a triangle lies
    within its circumradius of one of its corners.  Points farther than this
    from all of ``mesh``'s points are in no triangle of the shape.

    Parameters
    ----------
    mesh : PlanMesh
        The Delaunay mesh of the building's points.
    options, mean_spacing, alpha_scale
        As for :func:`alpha_shape`.

    Returns
    -------
    float
        Metres, rounded up (by a millionth) past the rounding of the triangle test.
    """
    options = options or AlphaOptions()
    return float(np.max(_spacing(options, mesh, mean_spacing))) * alpha_scale * options.scale * (1.0 + 1e-6)
