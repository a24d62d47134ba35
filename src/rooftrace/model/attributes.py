"""Per-building attributes of a 3D model, the ones 3DBAG users rely on.

=================  ======================================  =====================
attribute          meaning                                 3DBAG counterpart
=================  ======================================  =====================
``h_ground``       ground height of the walls (m)          ``b3_h_maaiveld``
``h_roof_min``     lowest roof point (m)                   ``b3_h_dak_min``
``h_roof_50p``     median roof point height (m)            ``b3_h_dak_50p``
``h_roof_70p``     70th percentile (m), LoD 1.2's roof     ``b3_h_dak_70p``
``h_roof_max``     highest roof point (m)                  ``b3_h_dak_max``
``h_ridge``        highest ridge line (m), null if none    (``b3_h_nok``)
``roof_type``      ``slanted``, ``horizontal``,            ``b3_dak_type``
                   ``multiple horizontal``, ``no planes``,
                   ``no points``
``n_planes``       roof planes                             ``b3_n_vlakken``
``n_ridges``       ridge lines                             ``b3_n_nokken``
``slope_deg``      area-weighted mean roof slope (deg)     ``b3_hellingshoek``
``azimuth_deg``    downslope direction of the largest      ``b3_azimut``
                   sloped face, clockwise from north
``volume_lodXX``   volume of the LoD solids (m³)           ``b3_volume_lodXX``
``rmse_lodXX``     vertical RMSE of the roof points to     ``b3_rmse_lodXX``
                   the LoD's roof (m)
``n_points``       roof points
``point_density``  roof points per m² of footprint         ``b3_pw_dichtheid``
``area``           footprint area (m²)
``status``,        ``ok``, ``flat_lod22``, ``partial`` or  ``b3_reconstructie_
``status_reason``  ``no_model``, and which level failed    onvolledig``
                   or is flat, and why
=================  ======================================  =====================

Missing values are ``None`` (JSON null).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rooftrace.model.measure import vertical_rmse
from rooftrace.model.types import LODS, BuildingModel
from rooftrace.model.validity import solid_volume

__all__ = ["building_attributes", "FLAT_SLOPE"]

#: roof planes flatter than this (deg) count as horizontal for ``roof_type``
FLAT_SLOPE = 3.0


def _num(v: float, digits: int = 3) -> float | None:
    return round(float(v), digits) if v is not None and np.isfinite(v) else None


def building_attributes(model: BuildingModel, roof, xyz: np.ndarray, ground: float) -> dict[str, Any]:
    """The attributes of the table above for one built model.

    Parameters
    ----------
    model : BuildingModel
        From :func:`rooftrace.model.build.build_model` (its ``status`` and
        ``status_reason`` are kept).
    roof : RoofStructure or None
    xyz : ndarray of shape (N, 3)
        The building's roof points (m).
    ground : float
        Its ground height (m).

    Returns
    -------
    dict of str to (float, int, str or None)
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    z = xyz[:, 2]
    has = len(z) > 0
    q = np.percentile(z, [50, 70]) if has else [np.nan, np.nan]
    area = float(sum(p.footprint.area for p in model.parts))
    out: dict[str, Any] = {
        "h_ground": _num(ground),
        "h_roof_min": _num(z.min()) if has else None,
        "h_roof_50p": _num(q[0]),
        "h_roof_70p": _num(q[1]),
        "h_roof_max": _num(z.max()) if has else None,
    }
    planes = np.zeros((0, 4)) if roof is None else np.asarray(roof.planes).reshape(-1, 4)
    kinds = [] if roof is None else list(roof.ridge_kind)
    ridges = [g for g, k in zip([] if roof is None else roof.ridges, kinds) if k == "ridge"]
    out["h_ridge"] = _num(max(np.asarray(g.coords)[:, 2].max() for g in ridges)) if ridges else None
    faces = [] if roof is None else list(zip(roof.faces, roof.face_plane))
    slope = roof.slope_deg if roof is not None and len(planes) else np.zeros(0)
    if not has:
        roof_type = "no points"
    elif not faces:
        roof_type = "no planes"
    elif (slope[[k for _, k in faces]] >= FLAT_SLOPE).any():
        roof_type = "slanted"
    else:
        heights = {round(float(s.rings[0][0][2]), 2) for p in model.parts if "1.3" in p.lods
                   for s in p.lods["1.3"].surfaces if s.kind == "RoofSurface"}
        roof_type = "multiple horizontal" if len(heights) > 1 else "horizontal"
    out["roof_type"] = roof_type
    out["n_planes"] = int(len(planes))
    out["n_ridges"] = int(len(ridges))
    if faces:
        w = np.array([f.area for f, _ in faces])
        k = np.array([k for _, k in faces])
        out["slope_deg"] = _num(np.average(slope[k], weights=w) if w.sum() > 0 else np.nan, 2)
        sloped = slope[k] >= FLAT_SLOPE
        out["azimuth_deg"] = _num(roof.aspect_deg[k[sloped][np.argmax(w[sloped])]], 2) if sloped.any() else None
    else:
        out["slope_deg"] = out["azimuth_deg"] = None
    for lod in LODS:
        solids = [p.lods[lod] for p in model.parts if lod in p.lods]
        tag = lod.replace(".", "")
        out[f"volume_lod{tag}"] = _num(sum(solid_volume(s) for s in solids), 2) if solids else None
        out[f"rmse_lod{tag}"] = _num(vertical_rmse(solids, xyz), 3) if solids and has else None
    out["n_points"] = int(len(z))
    out["point_density"] = _num(len(z) / area, 2) if area > 0 else None
    out["area"] = _num(area, 2)
    out["status"] = model.attributes.get("status", "ok")
    out["status_reason"] = model.attributes.get("status_reason")
    return out
