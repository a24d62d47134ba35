"""From one building's points to its regularised 3D roof outline (DESIGN.md stages 6-7).

alpha shape (rings) -> corners (Douglas-Peucker 3D + angle filter) ->
iterative CD-spline (degree per segment) -> the building's shape: lines and
curves chosen by model selection, the edge between the last roof point and
the first other point ('lines', default), or snapping and a fixed outward
correction ('cdspline') -> shapely Polygon with Z.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from scipy.spatial import QhullError, cKDTree
from threadpoolctl import threadpool_limits

from rooftrace.contour.alpha_shape import AlphaOptions, AlphaShape, alpha_reach, alpha_shape
from rooftrace.contour.cdspline import CDSplineOptions, iterative_cdspline
from rooftrace.contour.corners import CornerOptions, ring_corners, ring_douglas_peucker
from rooftrace.contour.coverage import MIN_COVERAGE, outline_coverage
from rooftrace.contour.edge import EdgeContext
from rooftrace.contour.knots import spline_outline
from rooftrace.contour.lines import bridge_inlets, line_outline
from rooftrace.contour.regularize import RegularizeOptions, dominant_direction, offset_ring, snap_ring
from rooftrace.contour.repair import make_valid_outline
from rooftrace.contour.spacing import PlanMesh
from rooftrace.contour.surface import SurfaceOptions, outline_points
from rooftrace.errors import GeometryError, InputError
from rooftrace.io.vector import Layer
from rooftrace.options import make_options
from rooftrace.progress import Reporter

__all__ = ["OutlineOptions", "RoofOutline", "trace_outline", "outline_buildings", "outlines_layer", "connected_buildings"]

log = logging.getLogger(__name__)

_STAGES = {"surface": SurfaceOptions, "alpha": AlphaOptions, "corners": CornerOptions, "cdspline": CDSplineOptions,
           "regularize": RegularizeOptions}

#: alpha is enlarged by these factors when the shape does not close, falls apart or does not bridge
#: the sampling (status "alpha_enlarged")
_RETRY_SCALES = (1.0, 1.5, 2.0, 3.0)
#: alpha bridges the sampling when the 90th percentile of the Delaunay edges stays below this share
#: of the alpha disk's diameter (AlphaShape.gap_fill).  An edge as long as the diameter is a gap the
#: disk enters; AHN3 roofs (Delft, City3D) measure 0.50-0.65, the demo's scan lines 0.86-0.93
_GAP_FILL_MAX = 0.75


@dataclass(frozen=True)
class OutlineOptions:
    """The outline stages' options, one frozen dataclass per TOML table.

    Attributes
    ----------
    surface : SurfaceOptions
        ``[surface]``: enabled, radius_factor, max_slope, tolerance.
    alpha : AlphaOptions
        ``[alpha]``: strategy, alpha, radius, long_edge_sigma, min_hole_area.
    corners : CornerOptions
        ``[corners]``: t_dist, t_ang, keep_curve_breaks.
    cdspline : CDSplineOptions
        ``[cdspline]``: significance, max_degree, test, densify.
    regularize : RegularizeOptions
        ``[regularize]``: offset_factor, snap, snap_tolerance, max_offset_ratio.
    """

    surface: SurfaceOptions = field(default_factory=SurfaceOptions)
    alpha: AlphaOptions = field(default_factory=AlphaOptions)
    corners: CornerOptions = field(default_factory=CornerOptions)
    cdspline: CDSplineOptions = field(default_factory=CDSplineOptions)
    regularize: RegularizeOptions = field(default_factory=RegularizeOptions)

    @classmethod
    def from_config(cls, config: dict | None = None, **overrides: Any) -> OutlineOptions:
        """Options from a TOML config dict (tables ``surface``, ``alpha``, ``corners``, ``cdspline``, ``regularize``).

        Keyword overrides name a field of any of the five stages (e.g.
        ``strategy="point"``, ``snap=True``); ``None`` means not given.
        """
        routed: dict[str, dict[str, Any]] = {name: {} for name in _STAGES}
        for key, value in overrides.items():
            owners = [name for name, c in _STAGES.items() if key in {f.name for f in dataclasses.fields(c)}]
            if not owners:
                raise InputError(f"outline: unknown option {key!r}")
            routed[owners[0]][key] = value
        return cls(**{name: make_options(c, config, **routed[name]) for name, c in _STAGES.items()})


@dataclass
class RoofOutline:
    """One building's roof outline.

    Attributes
    ----------
    building_id : int
    polygon : shapely.Polygon or None
        PolygonZ in the input CRS, outer ring counter-clockwise, holes
        clockwise; None when ``status`` says why there is none.
    degrees : list of list of int
        Per ring (outer first), the degree of each segment, in ring order.
    corners : list of ndarray of int
        Per ring, the indices of its corner vertices in the polygon's ring
        coordinates (closing vertex excluded); segment k starts at corner k.
    alpha_strategy : str
    alpha : float
        Metres (median of the per-edge values for the 'point' strategy).
    n_points : int
    status : str
        'ok', 'alpha_enlarged' (closed, or bridged the gaps between scan
        lines, only with a larger alpha), 'repaired'
        (invalid rings fixed by make_valid), 'multipart' (the points fall
        apart into several parts even with alpha tripled; the largest is
        kept), 'unregularised' (the CD-spline
        collapsed the outer ring, or the regularised outline left out points the alpha shape holds;
        the alpha-shape rings are kept), 'alpha_fallback' (the configured
        strategy's outline covered too few of the points; ``alpha_strategy`` names the one used),
        'low_coverage' (no strategy covers 99 % of the points; the best is kept), or why there is
        no outline ('too_few_points', 'collinear', 'no_ring', ...).
    z_min, z_mean, z_max : float
        Heights of the building's points, metres.
    sigma : float
        Residual standard deviation of the CD-spline fit of the outer ring, metres.
    coverage : float
        Share of the building's plan positions inside the polygon or within
        their alpha radius of it (:func:`~rooftrace.contour.coverage.outline_coverage`);
        below 0.99 the status says so.
    """

    building_id: int
    polygon: Any
    degrees: list = field(default_factory=list)
    corners: list = field(default_factory=list)
    alpha_strategy: str = ""
    alpha: float = float("nan")
    n_points: int = 0
    status: str = "ok"
    z_min: float = float("nan")
    z_mean: float = float("nan")
    z_max: float = float("nan")
    sigma: float = float("nan")
    coverage: float = float("nan")

    @property
    def area(self) -> float:
        """Planimetric area in m² (0 without a polygon)."""
        return 0.0 if self.polygon is None else float(self.polygon.area)


def _ring_outline(xyz: np.ndarray, spacing: float, options: OutlineOptions, *, outer: bool = True,
                  context: EdgeContext | None = None,
                  roof: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray, list[int], float]:
    if len(xyz) < 4:
        return xyz, np.arange(len(xyz)), [1] * len(xyz), 0.0
    reg = options.regularize
    lines = reg.method == "lines"
    if lines and outer and reg.bridge_factor > 0:
        # an inlet with no points on its far side (a step between roof levels) is no part of the shape
        xyz = xyz[bridge_inlets(xyz[:, :2], reg.bridge_factor * spacing)]
    corners = ring_corners(xyz, options.corners)
    # finer Douglas-Peucker vertices are where a mixed straight/curved segment may split
    candidates = np.setdiff1d(ring_douglas_peucker(xyz, options.corners.t_dist / 3), corners)
    spline = spline_outline(xyz, corners, candidates, options.cdspline)
    if lines:
        try:
            shape = line_outline(xyz, spline, spacing, noise_factor=reg.noise_factor, edge_factor=reg.edge_factor,
                                 directions=reg.directions, context=context, densify=options.cdspline.densify,
                                 z_tolerance=options.corners.t_dist,
                                 refit=lambda knots: iterative_cdspline(xyz, knots, options.cdspline),
                                 roof=roof)
        except ValueError:
            shape = None
        if shape is not None and _simple(shape.vertices):
            return shape.vertices, shape.corner_index, shape.degrees, shape.sigma
        log.debug("lines: no simple ring, the CD-spline's is kept")
    vertices, corner_index = spline.ring(options.cdspline.densify)
    degrees = spline.degrees
    # each regularisation step is kept only if the ring stays simple (no self-crossing)
    if reg.snap:
        direction = dominant_direction(vertices, corner_index, degrees)
        snapped = snap_ring(vertices, corner_index, degrees, direction, reg.snap_tolerance)
        if _simple(snapped):
            vertices = snapped
    for fraction in (1.0, 0.5, 0.25) if reg.offset_factor > 0 else ():
        # a narrow notch can close up under the full shift; a smaller one often still fits
        moved = offset_ring(vertices, fraction * reg.offset_factor * spacing, reg.max_offset_ratio)
        if _simple(moved):
            vertices = moved
            break
    return vertices, corner_index, degrees, spline.sigma


def _simple(vertices: np.ndarray) -> bool:
    return len(vertices) >= 3 and bool(shapely.LinearRing(vertices[:, :2]).is_simple)


def trace_outline(xyz: np.ndarray, options: OutlineOptions | None = None, *, mean_spacing: float | None = None,
                  context_xy: np.ndarray | None = None) -> RoofOutline:
    """Regularised 3D roof outline of one building, checked to cover the building's points.

    The outline (with its holes, after regularisation) must cover
    :data:`~rooftrace.contour.coverage.MIN_COVERAGE` of the building's points
    (inside or within the local alpha, :func:`~rooftrace.contour.coverage.outline_coverage`).
    When the configured alpha strategy breaks that, the other strategies are
    tried in turn (point → building → global), then the configured one with
    alpha doubled and tripled; the first that holds is kept with status
    ``alpha_fallback``.  When the regularisation gives up points the alpha
    shape holds, the alpha shape's rings are kept (``unregularised``).  When
    nothing holds, the outline covering the most is kept with status
    ``low_coverage`` (or ``multipart``, when the building's points fall apart).

    Parameters
    ----------
    xyz : ndarray of shape (N, 3) float64
        The building's points, metres in a projected CRS.
    options : OutlineOptions, optional
    mean_spacing : float, optional
        The cloud's mean point spacing s_avg in metres (alpha of the 'global'
        strategy when ``options.alpha.alpha`` is None).
    context_xy : ndarray of shape (C, 2) or (C, 3) float64, optional
        Plan coordinates (metres, same CRS), with heights when known, of
        points around the building that are not its roof: ground,
        vegetation, other buildings.  The 'lines' regularisation places the
        edge beyond the last roof point by half the sampling step or half the
        gap to the first of these, whichever is smaller
        (:func:`rooftrace.contour.edge.edge_shift`).  With heights, those
        lying below the building where the enlarged alpha would bridge a gap
        keep it open (``[alpha] seen_through``).

    Returns
    -------
    RoofOutline
        ``building_id`` is 0; :func:`outline_buildings` sets it.

    Raises
    ------
    ValueError
        ``xyz`` is not of shape (N, 3).
    GeometryError
        Too few points, collinear points, or no closed ring with any strategy
        even with alpha tripled; the message is the status.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.mgrid[0:10:0.3, 0:6:0.3].reshape(2, -1).T  # points 0..9.9 x 0..5.7 m
    >>> xyz = np.column_stack([g, np.full(len(g), 5.0)])
    >>> out = trace_outline(xyz)
    >>> out.status, len(out.corners[0]), out.degrees, round(out.area), out.coverage
    ('ok', 4, [[1, 1, 1, 1]], 61, 1.0)
    """
    options = options or OutlineOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"trace_outline: xyz must have shape (N, 3), not {xyz.shape}")
    if not np.isfinite(xyz).all():
        raise GeometryError("non_finite")
    pts, below = outline_points(xyz, options.surface, mean_spacing, walls=True)
    # work near the origin: map coordinates (1e5 m) cost the least-squares fits digits
    origin = np.append(np.floor(xyz[:, :2].min(axis=0)), 0.0)
    pts = pts - origin
    if len(pts) < 3:
        raise GeometryError("too_few_points")
    around = None if context_xy is None else np.asarray(context_xy, dtype=np.float64) - origin[: np.shape(context_xy)[1]]
    context = None
    if options.regularize.method == "lines" and (around is not None or below.any()):
        # the building's own wall points on the boundary mark the edge (contour.edge)
        context = EdgeContext(None if around is None else around[:, :2], walls=pts[below, :2])
    seen = _SeenThrough.around(xyz - origin, around, options.surface.tolerance) if options.alpha.seen_through else None
    # every ring's noise floor is measured on the building's points (lines.boundary_step): one tree for all
    roof = cKDTree(pts[:, :2]) if options.regularize.method == "lines" else None
    mesh = PlanMesh(pts[:, :2])  # every alpha shape below is traced from these points
    best, first_error = None, None
    for k, (strategy, enlarge) in enumerate(_fallbacks(options.alpha.strategy, mean_spacing, options.alpha.alpha)):
        trial = options if k == 0 else dataclasses.replace(options, alpha=dataclasses.replace(
            options.alpha, strategy=strategy, scale=options.alpha.scale * enlarge))
        # a building whose parts only a passage joins is one polygon: bridge it rather than lose a part
        for cut in (seen, None) if seen is not None else (None,):
            try:
                shape, status = _alpha_shape(pts, trial.alpha, mean_spacing, cut, mesh)
            except GeometryError as exc:
                if str(exc) != "no_ring":
                    raise
                first_error = first_error or exc
                continue
            # the alpha shape is measured before the regularisation: a strategy whose shape has lost part
            # of the building (a ring dropped, the shape fallen apart) is not worth regularising
            covered = _traced_coverage(pts, shape)
            if best is None or covered > best[0]:
                best = (covered, k, trial, shape, status, cut is not None)
            if covered >= MIN_COVERAGE:
                break
        if best is not None and best[0] >= MIN_COVERAGE:
            break
    if best is None:
        raise first_error
    covered, k, trial, shape, status, was_cut = best
    outline = _regularised_or_traced(pts, origin, shape, status, trial, covered, context, roof)
    if was_cut and outline.status == "repaired":
        # a kept opening (a light well beside a wall, a notch) pinches the outline where the ring was
        # repaired, and no closed solid has such a plan: the shape without the cut is traced instead
        try:
            uncut, uncut_status = _alpha_shape(pts, trial.alpha, mean_spacing, None, mesh)
            retraced = _regularised_or_traced(pts, origin, uncut, uncut_status, trial,
                                              _traced_coverage(pts, uncut), context, roof)
        except GeometryError:
            retraced = None  # no shape without the cut: the repaired one stands
        if retraced is not None and retraced.coverage >= min(outline.coverage, MIN_COVERAGE):
            outline = retraced
    if outline.coverage < MIN_COVERAGE and outline.status != "multipart":
        outline.status = "low_coverage"
    elif k > 0:
        outline.status = "alpha_fallback"
    z = xyz[:, 2]
    outline.n_points, outline.z_min, outline.z_mean, outline.z_max = len(xyz), float(z.min()), float(z.mean()), \
        float(z.max())
    return outline


def _fallbacks(strategy: str, mean_spacing: float | None, alpha: float | None) -> list[tuple[str, float]]:
    """(strategy, alpha enlargement) to try in turn: the configured one, the others from the most local
    alpha to the least, then the configured one with alpha doubled and tripled (a few points farther
    apart than any of the alphas: a small building's stray point)."""
    order = [strategy] + [s for s in ("point", "building", "global") if s != strategy]
    if mean_spacing is None and alpha is None and strategy != "global":
        order.remove("global")  # without a cloud spacing 'global' is 'building'
    return [(s, 1.0) for s in order] + [(strategy, 2.0), (strategy, 3.0)]


class _SeenThrough:
    """The points around a building that lie below the building beside them: where the laser saw past it.

    ``pts`` are the building's points as measured (walls at their own
    height, not lifted to the roof), ``around`` the points that are not this
    roof (with heights, else nothing is known), both in metres in one frame;
    a point is below the building when it is more than ``tolerance`` (m)
    under the nearest building point.  Only the points within the alpha
    shape's reach of the building matter (:func:`alpha_reach`): the ground of
    a whole block lies in its bounding box, and the nearest-point search for
    the far points was most of the cost.
    """

    def __init__(self, pts: np.ndarray, candidates: np.ndarray, tolerance: float):
        self._tree = cKDTree(pts[:, :2])
        self._z = pts[:, 2]
        self._candidates = candidates
        self._tolerance = tolerance
        self._reach = -1.0
        self._below = np.zeros((0, 2))

    @classmethod
    def around(cls, pts: np.ndarray, around: np.ndarray | None, tolerance: float) -> _SeenThrough | None:
        """None when nothing is known below the building (no points around, or none with heights)."""
        if around is None or around.shape[1] < 3 or len(around) == 0:
            return None
        lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        inside = np.all((around[:, :2] >= lo) & (around[:, :2] <= hi), axis=1)
        cand = around[inside]
        if len(cand) == 0:
            return None
        return cls(pts, cand, tolerance)

    def within(self, reach: float) -> np.ndarray:
        """Plan positions (M, 2) of the points below the building within ``reach`` metres of one of its points."""
        if reach > self._reach:
            cand = self._candidates
            dist, nearest = self._tree.query(cand[:, :2], distance_upper_bound=reach)
            near = np.isfinite(dist)
            z = np.full(len(cand), -np.inf)
            z[near] = self._z[nearest[near]]
            self._below = cand[near & (cand[:, 2] < z - self._tolerance), :2]
            self._reach = reach
        return self._below


def _alpha_shape(pts: np.ndarray, options: AlphaOptions, mean_spacing: float | None,
                 seen_through: _SeenThrough | None = None, mesh: PlanMesh | None = None) -> tuple[AlphaShape, str]:
    """The alpha shape of the outline points, alpha enlarged until it closes, holds together and bridges the sampling."""
    mesh = mesh if mesh is not None else PlanMesh(pts[:, :2])
    status = "ok"
    shape = None
    for scale in _RETRY_SCALES:
        try:
            seen = None if seen_through is None else seen_through.within(
                alpha_reach(mesh, options, mean_spacing=mean_spacing, alpha_scale=scale))
            trial = alpha_shape(pts[:, :2], options, mean_spacing=mean_spacing, alpha_scale=scale,
                                seen_through=seen, mesh=mesh)
        except GeometryError as exc:
            if str(exc) != "no_ring":
                raise
            status = "alpha_enlarged"
            continue
        shape = shape or trial
        if trial.gap_fill >= _GAP_FILL_MAX and scale != _RETRY_SCALES[-1]:
            # the alpha disk does not bridge the sampling's own gaps (between scan lines): where
            # the lines end at an edge it slips in between them, the ring closes or not by chance
            # (13 wall points decided it for a demo building) and, closed, is jagged
            status = "alpha_enlarged"
            continue
        main_area = abs(_area(pts[trial.rings[0], :2]))
        if trial.dropped_area <= max(options.min_hole_area, 0.05 * main_area):
            shape = trial
            break
        # the building fell apart into several rings: a larger alpha joins them
        status = "alpha_enlarged"
    if shape is None:
        raise GeometryError("no_ring")
    if shape.dropped_area > max(options.min_hole_area, 0.05 * abs(_area(pts[shape.rings[0], :2]))):
        status = "multipart"
    return shape, status


def _traced_coverage(pts: np.ndarray, shape: AlphaShape) -> float:
    """Share of the points the alpha shape's rings cover, before any regularisation."""
    rings = [pts[r, :2] for r in shape.rings]
    traced = shapely.Polygon(rings[0], rings[1:])
    traced = traced if traced.is_valid else shapely.make_valid(traced)  # rings may touch at a point
    return outline_coverage(traced, pts[:, :2], shape.spacing * shape.scale)


def _regularised_or_traced(pts, origin, shape: AlphaShape, status: str, options: OutlineOptions, covered: float,
                           context: EdgeContext | None, roof: cKDTree | None) -> RoofOutline:
    """The regularised outline, or the alpha shape's rings when the regularisation gave up points they hold
    or left nothing polygonal to repair."""
    try:
        outline = _outline(pts, origin, shape, status, options, regularise=True, context=context, roof=roof)
    except GeometryError:
        # the regularised rings cross so that no polygon is left (a hole regularised over its shell):
        # the traced rings are still the building's outline
        return _outline(pts, origin, shape, "unregularised", options, regularise=False)
    if outline.coverage < MIN_COVERAGE and covered > outline.coverage:
        # a corner cut off: keep the alpha shape's rings
        outline = _outline(pts, origin, shape, "unregularised", options, regularise=False)
    return outline


def _outline(pts: np.ndarray, origin: np.ndarray, shape: AlphaShape, status: str, options: OutlineOptions, *,
             regularise: bool, context: EdgeContext | None = None, roof: cKDTree | None = None) -> RoofOutline:
    """The outline from an alpha shape's rings, regularised or as traced, its coverage measured."""
    rings, degrees, corners = [], [], []
    sigma = float("nan")
    for i, ring in enumerate(shape.rings):
        spacing = float(np.median(shape.spacing[ring]))
        vertices = None
        if regularise:
            try:
                vertices, corner_index, deg, s = _ring_outline(pts[ring], spacing, options, outer=i == 0,
                                                               context=context, roof=roof)
            except GeometryError:
                vertices = None
        if vertices is None or len(vertices) < 3 or abs(_area(vertices)) < 1e-6:
            # not regularised, or the regularisation collapsed the ring: keep the alpha-shape ring as it is
            if i > 0 and regularise:
                continue
            vertices, corner_index, deg, s = pts[ring], np.arange(len(ring)), [1] * len(ring), 0.0
            status = "unregularised"
        if i == 0:
            sigma = s
        rings.append(vertices + origin)
        degrees.append(list(deg))
        corners.append(corner_index)
    polygon = shapely.Polygon(rings[0], rings[1:])
    if not polygon.is_valid:
        polygon, corners = make_valid_outline(polygon, rings, corners)
        degrees = degrees[: 1 + len(polygon.interiors)] if polygon is not None else []
        status = "repaired"
    if polygon is None or polygon.is_empty:
        raise GeometryError("degenerate_outline")
    # a point may lie outside by its alpha radius: the shape cuts in between points that far apart
    coverage = outline_coverage(polygon, pts[:, :2] + origin[:2], shape.spacing * shape.scale)
    return RoofOutline(0, polygon, degrees, corners, shape.strategy, shape.alpha, len(pts), status, sigma=sigma,
                       coverage=coverage)


def _area(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def outline_buildings(xyz: np.ndarray, building_id: np.ndarray, options: OutlineOptions | None = None, *,
                      mean_spacing: float | None = None, reporter: Reporter | None = None,
                      context_xy: np.ndarray | None = None) -> list[RoofOutline]:
    """Outline every building (ids > 0), sorted by id; degenerate ones get a status, not an exception.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3) float64
    building_id : ndarray of shape (N,) int
        0 (or negative) = not a building.
    options : OutlineOptions, optional
    mean_spacing : float, optional
        Cloud mean spacing s_avg (metres), for the 'global' alpha strategy.
    reporter : Reporter, optional
    context_xy : ndarray of shape (C, 2) or (C, 3) float64, optional
        Plan coordinates (with heights when known) of the points that are no
        building's (ground, vegetation; noise left out), for the edge
        position of the 'lines' regularisation and, with heights, the gaps
        where the ground was seen (:func:`trace_outline`).  The other
        buildings' points always count as not this building's roof.

    Returns
    -------
    list of RoofOutline

    Examples
    --------
    >>> from rooftrace.roof.models import gable, sample_roof
    >>> xyz, _ = sample_roof(gable(), density=12, noise=0.03, seed=1)
    >>> [(o.building_id, o.status) for o in outline_buildings(xyz, np.ones(len(xyz), int))]
    [(1, 'ok')]
    """
    options = options or OutlineOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    building_id = np.asarray(building_id).astype(np.int64)
    if len(building_id) != len(xyz):
        raise ValueError(f"outline_buildings: {len(building_id)} building ids for {len(xyz)} points")
    sel = np.flatnonzero(building_id > 0)
    order = sel[np.argsort(building_id[sel], kind="stable")]
    ids, starts = np.unique(building_id[order], return_index=True)
    groups = np.split(order, starts[1:]) if len(order) else []
    reporter = reporter or Reporter()
    wanted = options.regularize.method == "lines" or options.alpha.seen_through
    around = _Surroundings(xyz[sel], building_id[sel], context_xy) if wanted else None
    outlines = []
    # the regularisation makes thousands of small BLAS calls (curve samples,
    # distances to lines; the CD-spline fits did too before they were
    # compiled); a multi-threaded BLAS turns each into a thread rendezvous:
    # Delft's 34 buildings took 23-25 s with two BLAS threads, 10 s with one
    with reporter.stage("outline", total=len(ids)), threadpool_limits(limits=1, user_api="blas"):
        for bid, idx in zip(ids, groups):
            try:
                context = around.near(xyz[idx, :2], int(bid)) if around is not None else None
                outline = trace_outline(xyz[idx], options, mean_spacing=mean_spacing, context_xy=context)
                outline.building_id = int(bid)
                if outline.status in ("alpha_fallback", "low_coverage"):
                    log.warning("building %d: the %s alpha's shape does not hold 99 %% of its %d points; %s: %s alpha "
                                "%.2f m, coverage %.3f", bid, options.alpha.strategy, len(idx), outline.status,
                                outline.alpha_strategy, outline.alpha, outline.coverage)
            except (GeometryError, ValueError, np.linalg.LinAlgError, QhullError, MemoryError) as exc:
                if not isinstance(exc, GeometryError):  # a bug, but one building must not stop a city
                    log.warning("building %d: outline failed (%s: %s)", bid, type(exc).__name__, exc)
                    exc = GeometryError(f"failed: {type(exc).__name__}")
                z = xyz[idx, 2]
                outline = RoofOutline(int(bid), None, alpha_strategy=options.alpha.strategy, n_points=len(idx),
                                      status=str(exc) or "failed", z_min=float(z.min()), z_mean=float(z.mean()),
                                      z_max=float(z.max()))
                log.debug("building %d: no outline (%s)", bid, outline.status)
            outlines.append(outline)
            reporter.advance()
    return outlines


class _Surroundings:
    """Points around each building that are not its roof: the context points and the other buildings'.

    Sorted by x once, so that a building's neighbourhood is a slice, not a
    scan of the whole cloud per building.
    """

    #: metres around a building's bounding box (the edge looks 3 spacings out)
    margin = 3.0

    def __init__(self, building_xyz: np.ndarray, building_id: np.ndarray, context_xy: np.ndarray | None):
        building_xyz = np.asarray(building_xyz, dtype=np.float64)
        ctx = np.zeros((0, building_xyz.shape[1])) if context_xy is None else np.asarray(context_xy, dtype=np.float64)
        dims = min(building_xyz.shape[1], ctx.shape[1])  # heights only when both have them
        xy = np.concatenate([building_xyz[:, :dims], ctx[:, :dims]])
        owner = np.concatenate([np.asarray(building_id, dtype=np.int64), np.zeros(len(ctx), np.int64)])
        order = np.argsort(xy[:, 0], kind="stable")
        self.xy, self.owner = xy[order], owner[order]

    def near(self, xy: np.ndarray, building: int) -> np.ndarray:
        """The points within ``margin`` of the bounding box of ``xy`` (plan, metres) not of ``building``, heights kept."""
        lo, hi = xy[:, :2].min(axis=0) - self.margin, xy[:, :2].max(axis=0) + self.margin
        a, b = np.searchsorted(self.xy[:, 0], [lo[0], hi[0]])
        cand, own = self.xy[a:b], self.owner[a:b]
        keep = (cand[:, 1] >= lo[1]) & (cand[:, 1] <= hi[1]) & (own != building)
        return cand[keep]


def outlines_layer(outlines: list[RoofOutline], extra_attributes: dict[str, list] | None = None) -> Layer:
    """The ``roof_outlines`` layer (PolygonZ): one feature per outline, failed ones with no geometry.

    Attributes: building_id, n_points, alpha_strategy, alpha, area (m²),
    z_min, z_mean, z_max (m), n_corners, degrees (per ring the segment
    degrees joined by ',' and rings joined by ';', e.g. ``"1,1,2,1;1,1,1,1"``),
    sigma (m), status, coverage (share of the building's points the outline
    covers), plus ``extra_attributes``.
    """
    attrs: dict[str, list] = {
        "building_id": [o.building_id for o in outlines],
        "n_points": [o.n_points for o in outlines],
        "alpha_strategy": [o.alpha_strategy for o in outlines],
        "alpha": [o.alpha for o in outlines],
        "area": [o.area for o in outlines],
        "z_min": [o.z_min for o in outlines],
        "z_mean": [o.z_mean for o in outlines],
        "z_max": [o.z_max for o in outlines],
        "n_corners": [int(sum(len(c) for c in o.corners)) for o in outlines],
        "degrees": [";".join(",".join(map(str, d)) for d in o.degrees) for o in outlines],
        "sigma": [o.sigma for o in outlines],
        "status": [o.status for o in outlines],
        "coverage": [o.coverage for o in outlines],
    }
    for key, values in (extra_attributes or {}).items():
        if len(values) != len(outlines):
            raise ValueError(f"outlines_layer: {key!r} has {len(values)} values for {len(outlines)} outlines")
        attrs[key] = list(values)
    return Layer([o.polygon for o in outlines], attrs, "PolygonZ")


def connected_buildings(xy: np.ndarray, radius: float, min_points: int = 3) -> np.ndarray:
    """Building ids of building points from connected components in plan view.

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
        Building (class 6) points, metres.
    radius : float
        Points closer than this (m) are linked; ~2 * mean spacing (L_Dxy, thesis §3.3).
    min_points : int
        Components with fewer points get id 0.

    Returns
    -------
    ndarray of shape (N,) int64
        1, 2, ... in order of each component's first point; 0 = dropped.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(xy)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), bool), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    big = np.bincount(label) >= min_points
    _, first = np.unique(label, return_index=True)
    order = np.argsort(first)  # components in order of their first point
    rank = np.zeros(len(first), dtype=np.int64)
    kept = order[big[order]]
    rank[kept] = np.arange(1, len(kept) + 1)
    return rank[label]
