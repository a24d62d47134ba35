"""The 3D GeoPackage layers of the models: one MultiPolygonZ per building part and surface type, per LoD."""

from __future__ import annotations

import numpy as np
import shapely

from rooftrace.io.vector import Layer
from rooftrace.model.types import LODS, SURFACE_KINDS
from rooftrace.model.validity import surface_polygons

__all__ = ["model_layers", "LAYER_NAMES"]

#: GeoPackage layer of each level of detail
LAYER_NAMES = {lod: "lod" + lod.replace(".", "") for lod in LODS}


def model_layers(models: list) -> dict[str, Layer]:
    """``lod12``, ``lod13``, ``lod22``: the models' surfaces for GIS (QGIS 3D views).

    One MultiPolygonZ feature per building, part and surface type, with the
    attributes ``building_id``, ``part_id``, ``surface_type``
    (``RoofSurface|WallSurface|GroundSurface``), ``status``, ``h_ground``,
    ``h_roof_70p`` and ``volume`` (m³, of the part's solid at that LoD).
    Features are in building, part, surface-type order.
    """
    out = {}
    for lod, name in LAYER_NAMES.items():
        surfaces, feature = [], []
        cols = {k: [] for k in ("building_id", "part_id", "surface_type", "status", "h_ground", "h_roof_70p",
                                "volume")}
        for m in models:
            for part in m.parts:
                solid = part.lods.get(lod)
                if solid is None:
                    continue
                for kind in SURFACE_KINDS:
                    mine = [s for s in solid.surfaces if s.kind == kind]
                    if not mine:
                        continue
                    feature.extend([len(cols["building_id"])] * len(mine))
                    surfaces.extend(mine)
                    cols["building_id"].append(int(m.building_id))
                    cols["part_id"].append(int(part.part_id))
                    cols["surface_type"].append(kind)
                    cols["status"].append(str(m.attributes.get("status", "")))
                    for key in ("h_ground", "h_roof_70p"):
                        v = m.attributes.get(key)
                        cols[key].append(np.nan if v is None else float(v))
                    v = part.attributes.get(f"volume_{name}")
                    cols["volume"].append(np.nan if v is None else float(v))
        # every surface of the layer built in a few array calls, then grouped into the features
        geoms = list(shapely.multipolygons(surface_polygons(surfaces), indices=feature)) if surfaces else []
        cols["building_id"] = np.asarray(cols["building_id"], dtype=np.int64)
        cols["part_id"] = np.asarray(cols["part_id"], dtype=np.int64)
        for key in ("h_ground", "h_roof_70p", "volume"):
            cols[key] = np.asarray(cols[key], dtype=np.float64)
        out[name] = Layer(geoms, cols, "MultiPolygonZ")
    return out
