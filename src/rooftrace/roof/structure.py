"""The roof polyhedron of one building: planes, faces, ridges, hips, valleys and steps.

:func:`roof_structure` chains the roof stage (DESIGN.md stage 8):

1. segment the roof points into planes and fit them by least squares
   (:func:`rooftrace.roof.segmentation.segment_planes`);
2. find adjacent planes (:func:`rooftrace.roof.adjacency.plane_adjacency`);
3. intersect adjacent planes into ridge, hip and valley lines clipped to
   their shared boundary, ends snapped to junctions and to the outline
   (:func:`rooftrace.roof.ridges.intersection_lines`);
4. split the outline into one face per plane, Z from the plane
   (:func:`rooftrace.roof.faces.partition_outline`);
5. give each face that fits fewer than half of the points under it to the
   plane at hand that fits more (:func:`rooftrace.roof.faces.fit_faces`);
6. step edges where neighbouring faces are at different heights
   (:func:`rooftrace.roof.faces.step_edges`).

:func:`rooftrace.roof.layers.faces_layer` and :func:`rooftrace.roof.layers.ridges_layer`
turn a list of structures into the ``roof_faces`` and ``ridges`` output layers.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.spatial import Delaunay, QhullError

from rooftrace.errors import GeometryError
from rooftrace.roof.adjacency import plane_adjacency
from rooftrace.roof.faces import (
    claim_points,
    fit_faces,
    lift_to_plane,
    merge_close_vertices,
    partition_outline,
    snap_to_lines,
    step_edges,
)
from rooftrace.roof.lowparts import low_blocks
from rooftrace.roof.planes import estimate_spacing, fit_planes, level_untilted
from rooftrace.roof.ridges import intersection_lines
from rooftrace.roof.segmentation import detail_planes, point_neighbourhoods, segment_planes
from rooftrace.roof.steplines import fit_step_boundaries
from rooftrace.roof.superstructures import superstructures

__all__ = ["RoofOptions", "RoofStructure", "roof_structure", "point_hull"]

log = logging.getLogger(__name__)

#: shortest face edge (m): closer face vertices are merged (val3dity snaps vertices within 1 mm, and the models
#: write on a 1 mm grid, so shorter edges come out as repeated points)
MIN_FACE_EDGE = 0.01


@dataclass(frozen=True)
class RoofOptions:
    """Options of the roof-plane and ridge stage (config section ``[planes]``).

    ``None`` means derived from the building's mean point spacing ``s``
    (``mean_spacing`` argument, or ``sqrt(hull area / N)``).

    Attributes
    ----------
    k_neighbours : int
        Neighbours for normals (k-NN PCA) and the region graph.
    normal_angle : float
        Largest normal angle (deg) between two linked points in region growing.
    max_local_rms : float or None
        Largest neighbourhood RMS (m) of a seed point; default ``2 median(rms)``.
    distance : float or None
        Largest height residual (m) of a point to its plane; default
        ``max(3 sigma_n, 0.05)``, ``sigma_n`` the noise of planar neighbourhoods.
    min_area : float
        Smallest roof plane kept (m²); chimneys and small clutter are below.
    min_detail_area : float or None
        Smallest plane (m²) of a second pass over the points left on no
        plane (chimney tops, small dormers, stair houses;
        :func:`rooftrace.roof.segmentation.detail_planes`), holding at least
        ``max(8, min_detail_area / s²)`` points; one whose tilt its points
        do not support is made horizontal.  ``None`` or ``>= min_area``
        turns the pass off.
    min_block_points : int or None
        Fewest points of a flat block (:func:`rooftrace.roof.superstructures.block_planes`):
        the points left on no plane after the second pass that stand more
        than ``step_height`` above the roof under them, on no neighbouring
        plane's extension within ``step_height`` and with no point within
        the spacing standing ``step_height`` higher (the top of a chimney, a
        vent, a parapet's coping, a gable wall's top), are linked into
        clusters, cut from their top in layers of ``step_height``, and each
        layer of at least this many points becomes a horizontal plane at its
        points' mean height when they support it against the roof (AIC);
        its face holding most of its points is kept however small, with no
        lines.  A lone return (a bird, a wire, a multipath echo, or a vent
        pipe) is no block at the default 2.  0 or ``None`` turns it off (and the
        low blocks).
    box_height : float
        With ``min_block_points``: a point on no plane with no point within
        the spacing standing ``step_height`` higher (a top point: a vent
        pipe, a chimney or a roof light of one or two returns, a coping the
        faces put under a lower level) standing at most this high (m) above
        the roof plane under it (higher, a bird or a wire), and every flat
        block's point, is one of ``RoofStructure.top_points``; where the
        LoD 2.2 roof faces leave one more than ``[model] box_rise`` under
        it, the model builds a box of the spacing's side under it, with no
        face of the partition (:func:`rooftrace.model.superstructures.with_boxes`).
        0 turns the boxes off.
    low_blocks : bool
        With ``min_block_points``, the mirror of the flat blocks for what
        lies *under* the roof (:func:`rooftrace.roof.lowparts.low_blocks`):
        each cluster of points on no plane, seen from above, is peeled from
        its bottom in layers of ``step_height`` while a layer lies more than
        that under the plane of its nearest labelled points (terraces,
        balconies, lower roof parts of mixed heights no plane took), each
        layer a horizontal plane with a face but no lines.
    merge_angle : float
        Adjacent coplanar regions within this angle (deg) are merged.
    iterations : int
        Rounds of plane refit and point reassignment.
    max_slope : float
        Steeper regions (deg) are walls, not roof planes (points unassigned).
    adjacency_radius : float or None
        Plan distance (m) between points of two planes that makes them
        adjacent; default ``L = max(2.5 s, 1.5 P90)``, ``P90`` the 90th
        percentile of the plan Delaunay edge lengths: scan lines farther apart
        than the mean spacing (anisotropic patterns) still link across a ridge.
    min_links : int
        Fewest close point pairs for two planes to be adjacent.
    line_tolerance : float or None
        Plan distance (m) of shared-boundary points from an intersection line
        for them to belong to it; default ``L`` (as ``adjacency_radius``).
    snap_distance : float or None
        Largest move (m) of a line end to a junction or the outline; default
        ``max(1.0, 4 s, 1.5 L)``.
    ridge_max_slope : float
        Convex intersection lines flatter than this (deg) are ridges, steeper hips.
    min_ridge_length : float
        Shortest ridge, hip, valley or step line kept (m).
    step_height : float
        Smallest height jump (m) between neighbouring faces for a step edge;
        also the most a point on no plane may stand above a neighbouring
        plane to count as its point in the face partition (a coping, a gutter).
    cell : float or None
        Raster cell (m) of the face partition; default ``s / 2``.  At a
        height step a cell of ``s / 2`` may hold points of both levels and
        put one under the other level's face; ``s / 4`` fits better (and
        its solids are valid), but the run takes 40 % more CPU on AHN3
        Delft without footprints (docs/design-notes.md, the issue's RMSE).
    face_boundaries : {'each', 'held', 'free'}
        How the face boundaries are simplified
        (:func:`rooftrace.roof.faces.partition_outline`): ``'each'`` every
        shared boundary by its own rule, ridges and valleys straight from
        node to node, height steps only as far as no more labelled points
        land under a face more than 0.1 m off their plane; ``'held'`` one
        tolerance per roof, held back by that rule (3.8 times the face
        vertices of ``'free'`` on AHN3 Delft, a 40 % slower run); ``'free'``
        one tolerance of 5 cells (a boundary may leave its height step).
    step_lines : bool
        Each height step between two faces is redrawn as lines fitted to
        separate the two levels' points within ``3 s`` of it
        (:func:`rooftrace.roof.steplines.fit_step_boundaries`), kept where
        they move no labelled point from under a face that fits it and mend
        one or take fewer vertices than the raster's boundary.
    claim_each : bool
        The labelled points the claim of all wedges at once leaves under
        another level (a neighbour's wedge in the way, a face one of the
        wedges on it would cut in two) are claimed one wedge at a time
        (:func:`rooftrace.roof.faces.claim_points`).
    hull_edge : float or None
        Longest triangle edge (m) of the point hull used when no outline is
        given; default ``max(3 s, 2 P95)``, ``P95`` the 95th percentile of
        the Delaunay edge lengths (scan-line patterns have long edges across
        the lines).
    """

    section = "planes"

    k_neighbours: int = 16
    normal_angle: float = 10.0
    max_local_rms: float | None = None
    distance: float | None = None
    min_area: float = 2.0
    min_detail_area: float | None = 0.5
    min_block_points: int | None = 2
    box_height: float = 10.0
    low_blocks: bool = True
    merge_angle: float = 5.0
    iterations: int = 4
    max_slope: float = 75.0
    adjacency_radius: float | None = None
    min_links: int = 3
    line_tolerance: float | None = None
    snap_distance: float | None = None
    ridge_max_slope: float = 5.0
    min_ridge_length: float = 1.0
    step_height: float = 0.5
    cell: float | None = None
    face_boundaries: str = "each"
    step_lines: bool = True
    claim_each: bool = True
    hull_edge: float | None = None

    def __post_init__(self) -> None:
        if int(self.k_neighbours) < 4:
            raise ValueError(f"k_neighbours must be at least 4, got {self.k_neighbours}")
        if int(self.iterations) < 1 or int(self.min_links) < 1:
            raise ValueError("iterations and min_links must be at least 1")
        for name in ("normal_angle", "merge_angle"):
            v = getattr(self, name)
            if not 0 < v < 90:
                raise ValueError(f"{name} must be in (0, 90) degrees, got {v}")
        for name in ("ridge_max_slope", "max_slope"):
            if not 0 <= getattr(self, name) < 90:
                raise ValueError(f"{name} must be in [0, 90) degrees, got {getattr(self, name)}")
        for name in ("min_area", "min_ridge_length", "step_height", "box_height"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.face_boundaries not in ("each", "held", "free"):
            raise ValueError(f"face_boundaries must be 'each', 'held' or 'free', got {self.face_boundaries!r}")
        if self.min_block_points is not None and int(self.min_block_points) < 0:
            raise ValueError(f"min_block_points must be >= 0 or None, got {self.min_block_points}")
        for f in dataclasses.fields(self):
            if f.default is None:
                v = getattr(self, f.name)
                if v is not None and not v > 0:
                    raise ValueError(f"{f.name} must be > 0 or None (derived), got {v}")




@dataclass
class RoofStructure:
    """The roof polyhedron of one building.

    Attributes
    ----------
    building_id : int
    planes : ndarray of shape (K, 4), float64
        ``(a, b, c, d)`` with ``a X + b Y + c Z + d = 0``, unit normal, ``c > 0``.
    plane_sigma : ndarray of shape (K,)
        RMS of the height residuals of each plane's points (m).
    plane_cov : ndarray of shape (K, 3, 3)
        Covariance of ``(p, q, r)`` in ``Z = p (X - cx) + q (Y - cy) + r``
        (``p, q`` unitless slopes, ``r`` in m), ``(cx, cy) = plane_centre[k]``.
        The normalised plane is ``(-p, -q, 1, p cx + q cy - r) / sqrt(1 + p² + q²)``.
    plane_centre : ndarray of shape (K, 2)
        Centroid of each plane's points (m).
    plane_n : ndarray of shape (K,), int
        Points per plane.
    labels : ndarray of shape (N,), int
        Plane per input point, ``-1`` unassigned (walls, noise, structures
        too small for a plane).
    plane_detail : ndarray of shape (K,), bool
        Planes of the segmentation's second pass over the leftover points
        (``RoofOptions.min_detail_area``: chimney tops, small dormers, stair
        houses), numbered after the main planes.  They get faces but no
        ridge, hip, valley or step lines.
    faces : list of shapely Polygon with Z
        Tiling of the outline, Z on the face's plane.
    face_plane : list of int
        Plane index of each face (a plane may have several faces).
    ridges : list of shapely LineString with Z
    ridge_kind : list of str
        ``ridge``, ``hip``, ``valley`` or ``step``.
    ridge_planes : list of tuple of int
        The two planes of each line (for steps: upper, lower).
    outline : shapely Polygon or None
        The plan outline the faces tile.
    spacing : float
        Mean point spacing used (m).
    top_points : ndarray of shape (M, 3), float64
        The top points of what stands on the roof (the flat blocks' points
        and top points on no plane, :func:`rooftrace.roof.superstructures.superstructures`):
        the model puts a box under those its faces leave far under them.
    status : str
        ``ok``, or why the structure is empty or partial (``too_few_points``,
        ``degenerate``, ``no_planes``; with planes but no lines or faces:
        ``no_lines``, ``no_faces``).
    """

    building_id: int = 0
    planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    plane_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    plane_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    plane_centre: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    plane_n: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    labels: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    plane_detail: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    faces: list = field(default_factory=list)
    face_plane: list = field(default_factory=list)
    ridges: list = field(default_factory=list)
    ridge_kind: list = field(default_factory=list)
    ridge_planes: list = field(default_factory=list)
    outline: object = None
    spacing: float = float("nan")
    top_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    status: str = "ok"

    @property
    def slope_deg(self) -> np.ndarray:
        """Slope of each plane (deg from horizontal)."""
        return np.degrees(np.arccos(np.clip(self.planes[:, 2], -1.0, 1.0)))

    @property
    def aspect_deg(self) -> np.ndarray:
        """Direction each plane faces (downslope), deg clockwise from north
        (0 north, 90 east); NaN for a flat plane (slope under 1°, where the
        direction is noise)."""
        a, b = self.planes[:, 0], self.planes[:, 1]
        asp = np.degrees(np.arctan2(a, b)) % 360.0
        return np.where(self.slope_deg < 1.0, np.nan, asp)


def point_hull(xy: np.ndarray, max_edge: float | None = None, *, floor: float = 0.0):
    """Plan outline of points: union of Delaunay triangles with no edge over ``max_edge`` (m).

    The default ``max_edge`` is ``max(floor, 2 P95)``, ``P95`` the 95th
    percentile of the Delaunay edge lengths, which adapts to anisotropic patterns (scan lines farther
    apart than the along-line spacing).  The largest polygon is returned; the
    convex hull when the triangles do not make one.
    """
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    try:
        tri = Delaunay(xy)
    except QhullError:
        raise GeometryError("cannot outline the points: they are collinear") from None
    s = tri.simplices
    p = xy[s]
    e = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2)
    if max_edge is None:
        max_edge = max(floor, 2.0 * float(np.percentile(e, 95)))
    e = e.max(axis=1)
    # Duplicated points (overlapping strips) leave zero-area triangles.
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]) / 2
    e[area < 1e-9] = np.inf
    keep = s[e <= max_edge]
    if len(keep) == 0:
        return shapely.convex_hull(shapely.multipoints(xy))
    polys = shapely.polygons(xy[keep])
    try:
        u = shapely.coverage_union_all(polys)
    except shapely.errors.GEOSException:
        u = shapely.union_all(polys)
    parts = list(getattr(u, "geoms", [u]))
    return max(parts, key=lambda g: g.area)


def _edge_percentile(xyz: np.ndarray, q: float) -> float:
    """Percentile ``q`` of the plan Delaunay edge lengths (m)."""
    try:
        p = xyz[Delaunay(xyz[:, :2]).simplices][:, :, :2]
    except QhullError:
        return 0.0
    return float(np.percentile(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2), q))


def _empty(building_id, n, status, spacing=float("nan"), outline=None) -> RoofStructure:
    return RoofStructure(building_id=building_id, labels=np.full(n, -1, np.int64), status=status, spacing=spacing, outline=outline)


def roof_structure(xyz, outline=None, options: RoofOptions | None = None, *, mean_spacing: float | None = None,
                   building_id: int = 0, detected: np.ndarray | None = None) -> RoofStructure:
    """Roof planes, faces and ridge lines of one building.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        The building's roof points in a projected CRS (m).
    outline : shapely Polygon, optional
        The roof outline (Z ignored, holes allowed).  Default: the hull of
        the points (:func:`point_hull` with ``options.hull_edge``).
    options : RoofOptions, optional
    mean_spacing : float, optional
        Mean point spacing ``s`` (m); default ``sqrt(hull area / N)``.
    building_id : int
    detected : ndarray of shape (N,), bool, optional
        The points the detection calls building (default all), when the
        building also holds others (points a footprint took in): only the
        detected points hide a point under them from the roof faces, and
        they decide a face's fit first
        (:func:`rooftrace.roof.faces.fit_faces`).  The pipeline does not
        give it: with the footprints' tree test no crown joins a building,
        and it measured 0.198 against 0.196 m without (docs/design-notes.md).

    Returns
    -------
    RoofStructure
        Degenerate input (too few points, collinear points, no planar
        region) does not raise: the structure is empty and ``status`` says why.

    Examples
    --------
    >>> from rooftrace.roof.models import gable, sample_roof
    >>> xyz, _ = sample_roof(gable(), density=12, noise=0.03, seed=1)
    >>> roof = roof_structure(xyz)
    >>> len(roof.planes), roof.ridge_kind
    (2, ['ridge'])
    """
    opt = options or RoofOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
    if not np.isfinite(xyz).all():
        raise ValueError("xyz holds NaN or infinite coordinates")
    n = len(xyz)
    if detected is not None and np.shape(detected) != (n,):
        raise ValueError(f"detected must have shape ({n},), got {np.shape(detected)}")
    if n < max(10, opt.k_neighbours):
        return _empty(building_id, n, "too_few_points")
    try:
        ok = mean_spacing is not None and np.isfinite(mean_spacing) and mean_spacing > 0
        s = float(mean_spacing) if ok else estimate_spacing(xyz)
    except GeometryError:
        return _empty(building_id, n, "degenerate")
    if outline is None:
        try:
            outline = point_hull(xyz, opt.hull_edge, floor=3.0 * s)
        except GeometryError:
            return _empty(building_id, n, "degenerate", s)
    outline2d = shapely.make_valid(shapely.force_2d(outline))
    if outline2d.geom_type != "Polygon":
        parts = [g for g in getattr(outline2d, "geoms", []) if g.geom_type == "Polygon"]
        outline2d = max(parts, key=lambda g: g.area) if parts else outline2d
    link = max(2.5 * s, 1.5 * _edge_percentile(xyz, 90))
    # one neighbour search for both segmentation passes
    neighbourhoods = point_neighbourhoods(xyz, opt.k_neighbours)
    try:
        labels, fit, tol = segment_planes(
            xyz, s, k=opt.k_neighbours, normal_angle=opt.normal_angle, max_local_rms=opt.max_local_rms,
            distance=opt.distance, min_area=opt.min_area, merge_angle=opt.merge_angle, iterations=opt.iterations,
            max_slope=opt.max_slope, link=opt.adjacency_radius or link, neighbourhoods=neighbourhoods,
        )
    except GeometryError as exc:
        log.debug("building %s: %s", building_id, exc)
        return _empty(building_id, n, "no_planes", s, outline2d)
    # The lines are made of the main planes only: superstructures (the
    # second pass's planes) get faces, not ridges, hips or steps.
    main, n_main = labels, len(fit.planes)
    if opt.min_detail_area is not None and opt.min_detail_area < opt.min_area:
        labels = detail_planes(xyz, labels, s, distance=tol, min_area=opt.min_detail_area, k=opt.k_neighbours,
                               max_slope=opt.max_slope, link=opt.adjacency_radius or link,
                               neighbourhoods=neighbourhoods)
        if labels.max() + 1 > n_main:
            fit = fit_planes(xyz, labels)
    detail = np.arange(len(fit.planes)) >= n_main
    if detail.any():
        fit = level_untilted(xyz, labels, fit, detail)
    blocks, tops = None, np.zeros(0, dtype=np.int64)
    if opt.min_block_points:
        n_planes = len(fit.planes)
        found = superstructures(xyz, labels, fit, s, min_points=opt.min_block_points, rise=opt.step_height,
                                link=opt.adjacency_radius or link, box_height=opt.box_height)
        labels, fit, tops = found.labels, found.fit, found.tops
        n_blocks = len(fit.planes)
        if opt.low_blocks:
            # (at their own fewest points, 4: the low blocks were measured so)
            labels, fit = low_blocks(xyz, labels, fit, s, rise=opt.step_height, link=opt.adjacency_radius or link)
        detail = np.arange(len(fit.planes)) >= n_main
        # the faces of the blocks on the roof are kept however small: a chimney of two points
        blocks = np.zeros(len(fit.planes), dtype=bool)
        blocks[n_planes:n_blocks] = True
    roof = RoofStructure(
        building_id=building_id, planes=fit.planes, plane_sigma=fit.sigma, plane_cov=fit.cov,
        plane_centre=fit.centre, plane_n=fit.n, labels=labels, outline=outline2d, spacing=s,
        plane_detail=detail, top_points=xyz[tops],
    )
    radius = opt.adjacency_radius or link
    line_tol = opt.line_tolerance or link
    adj = plane_adjacency(xyz, main, fit.planes, radius, opt.min_links)
    # Geometry kernels can still fail on odd outlines (GEOS topology errors):
    # the planes stand, the building gets a status, the run goes on.
    try:
        lines = intersection_lines(
            fit.planes, adj, outline2d, line_tolerance=line_tol,
            snap=opt.snap_distance or max(1.0, 4.0 * s, 1.5 * link), ridge_max_slope=opt.ridge_max_slope,
            min_length=opt.min_ridge_length, xyz=xyz, labels=main,
        )
    except (GeometryError, shapely.errors.GEOSException, ValueError) as exc:
        log.warning("building %s: no ridge lines (%s)", building_id, exc)
        roof.status = "no_lines"
        return roof
    roof.ridges, roof.ridge_kind, roof.ridge_planes = list(lines.lines), list(lines.kinds), list(lines.pairs)
    cell = opt.cell or s / 2
    try:
        polys, pids = partition_outline(
            outline2d, xyz, labels, fit.planes, lines, cell=cell, line_tolerance=line_tol,
            boundaries=opt.face_boundaries, plane_sigma=fit.sigma, rise=opt.step_height, kept_planes=blocks,
        )
        polys = snap_to_lines(polys, lines.lines, outline2d, 2.0 * cell)
        # a lower level's returns within s of a point of a main roof plane (twice the smallest plane) standing
        # step_height higher lie under its eave: they neither place its step nor stop its claim
        eaves = (np.arange(len(fit.planes)) < n_main) & (fit.n * s**2 >= 2 * opt.min_area)
        hide = dict(hidden_within=s, overhanging=eaves)
        if opt.step_lines:
            # the height steps as lines between the two levels' points, not the raster's staircase
            polys, pids = fit_step_boundaries(polys, pids, xyz, labels, fit.planes, step_height=opt.step_height,
                                              band=3.0 * s, run_tolerance=s, rise=opt.step_height, **hide)
        # the edge rows of roof levels the raster, the simplification or the slivers left under another level
        polys, pids = claim_points(polys, pids, outline2d, xyz, labels, fit.planes, radius=2 * s, width=cell,
                                   step_height=opt.step_height, one_by_one=opt.claim_each, **hide)
        # the faces left over points of another level (a sliver merged into a small neighbour, a messy corner)
        polys, pids = fit_faces(polys, pids, xyz, labels, fit.planes, spacing=s, rise=opt.step_height,
                                detected=detected)
        polys = merge_close_vertices(polys, outline2d, MIN_FACE_EDGE)
    except (GeometryError, shapely.errors.GEOSException, ValueError) as exc:
        log.warning("building %s: no roof faces (%s)", building_id, exc)
        roof.status = "no_faces"
        return roof
    roof.faces = list(lift_to_plane(np.array(polys, dtype=object), fit.planes[list(pids)])) if polys else []
    roof.face_plane = list(pids)
    try:
        steps, spairs = step_edges(polys, pids, fit.planes, step_height=opt.step_height,
                                    min_length=opt.min_ridge_length, simplify=cell / 2)
    except (shapely.errors.GEOSException, ValueError) as exc:
        log.warning("building %s: no step edges (%s)", building_id, exc)
        steps, spairs = [], []
    kept = [i for i, pair in enumerate(spairs) if max(pair) < n_main]
    roof.ridges += [steps[i] for i in kept]
    roof.ridge_kind += ["step"] * len(kept)
    roof.ridge_planes += [spairs[i] for i in kept]
    if not roof.faces:
        roof.status = "no_faces"
    return roof
