"""Quality metrics of extracted roof outlines against a reference (thesis §3.5).

Area-based scores (completeness, correctness, F-score, ISPRS quality),
line-based distances (Hausdorff, PoLiS in 2D and 3D, RMSE of reference
vertices in x, y, z), corner scores of the shape (count ratio, completeness,
correctness, offset) and buffer scores of ridge lines.

Conventions shared by every function:

* a polygon's vertices are those of all its rings (outer ring and holes, and
  of every part of a MultiPolygon), each ring's closing vertex counted once;
* distances are in the units of the CRS (metres for projected CRSs);
* a ``None`` or empty geometry gives NaN (shapely's convention), never an error.

Rings, segments and the closest-point search live in
:mod:`rooftrace.evaluate.geometry`; what a corner is, in
:mod:`rooftrace.evaluate.corners`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from rooftrace.evaluate.corners import COLLINEAR_TOLERANCE, CURVE_TURN, match_corners, outline_corners
from rooftrace.evaluate.geometry import closest_on_segments, polygonal, ring_segments, ring_vertices

__all__ = [
    "polis",
    "hausdorff",
    "rmse_xyz",
    "vertex_residuals",
    "area_scores",
    "boundary_errors",
    "ridge_scores",
    "corner_metrics",
    "outline_corners",
    "ring_vertices",
    "ring_segments",
]

log = logging.getLogger(__name__)


def _directed_mean(a: BaseGeometry, b: BaseGeometry, dim: int) -> float:
    verts = ring_vertices(a)
    if dim == 2:
        return float(shapely.distance(shapely.points(verts[:, :2]), b.boundary).mean())
    p0, p1 = ring_segments(b)
    foot = closest_on_segments(verts, p0, p1, 3)
    return float(np.linalg.norm(verts - foot, axis=1).mean())


def _check_dim(dim) -> int:
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)):
        raise TypeError(f"dim must be 2 or 3, not {dim!r}")
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, not {dim}")
    return int(dim)


def polis(a, b, *, dim: int = 2) -> float:
    """PoLiS distance between two polygons (Avbelj et al. 2015; thesis eq. 3.15).

    ``p(A, B) = 1/(2q) Σ_{a_j} d(a_j, ∂B) + 1/(2r) Σ_{b_k} d(b_k, ∂A)``: the
    symmetric mean of the distances from the vertices of each polygon to the
    boundary of the other.

    Parameters
    ----------
    a, b : Polygon or MultiPolygon (or a sequence of them, unioned)
        Vertices of all rings count (outer and holes), the closing vertex
        once; distances are to the whole boundary (all rings).
    dim : {2, 3}, default 2
        2: planimetric distances (z ignored). 3: Euclidean distances in 3D to
        the 3D boundary segments; both geometries must carry z.

    Returns
    -------
    float
        In CRS units (m). NaN when either geometry is None or empty.

    Raises
    ------
    ValueError
        ``dim=3`` on a geometry without z, or ``dim`` not 2 or 3.

    References
    ----------
    Avbelj J., Müller R., Bamler R. (2015). A metric for polygon comparison
    and building extraction evaluation. IEEE GRSL 12(1), 170–174.
    doi:10.1109/LGRS.2014.2330695

    Examples
    --------
    >>> from shapely import box
    >>> polis(box(0, 0, 10, 10), box(2, 0, 12, 10))
    1.0
    """
    dim = _check_dim(dim)
    a, b = polygonal(a, "a"), polygonal(b, "b")
    if a is None or b is None:
        return math.nan
    if dim == 3 and not (shapely.has_z(a) and shapely.has_z(b)):
        raise ValueError("polis(dim=3) needs both polygons with z coordinates")
    return 0.5 * _directed_mean(a, b, dim) + 0.5 * _directed_mean(b, a, dim)


def hausdorff(a, b, *, densify: float | None = None) -> float:
    """Hausdorff distance between the boundaries of two polygons (thesis eq. 3.13).

    Computed as ``shapely.hausdorff_distance(a.boundary, b.boundary)``, i.e.
    GEOS's discrete Hausdorff distance: vertices of each boundary against the
    other boundary. It is exact for polygons whose farthest points are
    vertices (the usual case for outlines); ``densify`` (a fraction in (0, 1]
    of each segment) adds points along the segments for the general case.

    Parameters
    ----------
    a, b : Polygon or MultiPolygon (or sequences, unioned)
    densify : float, optional

    Returns
    -------
    float
        Planimetric distance in CRS units; NaN when either is None or empty.

    Examples
    --------
    >>> from shapely import box
    >>> hausdorff(box(0, 0, 10, 10), box(2, 0, 12, 10))
    2.0
    """
    a, b = polygonal(a, "a"), polygonal(b, "b")
    if a is None or b is None:
        return math.nan
    if densify is None:
        return float(shapely.hausdorff_distance(a.boundary, b.boundary))
    return float(shapely.hausdorff_distance(a.boundary, b.boundary, densify=densify))


def vertex_residuals(reference, extracted, *, step_tolerance: float = 0.005) -> np.ndarray:
    """Extracted minus reference coordinates at every reference vertex.

    For each reference vertex the planimetrically closest point on the
    extracted boundary gives dx, dy.  dz is taken, among the points of the
    extracted boundary within ``step_tolerance`` in plan of that closest
    point, at the one whose z is closest to the vertex's (z interpolated
    linearly along the extracted segments; a vertical segment offers its two
    ends).  Without a vertical step this changes dz by at most
    ``step_tolerance`` times the outline's slope.

    Parameters
    ----------
    reference, extracted : Polygon or MultiPolygon
    step_tolerance : float, default 0.005
        Plan distance of the z candidates from the closest point, in CRS
        units (m).  At a vertical step of a 3D outline (an annex meeting the
        main roof: two vertices at one xy) the plan-closest point is
        ambiguous, and the first segment found may carry the other roof's
        height.  5 mm is far above the rounding of projected coordinates
        (~1e-10 m) and covers steps whose two vertices were written a few mm
        apart, while staying well below outline errors (cm to dm), so no
        other part of the outline competes.

    Returns
    -------
    ndarray of shape (N, 3) float64
        dx, dy, dz in CRS units, one row per reference vertex; dz is NaN when
        either geometry has no z. Empty (0, 3) when either is None/empty.

    Raises
    ------
    TypeError, ValueError
        ``step_tolerance`` not a number, or negative.

    Examples
    --------
    A vertical step at x = 4 (the annex at z = 3, the main roof at z = 8):
    the reference corner on the main roof is measured against the main roof.

    >>> from shapely import Polygon
    >>> step = [(0, 0, 3), (4, 0, 3), (4, 0, 8), (10, 0, 8), (10, 5, 8), (0, 5, 3)]
    >>> vertex_residuals(Polygon(step), Polygon(step))[2].tolist()
    [0.0, 0.0, 0.0]
    """
    if isinstance(step_tolerance, bool) or not isinstance(step_tolerance, (int, float, np.floating)):
        raise TypeError(f"step_tolerance must be a number, not {step_tolerance!r}")
    if not step_tolerance >= 0:
        raise ValueError(f"step_tolerance must be >= 0, not {step_tolerance}")
    ref, ext = polygonal(reference, "reference"), polygonal(extracted, "extracted")
    if ref is None or ext is None:
        return np.empty((0, 3))
    verts = ring_vertices(ref)
    p0, p1 = ring_segments(ext)
    return closest_on_segments(verts, p0, p1, 2, z_tie=float(step_tolerance)) - verts


def rmse_xyz(reference, extracted, *, step_tolerance: float = 0.005) -> tuple[float, float, float]:
    """RMSE in x, y and z of the reference vertices (thesis eq. 3.16).

    Discrepancies are taken against the closest points on the extracted
    outline, z on the side of a vertical step nearest to the vertex's z (see
    :func:`vertex_residuals`, which also describes ``step_tolerance``).

    Returns
    -------
    (float, float, float)
        RMSE x, y, z in CRS units (m); z is NaN for 2D input, all NaN when
        either geometry is None or empty.

    Examples
    --------
    >>> from shapely import box
    >>> rmse_xyz(box(0, 0, 10, 10), box(2, 0, 12, 10))[:2]
    (1.4142135623730951, 0.0)
    """
    res = vertex_residuals(reference, extracted, step_tolerance=step_tolerance)
    if len(res) == 0:
        return (math.nan, math.nan, math.nan)
    r = np.sqrt(np.mean(res ** 2, axis=0))
    return (float(r[0]), float(r[1]), float(r[2]))


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0 else math.nan


def area_scores(extracted, reference) -> dict[str, float]:
    """Area-based completeness, correctness, F-score and quality (thesis eq. 3.10–3.12).

    TP = area(E ∩ R), FN = area(R) − TP, FP = area(E) − TP, with E and R the
    unions of the extracted and reference polygons (planimetric areas).

    Parameters
    ----------
    extracted, reference : Polygon, MultiPolygon, a sequence of them, or None

    Returns
    -------
    dict
        ``completeness`` TP/(TP+FN), ``correctness`` TP/(TP+FP),
        ``f_score`` 2TP/(2TP+FP+FN) (the harmonic mean of the two),
        ``quality`` TP/(TP+FN+FP) (ISPRS), all in [0, 1]; and the areas
        ``tp``, ``fn``, ``fp`` (CRS units²).
        A score whose denominator is zero is NaN: completeness without
        reference, correctness without extraction, F-score and quality when
        both are empty. With only one side empty, F-score and quality are 0.

    Examples
    --------
    >>> from shapely import box
    >>> s = area_scores(box(0, 0, 10, 10), box(5, 0, 15, 10))
    >>> s["completeness"], s["correctness"], s["quality"]
    (0.5, 0.5, 0.3333333333333333)
    """
    ext, ref = polygonal(extracted, "extracted"), polygonal(reference, "reference")
    area_e = float(ext.area) if ext is not None else 0.0
    area_r = float(ref.area) if ref is not None else 0.0
    tp = float(shapely.intersection(ext, ref).area) if ext is not None and ref is not None else 0.0
    # rounding in the overlay can leave TP a hair above an area; keep FN, FP >= 0
    tp = min(tp, area_e, area_r)
    fn, fp = area_r - tp, area_e - tp
    return {
        "completeness": _ratio(tp, tp + fn),
        "correctness": _ratio(tp, tp + fp),
        "f_score": _ratio(2 * tp, 2 * tp + fp + fn),
        "quality": _ratio(tp, tp + fn + fp),
        "tp": tp,
        "fn": fn,
        "fp": fp,
    }


def corner_metrics(extracted, reference, tolerance: float = 0.5, *,
                   collinear_tolerance: float = COLLINEAR_TOLERANCE,
                   curve_turn: float = CURVE_TURN) -> dict:
    """Corner scores of an extracted outline against its reference: is it the same shape?

    Corners are those of :func:`~rooftrace.evaluate.corners.outline_corners`
    (a vertex where the ring turns, collinear vertices within 2 cm and
    vertices along curves set aside). They are matched one-to-one within
    ``tolerance``: the most pairs, then the smallest total distance.

    Parameters
    ----------
    extracted, reference : Polygon, MultiPolygon, a sequence of them, or None
    tolerance : float, default 0.5
        Largest distance of a matched corner pair (CRS units, m).
    collinear_tolerance, curve_turn : float
        Passed to :func:`~rooftrace.evaluate.corners.outline_corners` (m, degrees).

    Returns
    -------
    dict
        ``n_corners``, ``n_corners_reference``, ``n_corners_matched``
        (counts); ``corner_ratio`` n_corners / n_corners_reference (1 is the
        reference's count, 2 twice as many corners; NaN when the reference
        has none); ``corner_completeness`` the share of reference corners
        matched and ``corner_correctness`` the share of extracted corners
        matched (0–1; NaN when that side has no corner);
        ``corner_offset`` the mean distance of the matched pairs (m; NaN
        without pairs).

    Examples
    --------
    A rectangle against an L-shaped reference sharing three of its corners:

    >>> from shapely import Polygon, box
    >>> ell = Polygon([(0, 0), (10, 0), (10, 4), (6, 4), (6, 8), (0, 8)])
    >>> c = corner_metrics(box(0, 0, 10, 8), ell)
    >>> c["n_corners"], c["n_corners_reference"], c["corner_completeness"], c["corner_correctness"]
    (4, 6, 0.5, 0.75)
    """
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float, np.floating)):
        raise TypeError(f"tolerance must be a number, not {tolerance!r}")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, not {tolerance}")
    opts = {"collinear_tolerance": collinear_tolerance, "curve_turn": curve_turn}
    ce = outline_corners(polygonal(extracted, "extracted"), **opts)
    cr = outline_corners(polygonal(reference, "reference"), **opts)
    pairs, dist = match_corners(ce, cr, float(tolerance))
    ne, nr, nm = len(ce), len(cr), len(pairs)
    return {
        "n_corners": ne,
        "n_corners_reference": nr,
        "n_corners_matched": nm,
        "corner_ratio": _ratio(ne, nr),
        "corner_completeness": _ratio(nm, nr),
        "corner_correctness": _ratio(nm, ne),
        "corner_offset": float(dist.mean()) if nm else math.nan,
    }


def boundary_errors(extracted, reference, band: float = 1.0, *, boundary=None) -> dict[str, float]:
    """The FP and FN area lying within ``band`` of the reference boundary.

    These are errors of where the outline runs, not of which buildings were
    found: against a footprint drawn at the walls (a cadastre), the eaves of
    a correct roof outline are FP in this band; a missed or extra building
    lies mostly outside it, unless it is narrower than twice the band (a
    2.5 m garden shed lies wholly within 1 m of its walls).

    Parameters
    ----------
    extracted, reference : Polygon, MultiPolygon, a sequence of them, or None
    band : float, default 1.0
        Half-width of the band around the reference boundary (CRS units, m).
    boundary : geometry, optional
        The lines the band runs along; default the reference's boundary.
        When both sides were clipped to an area of interest, pass the
        boundary of the unclipped reference, so that the cut is no boundary.

    Returns
    -------
    dict
        ``fp_boundary``, ``fn_boundary`` (CRS units²); 0 when either side is empty.

    Examples
    --------
    >>> from shapely import box
    >>> e = boundary_errors(box(-0.5, 0, 10, 10), box(0, 0, 10, 10))  # a 0.5 m eave on one side
    >>> e["fp_boundary"], e["fn_boundary"]
    (5.0, 0.0)
    """
    if not band > 0:
        raise ValueError(f"band must be > 0, not {band}")
    ext, ref = polygonal(extracted, "extracted"), polygonal(reference, "reference")
    if ext is None or ref is None:
        return {"fp_boundary": 0.0, "fn_boundary": 0.0}
    near = shapely.buffer(ref.boundary if boundary is None else boundary, band)
    return {"fp_boundary": float(shapely.difference(ext, ref).intersection(near).area),
            "fn_boundary": float(shapely.difference(ref, ext).intersection(near).area)}


def _lines(geoms, name: str) -> BaseGeometry | None:
    if geoms is None:
        return None
    if isinstance(geoms, BaseGeometry):
        geoms = [geoms]
    parts = [g for g in geoms if g is not None and not g.is_empty]
    for g in parts:
        if not isinstance(g, (shapely.LineString, shapely.MultiLineString)):
            raise TypeError(f"{name} must hold LineStrings, not {g.geom_type}")
    return shapely.union_all(np.asarray(parts, dtype=object)) if parts else None


def _sample(lines: BaseGeometry, step: float) -> np.ndarray:
    """Points every ``step`` along each line (ends included), as an array of shapely Points."""
    out = []
    for line in shapely.get_parts(lines):
        n = max(1, int(math.ceil(line.length / step)))
        out.append(shapely.line_interpolate_point(line, np.linspace(0.0, line.length, n + 1)))
    return np.concatenate(out) if out else np.empty(0, dtype=object)


def ridge_scores(extracted: Iterable | None, reference: Iterable | None, buffer: float = 0.5) -> dict:
    """Buffer-based completeness and correctness of ridge lines, and their position error.

    Completeness is the fraction of the reference ridge length lying within
    ``buffer`` of an extracted ridge; correctness the fraction of the
    extracted length within ``buffer`` of a reference ridge (Heipke et al.
    1997). The position error is the mean planimetric distance to the
    reference ridges of points sampled every ``buffer / 5`` along the
    extracted ridges, over those that lie within the buffer (the matched part).

    Parameters
    ----------
    extracted, reference : sequence of LineString / MultiLineString, or None
    buffer : float, default 0.5
        Buffer half-width in CRS units (m).

    Returns
    -------
    dict
        ``ridge_completeness``, ``ridge_correctness`` (0–1; NaN when the
        denominator length is zero), ``ridge_position_error`` (m; NaN when no
        extracted ridge lies within the buffer), ``n_ridges_reference``,
        ``n_ridges_extracted`` (counts of line parts).
    """
    if not isinstance(buffer, (int, float)) or isinstance(buffer, bool):
        raise TypeError(f"buffer must be a number, not {buffer!r}")
    if not buffer > 0:
        raise ValueError(f"buffer must be > 0, not {buffer}")
    ext, ref = _lines(extracted, "extracted"), _lines(reference, "reference")
    n_e = len(shapely.get_parts(ext)) if ext is not None else 0
    n_r = len(shapely.get_parts(ref)) if ref is not None else 0
    len_e = float(ext.length) if ext is not None else 0.0
    len_r = float(ref.length) if ref is not None else 0.0
    comp = corr = err = math.nan
    if ext is not None and ref is not None:
        buf_e, buf_r = ext.buffer(buffer), ref.buffer(buffer)
        comp = _ratio(float(ref.intersection(buf_e).length), len_r)
        corr = _ratio(float(ext.intersection(buf_r).length), len_e)
        d = shapely.distance(_sample(ext, buffer / 5.0), ref)
        d = d[d <= buffer]
        err = float(d.mean()) if len(d) else math.nan
    elif ext is None and ref is not None:
        comp = 0.0
    elif ref is None and ext is not None:
        corr = 0.0
    return {
        "ridge_completeness": comp,
        "ridge_correctness": corr,
        "ridge_position_error": err,
        "n_ridges_reference": n_r,
        "n_ridges_extracted": n_e,
    }
