"""Quality evaluation of extracted roof outlines and ridges against a reference (stage 11).

:func:`evaluate` gives the content of ``metrics.json``; the metric functions
live in :mod:`rooftrace.evaluate.metrics`, the matching in
:mod:`rooftrace.evaluate.matching` and the HTML report in
:mod:`rooftrace.evaluate.report`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
import shapely

from rooftrace.evaluate.matching import coverage, match_buildings
from rooftrace.evaluate.metrics import (
    area_scores,
    boundary_errors,
    corner_metrics,
    hausdorff,
    polis,
    ridge_scores,
    vertex_residuals,
)

__all__ = ["evaluate", "SUMMARY_KEYS"]

log = logging.getLogger(__name__)

#: scene-level keys printed in summaries (the table and ``--json``), in order
SUMMARY_KEYS = (
    "completeness", "correctness", "f_score", "quality",
    "fn_area", "fp_area", "fn_area_boundary", "fp_area_boundary",
    "object_completeness", "object_correctness",
    "polis_mean", "polis_3d_mean", "hausdorff_mean", "rmse_x", "rmse_y", "rmse_z",
    "corner_ratio_median", "corner_ratio_within_1_5", "corner_completeness", "corner_correctness",
    "corner_offset_mean",
    "n_reference", "n_extracted", "n_matched", "n_matched_merged", "n_reference_in_merged",
    "n_extracted_in_merged", "n_missed", "n_false_positive",
    "ridge_completeness", "ridge_correctness", "ridge_position_error",
)


def _clean_polygons(geoms, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Valid, non-empty polygons and their indices in the input sequence."""
    out, keep = [], []
    for i, g in enumerate(geoms):
        if g is None or g.is_empty:
            continue
        if not isinstance(g, (shapely.Polygon, shapely.MultiPolygon)):
            raise TypeError(f"{name}[{i}] must be a Polygon or MultiPolygon, not {g.geom_type}")
        if not g.is_valid:
            fixed = shapely.make_valid(g)
            polys = [p for p in shapely.get_parts(fixed) if isinstance(p, shapely.Polygon) and p.area > 0]
            log.warning("%s polygon %d is invalid (%s); evaluated after make_valid",
                        name, i, shapely.is_valid_reason(g))
            if not polys:
                continue
            g = polys[0] if len(polys) == 1 else shapely.MultiPolygon(polys)
        if g.area <= 0:
            continue
        out.append(g)
        keep.append(i)
    dropped = len(geoms) - len(keep)
    if dropped:
        log.warning("%d %s geometries are empty or have no area; they are ignored", dropped, name)
    return np.asarray(out, dtype=object), np.asarray(keep, dtype=np.int64)


def _in_aoi(geoms: np.ndarray, aoi) -> np.ndarray:
    if aoi is None or len(geoms) == 0:
        return np.ones(len(geoms), dtype=bool)
    return shapely.contains_xy(aoi, shapely.get_coordinates(shapely.point_on_surface(geoms)))


def _unit_geometry(geoms: np.ndarray, ids: tuple[int, ...]):
    if len(ids) == 1:
        return geoms[ids[0]]
    # collinear vertices left where parts met would count as vertices in PoLiS
    return shapely.simplify(shapely.union_all(geoms[list(ids)]), 0.0)


def _nan_mean(values) -> float:
    v = np.asarray([x for x in values if x is not None and not math.isnan(x)], dtype=float)
    return float(v.mean()) if len(v) else math.nan


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


#: a unit's corner count is "within 1.5×" the reference's when their ratio lies in [1/1.5, 1.5]
_CORNER_RATIO_BAND = 1.5


def _corner_summary(matched: list[dict], tolerance: float) -> dict:
    """Scene-level corner scores over the matched units: pooled counts, median ratio."""
    n_e = sum(b["n_corners"] for b in matched)
    n_r = sum(b["n_corners_reference"] for b in matched)
    n_m = sum(b["n_corners_matched"] for b in matched)
    ratios = np.asarray([b["corner_ratio"] for b in matched if b["n_corners_reference"] > 0], dtype=float)
    offset = sum(b["corner_offset"] * b["n_corners_matched"] for b in matched if b["n_corners_matched"])
    within = (ratios >= 1 / _CORNER_RATIO_BAND) & (ratios <= _CORNER_RATIO_BAND)
    return {
        "corner_ratio_median": float(np.median(ratios)) if len(ratios) else math.nan,
        "corner_ratio_within_1_5": float(within.mean()) if len(ratios) else math.nan,
        "corner_completeness": n_m / n_r if n_r else math.nan,
        "corner_correctness": n_m / n_e if n_e else math.nan,
        "corner_offset_mean": offset / n_m if n_m else math.nan,
        "n_corners": n_e, "n_corners_reference": n_r, "n_corners_matched": n_m,
        "corner_tolerance": float(tolerance),
    }


def _unit_counts(buildings: list[dict]) -> dict:
    """How the buildings form units: one to one, merged blocks, missed, false detections."""
    matched = [b for b in buildings if b["status"] == "matched"]
    merged = [b for b in matched if len(b["reference_ids"]) > 1 or len(b["extracted_ids"]) > 1]
    return {
        "n_matched_one_to_one": len(matched) - len(merged),
        "n_matched_merged": len(merged),
        "n_reference_in_merged": sum(len(b["reference_ids"]) for b in merged),
        "n_extracted_in_merged": sum(len(b["extracted_ids"]) for b in merged),
        "n_missed": sum(b["status"] == "missed" for b in buildings),
        "n_false_positive": sum(b["status"] == "false_positive" for b in buildings),
    }


def _unit_record(k, e_ids, r_ids, ext, ref, ext_keep, ref_keep, ext_labels, ref_labels,
                 corner_tolerance) -> dict:
    e = _unit_geometry(ext, e_ids) if e_ids else None
    r = _unit_geometry(ref, r_ids) if r_ids else None
    status = "matched" if e_ids and r_ids else ("missed" if r_ids else "false_positive")
    rec = {
        "unit": k,
        "status": status,
        "reference_ids": [ref_labels[int(ref_keep[i])] for i in r_ids],
        "extracted_ids": [ext_labels[int(ext_keep[i])] for i in e_ids],
        # positions in the input sequences, so that plots can find the geometries
        "reference_index": [int(ref_keep[i]) for i in r_ids],
        "extracted_index": [int(ext_keep[i]) for i in e_ids],
        "area_reference": float(r.area) if r is not None else 0.0,
        "area_extracted": float(e.area) if e is not None else 0.0,
    }
    sc = area_scores(e, r)
    rec.update({key: sc[key] for key in ("completeness", "correctness", "f_score", "quality")})
    with_z = e is not None and r is not None and shapely.has_z(e) and shapely.has_z(r)
    res = vertex_residuals(r, e)
    rmse = np.sqrt(np.mean(res ** 2, axis=0)) if len(res) else np.full(3, math.nan)
    rec.update({
        "polis": polis(e, r),
        "polis_3d": polis(e, r, dim=3) if with_z else math.nan,
        "hausdorff": hausdorff(e, r),
        "rmse_x": float(rmse[0]), "rmse_y": float(rmse[1]), "rmse_z": float(rmse[2]),
        "n_reference_vertices": int(len(res)),
    })
    rec.update(corner_metrics(e, r, corner_tolerance))
    return rec, res


def evaluate(
    extracted: Sequence,
    reference: Sequence,
    *,
    aoi=None,
    extracted_ridges: Sequence | None = None,
    reference_ridges: Sequence | None = None,
    ridge_buffer: float = 0.5,
    min_overlap: float = 0.5,
    merge_blocks: bool = True,
    extracted_ids: Sequence | None = None,
    reference_ids: Sequence | None = None,
    boundary_band: float = 1.0,
    corner_tolerance: float = 0.5,
) -> dict:
    """Evaluate extracted roof outlines against reference ones (thesis §3.5).

    Parameters
    ----------
    extracted, reference : sequence of Polygon / MultiPolygon
        Outlines in one CRS, 2D or 3D. None and empty entries are ignored;
        invalid ones are repaired with ``shapely.make_valid`` (with a warning).
    aoi : Polygon, MultiPolygon or a sequence of them, optional
        Area of interest. Area scores use the polygons clipped to it; the
        building-level results keep the polygons whose
        ``point_on_surface`` lies inside it (uncut, so distances stay honest).
    extracted_ridges, reference_ridges : sequence of LineString, optional
        Ridge lines; ridge scores are added when both are given (clipped to
        the AOI when there is one).
    ridge_buffer : float, default 0.5
        Buffer half-width for the ridge scores (m).
    min_overlap : float, default 0.5
        Overlap fraction for matching and for object-level counts.
    merge_blocks : bool, default True
        Evaluate connected blocks of overlapping buildings as units (see
        :mod:`rooftrace.evaluate.matching`); False for one-to-one matching.
    extracted_ids, reference_ids : sequence, optional
        Labels written into the per-building records (default: indices).
    boundary_band : float, default 1.0
        Half-width (m) of the band along the reference boundary in which FP
        and FN areas are also reported apart.
    corner_tolerance : float, default 0.5
        Largest distance (m) of a matched pair of corners (see
        :func:`~rooftrace.evaluate.metrics.corner_metrics`).

    Returns
    -------
    dict
        JSON-serialisable (NaN written as None). Scene-level area scores
        ``completeness``, ``correctness``, ``f_score``, ``quality`` (0–1; see
        :func:`~rooftrace.evaluate.metrics.area_scores` for empty inputs),
        ``tp_area``, ``fn_area``, ``fp_area`` (m²) and the parts of the last
        two within ``boundary_band`` of the reference boundary,
        ``fn_area_boundary`` and ``fp_area_boundary``
        (:func:`~rooftrace.evaluate.metrics.boundary_errors`); object-level counts
        ``n_reference``, ``n_extracted``, ``n_matched`` (matched units),
        ``n_matched_one_to_one`` and ``n_matched_merged`` (matched units of
        one reference and one extracted building, and the others: blocks),
        ``n_reference_in_merged`` and ``n_extracted_in_merged`` (the
        buildings in those blocks), ``n_missed`` (reference buildings
        without match), ``n_false_positive`` (extracted buildings without
        match), ``n_reference_found`` and ``n_extracted_correct`` (buildings covered
        at least ``min_overlap`` by the other side), ``object_completeness``,
        ``object_correctness``; means over matched units ``polis_mean``,
        ``polis_median``, ``polis_3d_mean``, ``hausdorff_mean``,
        ``hausdorff_max``; ``rmse_x``, ``rmse_y``, ``rmse_z`` pooled over the
        reference vertices of all matched units (m); shape scores over the
        matched units: ``corner_ratio_median`` (median of extracted over
        reference corner counts), ``corner_ratio_within_1_5`` (share of units
        whose ratio lies in [1/1.5, 1.5]), ``corner_completeness`` and
        ``corner_correctness`` (matched corners over all reference /
        extracted corners, pooled), ``corner_offset_mean`` (mean distance of
        the matched corner pairs, m), the pooled counts ``n_corners``,
        ``n_corners_reference``, ``n_corners_matched`` and
        ``corner_tolerance``; ``matching_rule`` and
        ``matching_rule_description``; the ridge keys of
        :func:`~rooftrace.evaluate.metrics.ridge_scores` when ridges are
        given; and ``buildings``, one record per unit (matched, missed or
        false_positive) with its ids (``reference_ids``, ``extracted_ids``:
        the given labels; ``reference_index``, ``extracted_index``: positions
        in the input sequences) and metrics, among them the corner scores
        of :func:`~rooftrace.evaluate.metrics.corner_metrics`.

    Examples
    --------
    >>> from shapely import box
    >>> m = evaluate([box(0, 0, 10, 10)], [box(1, 0, 11, 10)])
    >>> m["completeness"], m["polis_mean"], m["n_matched"]
    (0.9, 0.5, 1)
    """
    if not corner_tolerance > 0:
        raise ValueError(f"corner_tolerance must be > 0, not {corner_tolerance}")
    ext_all = list(extracted)
    ref_all = list(reference)
    ext_labels = list(extracted_ids) if extracted_ids is not None else list(range(len(ext_all)))
    ref_labels = list(reference_ids) if reference_ids is not None else list(range(len(ref_all)))
    if len(ext_labels) != len(ext_all) or len(ref_labels) != len(ref_all):
        raise ValueError("extracted_ids and reference_ids must have one label per polygon")
    ext, ext_keep = _clean_polygons(ext_all, "extracted")
    ref, ref_keep = _clean_polygons(ref_all, "reference")
    if aoi is not None:
        aoi = shapely.union_all(np.asarray([aoi] if isinstance(aoi, shapely.Geometry) else list(aoi), dtype=object))
        if aoi.is_empty or aoi.area <= 0:
            raise ValueError("aoi must be a polygon with a positive area")
        shapely.prepare(aoi)

    clip = (lambda g: shapely.intersection(g, aoi)) if aoi is not None else (lambda g: g)
    scene_ext = clip(shapely.union_all(ext)) if len(ext) else None
    scene_ref = clip(shapely.union_all(ref)) if len(ref) else None
    scene = area_scores(scene_ext, scene_ref)
    # the band runs along the reference's own boundary, not along the AOI's cut through it
    near = boundary_errors(scene_ext, scene_ref, boundary_band,
                           boundary=shapely.union_all(ref).boundary if len(ref) else None)

    sel_e, sel_r = _in_aoi(ext, aoi), _in_aoi(ref, aoi)
    ext, ext_keep = ext[sel_e], ext_keep[sel_e]
    ref, ref_keep = ref[sel_r], ref_keep[sel_r]
    m = match_buildings(ext, ref, min_overlap=min_overlap, merge_blocks=merge_blocks)

    cov_r = coverage(ref, ext, m.pairs, m.inter, side=1)
    cov_e = coverage(ext, ref, m.pairs, m.inter, side=0)
    n_found = int(np.sum(cov_r >= min_overlap))
    n_correct = int(np.sum(cov_e >= min_overlap))

    buildings, residuals = [], []
    for k, (e_ids, r_ids) in enumerate(m.units):
        rec, res = _unit_record(k, e_ids, r_ids, ext, ref, ext_keep, ref_keep, ext_labels, ref_labels,
                                corner_tolerance)
        buildings.append(rec)
        if rec["status"] == "matched":
            residuals.append(res)
    matched = [b for b in buildings if b["status"] == "matched"]
    res = np.concatenate(residuals) if residuals else np.empty((0, 3))
    # z is NaN unless every matched unit is 3D on both sides
    rmse = np.sqrt(np.mean(res ** 2, axis=0)) if len(res) else np.full(3, math.nan)
    polis_values = [b["polis"] for b in matched]
    out = {
        "completeness": scene["completeness"],
        "correctness": scene["correctness"],
        "f_score": scene["f_score"],
        "quality": scene["quality"],
        "tp_area": scene["tp"], "fn_area": scene["fn"], "fp_area": scene["fp"],
        "fn_area_boundary": near["fn_boundary"], "fp_area_boundary": near["fp_boundary"],
        "boundary_band": float(boundary_band),
        "polis_mean": _nan_mean(polis_values),
        "polis_median": float(np.median(polis_values)) if polis_values else math.nan,
        "polis_3d_mean": _nan_mean(b["polis_3d"] for b in matched),
        "hausdorff_mean": _nan_mean(b["hausdorff"] for b in matched),
        "hausdorff_max": max((b["hausdorff"] for b in matched), default=math.nan),
        "rmse_x": float(rmse[0]), "rmse_y": float(rmse[1]), "rmse_z": float(rmse[2]),
        "n_rmse_vertices": int(len(res)),
        **_corner_summary(matched, corner_tolerance),
        "n_reference": int(len(ref)),
        "n_extracted": int(len(ext)),
        "n_matched": len(matched),
        **_unit_counts(buildings),
        "n_reference_found": n_found,
        "n_extracted_correct": n_correct,
        "object_completeness": n_found / len(ref) if len(ref) else math.nan,
        "object_correctness": n_correct / len(ext) if len(ext) else math.nan,
        "min_overlap": float(min_overlap),
        "matching_rule": m.rule,
        "matching_rule_description": m.description,
        "aoi_area": float(aoi.area) if aoi is not None else None,
    }
    if extracted_ridges is not None and reference_ridges is not None:
        er, rr = list(extracted_ridges), list(reference_ridges)
        if aoi is not None:
            er = [g for g in shapely.intersection(np.asarray(er, dtype=object), aoi) if not g.is_empty]
            rr = [g for g in shapely.intersection(np.asarray(rr, dtype=object), aoi) if not g.is_empty]
        out.update(ridge_scores(er, rr, ridge_buffer))
        out["ridge_buffer"] = float(ridge_buffer)
    out["buildings"] = buildings
    log.info("evaluated %d matched units of %d reference / %d extracted buildings",
             len(matched), len(ref), len(ext))
    return _jsonable(out)
