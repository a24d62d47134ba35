"""The 3D GeoPackage layers of the models: one MultiPolygonZ per building part and surface type, per LoD."""

from __future__ import annotations

import numpy as np
import shapely

from rooftrace.io.vector import Layer
from rooftrace.model.types import LODS, SURFACE_KINDS

__all__ = ["model_layers", "LAYER_NAMES"]

#: GeoPackage layer of each level of detail
LAYER_NAMES = {lod: "lod" + lod.replace(".", "") for lod in LODS}


def _multipolygon(surfaces) -> shapely.MultiPolygon:
    # surfaces without holes (nearly all: walls) built in one call, one feature at a time: built for a whole
    # layer at once, the rings and polygons alive together kept the garbage collector busy (slower on Delft)
    simple = [s.rings[0] for s in surfaces if len(s.rings) == 1]
    polys = iter(shapely.polygons(shapely.linearrings(np.concatenate(simple), indices=np.repeat(
        np.arange(len(simple)), [len(r) for r in simple]))) if simple else [])
    return shapely.multipolygons([next(polys) if len(s.rings) == 1 else shapely.Polygon(s.rings[0], s.rings[1:])
                                  for s in surfaces])


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
        geoms = []
        cols = {k: [] for k in ("building_id", "part_id", "surface_type", "status", "h_ground", "h_roof_70p",
                                "volume")}
        for m in models:
            for part in m.parts:
                solid = part.lods.get(lod)
                if solid is None:
                    continue
                for kind in SURFACE_KINDS:
                    surfaces = [s for s in solid.surfaces if s.kind == kind]
                    if not surfaces:
                        continue
                    geoms.append(_multipolygon(surfaces))
                    cols["building_id"].append(int(m.building_id))
                    cols["part_id"].append(int(part.part_id))
                    cols["surface_type"].append(kind)
                    cols["status"].append(str(m.attributes.get("status", "")))
                    for key in ("h_ground", "h_roof_70p"):
                        v = m.attributes.get(key)
                        cols[key].append(np.nan if v is None else float(v))
                    v = part.attributes.get(f"volume_{name}")
                    cols["volume"].append(np.nan if v is None else float(v))
        cols["building_id"] = np.asarray(cols["building_id"], dtype=np.int64)
        cols["part_id"] = np.asarray(cols["part_id"], dtype=np.int64)
        for key in ("h_ground", "h_roof_70p", "volume"):
            cols[key] = np.asarray(cols[key], dtype=np.float64)
        out[name] = Layer(geoms, cols, "MultiPolygonZ")
    return out
