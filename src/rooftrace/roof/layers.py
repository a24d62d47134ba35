"""The ``roof_faces`` and ``ridges`` output layers from a list of roof structures."""

from __future__ import annotations

import numpy as np

from rooftrace.io.vector import Layer
from rooftrace.roof.structure import RoofStructure

__all__ = ["faces_layer", "ridges_layer"]


def _length3d(line) -> float:
    c = np.asarray(line.coords)
    return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0


def faces_layer(structures: list[RoofStructure]) -> Layer:
    """The ``roof_faces`` layer: one PolygonZ per face.

    Attributes: ``building_id``, ``plane_id``, ``slope_deg``, ``aspect_deg``
    (downslope direction clockwise from north, NaN under 1° of slope), ``rmse`` (m,
    height residuals of the plane's points), ``n_points``.
    """
    geoms, cols = [], {k: [] for k in ("building_id", "plane_id", "slope_deg", "aspect_deg", "rmse", "n_points")}
    for st in structures:
        slope, aspect = st.slope_deg, st.aspect_deg
        for g, k in zip(st.faces, st.face_plane):
            geoms.append(g)
            cols["building_id"].append(int(st.building_id))
            cols["plane_id"].append(int(k))
            cols["slope_deg"].append(float(slope[k]))
            cols["aspect_deg"].append(float(aspect[k]))
            cols["rmse"].append(float(st.plane_sigma[k]))
            cols["n_points"].append(int(st.plane_n[k]))
    cols["building_id"] = np.asarray(cols["building_id"], dtype=np.int64)
    cols["plane_id"] = np.asarray(cols["plane_id"], dtype=np.int64)
    cols["n_points"] = np.asarray(cols["n_points"], dtype=np.int64)
    for k in ("slope_deg", "aspect_deg", "rmse"):
        cols[k] = np.asarray(cols[k], dtype=np.float64)
    return Layer(geoms, cols, "PolygonZ")


def ridges_layer(structures: list[RoofStructure]) -> Layer:
    """The ``ridges`` layer: one LineStringZ per ridge, hip, valley or step edge.

    Attributes: ``building_id``, ``kind`` (``ridge|hip|valley|step``),
    ``length`` (m, 3D), ``plane_a``, ``plane_b`` (the two planes; for a step,
    upper then lower).
    """
    geoms, bid, kind, length, pa, pb = [], [], [], [], [], []
    for st in structures:
        for g, k, (a, b) in zip(st.ridges, st.ridge_kind, st.ridge_planes):
            geoms.append(g)
            bid.append(int(st.building_id))
            kind.append(k)
            length.append(_length3d(g))
            pa.append(int(a))
            pb.append(int(b))
    cols = {
        "building_id": np.asarray(bid, dtype=np.int64),
        "kind": kind,
        "length": np.asarray(length, dtype=np.float64),
        "plane_a": np.asarray(pa, dtype=np.int64),
        "plane_b": np.asarray(pb, dtype=np.int64),
    }
    return Layer(geoms, cols, "LineStringZ")
