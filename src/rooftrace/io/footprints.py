"""Building footprints in: any OGR vector, reprojected to the point cloud's CRS, with their ids.

Reading only; the assignment of points to footprints is
:mod:`rooftrace.footprints` (no I/O there).
"""

from __future__ import annotations

import logging
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pyproj
import shapely

from rooftrace.errors import InputError, OptionError
from rooftrace.footprints import Footprints
from rooftrace.io.checks import horizontal_crs
from rooftrace.io.vector import list_layers, load_pyogrio

__all__ = ["read_footprints", "FOOTPRINT_ID_FIELDS"]

log = logging.getLogger(__name__)


#: attribute names taken as the footprint id when ``--footprint-id`` is not given, in order (case-insensitive):
#: BAG/BGT building ids first ("identifica": the Shapefile-truncated name), then generic ones; without any of
#: them the feature id (FID)
FOOTPRINT_ID_FIELDS = ("identificatie", "identifica", "identificatiebagpnd", "id", "fid", "gml_id")


def read_footprints(path: str | os.PathLike, crs: pyproj.CRS | None = None, *,
                    id_field: str | None = None) -> Footprints:
    """Read building footprints (any OGR vector: GPKG, GeoJSON, Shapefile, FlatGeobuf, SQLite ...).

    The first layer with polygons is read (a warning names the others).
    Polygons are reprojected to ``crs`` (the point cloud's); holes and
    multipolygons are kept, invalid rings repaired (``make_valid``, with a
    warning), features without a polygon skipped (with a warning).

    CRS rules, as GIS users expect them (QGIS and ogr2ogr behave alike):
    a file without a CRS is taken to be in the cloud's CRS (a warning); so is
    a GeoJSON without a ``crs`` member (WGS 84 by RFC 7946) whose
    coordinates cannot be longitude/latitude; a cloud without a CRS takes
    the footprints as they are (a warning).  Compound CRSs (e.g.
    EPSG:7415 = RD New + NAP) are compared by their horizontal part.

    Parameters
    ----------
    path : path-like
    crs : pyproj.CRS, optional
        The point cloud's CRS.
    id_field : str, optional
        Attribute holding the footprint id; default the first of
        :data:`FOOTPRINT_ID_FIELDS` present, else the feature id (``"fid"``).

    Returns
    -------
    rooftrace.footprints.Footprints

    Raises
    ------
    InputError
        Unreadable file, no polygon layer, no polygon, unknown ``id_field``,
        or a CRS that cannot be transformed to ``crs``.
    """
    path = Path(path)
    names = list_layers(path)
    try:
        layers = load_pyogrio().list_layers(str(path))
    except Exception:  # list_layers above has already said why
        layers = []
    polygonal = [str(name) for name, kind in layers if kind and "polygon" in str(kind).lower()]
    unknown = [str(name) for name, kind in layers if not kind or str(kind).lower() in ("unknown", "geometry", "none")]
    candidates = polygonal or unknown
    if not candidates:
        raise OptionError(f"{path}: no polygon layer (layers: {', '.join(names) or 'none'}); {{footprints}} needs "
                          "building footprints as polygons", "footprints")
    layer = candidates[0]
    if len(candidates) > 1:
        log.warning("%s: reading footprints from layer %r (also there: %s)", path, layer, ", ".join(candidates[1:]))
    try:
        meta, fids, wkb, values = load_pyogrio().raw.read(str(path), layer=layer, return_fids=True)
    except Exception as exc:
        reason = " ".join(str(exc).split())[:200]
        raise InputError(f"{path}: cannot read layer {layer!r} ({reason})") from None
    fields = [str(f) for f in meta["fields"]]
    if id_field is not None:
        lower = {f.lower(): f for f in fields}
        if id_field not in fields and id_field.lower() not in lower and id_field.lower() != "fid":
            raise OptionError(f"{path}: no attribute {id_field!r} for {{footprint_id}} (attributes: "
                              f"{', '.join(fields) or 'none'}; 'fid' is the feature id)", "footprint_id")
        chosen = id_field if id_field in fields else lower.get(id_field.lower())
    else:
        lower = {f.lower(): f for f in fields}
        chosen = next((lower[k] for k in FOOTPRINT_ID_FIELDS if k in lower), None)
    ids = list(values[fields.index(chosen)]) if chosen is not None else [int(v) for v in fids]
    id_name = chosen if chosen is not None else "fid"

    geoms = shapely.from_wkb(wkb) if wkb is not None else np.empty(0, object)
    geoms = shapely.force_2d(geoms) if len(geoms) else geoms
    kinds = shapely.get_type_id(geoms) if len(geoms) else np.zeros(0, int)
    keep = np.isin(kinds, (3, 6)) & ~shapely.is_empty(geoms)
    if not keep.any():
        raise OptionError(f"{path}: layer {layer!r} holds no polygons ({len(geoms)} features); {{footprints}} needs "
                          "building footprints as polygons", "footprints")
    if not keep.all():
        log.warning("%s: %d of %d features are not polygons (or empty) and are skipped", path,
                    int((~keep).sum()), len(geoms))
    geoms = geoms[keep]
    ids = [_scalar(v, fid) for v, fid, k in zip(ids, fids, keep) if k]
    if len(set(ids)) < len(ids):
        log.warning("%s: the footprint ids (%s) are not unique", path, id_name)
    invalid = ~shapely.is_valid(geoms)
    if invalid.any():
        log.warning("%s: %d invalid footprint polygons repaired (make_valid)", path, int(invalid.sum()))
        repaired = shapely.make_valid(geoms[invalid])
        # make_valid may return a collection with lines: keep its polygonal part
        geoms[invalid] = [_polygonal(g) for g in repaired]

    source = pyproj.CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    if source is not None and source.is_geographic and _implicit_wgs84(path, geoms):
        log.warning("%s: GeoJSON without a 'crs' member and coordinates that are not longitude/latitude; "
                    "taking them in the point cloud's CRS", path)
        source = None
    target = horizontal_crs(crs)
    if source is None:
        if target is not None:
            log.warning("%s: no CRS; taking the footprints in the point cloud's CRS (%s)", path, target.name)
    elif target is None:
        log.warning("%s: the point cloud has no CRS; taking the footprints' coordinates (%s) as they are",
                    path, source.name)
    elif not horizontal_crs(source).equals(target):
        try:
            transformer = pyproj.Transformer.from_crs(horizontal_crs(source), target, always_xy=True)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                geoms = shapely.transform(geoms, lambda xy: np.column_stack(transformer.transform(xy[:, 0], xy[:, 1])))
        except pyproj.exceptions.ProjError as exc:
            raise InputError(f"{path}: cannot reproject the footprints from {source.name} to {target.name} "
                             f"({exc})") from None
        if not np.isfinite(shapely.get_coordinates(geoms)).all():
            raise InputError(f"{path}: the footprints do not reproject from {source.name} to {target.name} "
                             "(coordinates out of the CRS's area); check the file's CRS")
    return Footprints(tuple(geoms), tuple(ids), id_name)


def _scalar(value: Any, fid: Any) -> Any:
    """A footprint id as a plain int or str; a missing value falls back to the feature id."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return int(fid)
    if isinstance(value, (np.integer, int, bool)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return int(value) if float(value).is_integer() else float(value)
    return str(value)


def _polygonal(geom: Any) -> Any:
    parts = [g for g in shapely.get_parts(geom) if shapely.get_type_id(g) in (3, 6)]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(
        [p for g in parts for p in shapely.get_parts(g)])


def _implicit_wgs84(path: Path, geoms: np.ndarray) -> bool:
    """A GeoJSON read as WGS 84 only because it declares nothing, whose coordinates cannot be degrees."""
    if path.suffix.lower() not in (".geojson", ".json"):
        return False
    xy = shapely.get_coordinates(geoms)
    return bool(len(xy)) and bool((np.abs(xy[:, 0]) > 180).any() or (np.abs(xy[:, 1]) > 90).any())
