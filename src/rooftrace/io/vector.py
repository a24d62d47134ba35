"""Vector layers in and out via pyogrio: any OGR format is read; GeoPackage, GeoJSON and FlatGeobuf are written.

A layer is a list of shapely geometries plus columns of attributes.  Several
layers go into one GeoPackage in a single atomic write.

Only single-file formats are written: an output is written to a temporary
file beside the target and renamed onto it, which is atomic for one file
only.  A Shapefile is several files (.shp, .shx, .dbf, .prj, .cpg) that
cannot be replaced together atomically (and it truncates field names to 10
characters), so ``.shp`` outputs are refused with a pointer to GeoPackage;
Shapefiles are still read.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyogrio
import pyproj
import shapely

from rooftrace.errors import InputError
from rooftrace.io.atomic import atomic_path

__all__ = ["Layer", "write_layers", "read_layer", "list_layers", "vector_driver", "read_footprints",
           "FOOTPRINT_ID_FIELDS"]

log = logging.getLogger(__name__)

_DRIVERS = {".gpkg": "GPKG", ".geojson": "GeoJSON", ".json": "GeoJSON", ".fgb": "FlatGeobuf"}
#: GeoPackage 1.3: GDAL >= 3.7 writes 1.4 by default, which GDAL 3.6 (Debian 12, QGIS LTR builds of
#: that age) opens with "v1.4.0 may only be partially supported"; the layers need nothing of 1.4
GPKG_VERSION = "1.3"
_DATASET_OPTIONS = {"GPKG": {"VERSION": GPKG_VERSION}}
#: multi-file formats, read but never written (no atomic replacement of a set of files)
_MULTI_FILE = {".shp": "Shapefile", ".shx": "Shapefile", ".dbf": "Shapefile", ".tab": "MapInfo TAB", ".mif": "MapInfo MIF"}


@dataclass
class Layer:
    """Geometries and their attribute columns.

    Parameters
    ----------
    geometries : sequence of shapely geometries
    attributes : dict of str to sequence
        One value per geometry in each column (ints, floats or strings).
    geometry_type : str
        OGR geometry type, e.g. ``"PolygonZ"``, ``"LineStringZ"``, ``"Point"``.
    crs : pyproj.CRS or None
        Filled when read; on write the call's ``crs`` wins.
    """

    geometries: Sequence[Any]
    attributes: dict[str, Sequence[Any]] = field(default_factory=dict)
    geometry_type: str = "Unknown"
    crs: Any = None

    def __len__(self) -> int:
        return len(self.geometries)


def _column(values: Sequence[Any]) -> np.ndarray:
    arr = np.asarray(values)
    if arr.dtype.kind in "biuf":
        return arr
    if arr.dtype == bool:
        return arr.astype(np.int8)
    return np.array([None if v is None else str(v) for v in values], dtype=object)


def write_layers(
    path: str | os.PathLike,
    layers: Mapping[str, Layer],
    crs: pyproj.CRS | None = None,
    *,
    overwrite: bool = False,
) -> Path:
    """Write named layers into one vector file, atomically.

    Empty layers are written too (with their schema), so a reader always
    finds ``roof_outlines``, ``ridges`` ... even when no building was found.

    Parameters
    ----------
    path : path-like
        ``.gpkg`` (any number of layers), ``.geojson``/``.json`` or ``.fgb``
        (one layer).
    layers : mapping of str to Layer
        Layer name to geometries and attributes.
    crs : pyproj.CRS, optional
        Written to every layer.
    overwrite : bool, default False
        Replace an existing file.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        Unknown or multi-file format (Shapefile), several layers for a
        one-layer format, or an existing output without ``overwrite``.
    """
    path = Path(path)
    driver = vector_driver(path)
    if driver != "GPKG" and len(layers) > 1:
        raise InputError(f"{path}: {driver} holds one layer; use a .gpkg output for {', '.join(layers)}")
    wkt = crs.to_wkt() if crs is not None else None
    with atomic_path(path, overwrite) as tmp:
        for name, layer in layers.items():
            n = len(layer)
            for key, col in layer.attributes.items():
                if len(col) != n:
                    raise ValueError(f"layer {name}: attribute {key!r} has {len(col)} values for {n} geometries")
            geoms = np.asarray(shapely.to_wkb(np.asarray(layer.geometries, dtype=object), output_dimension=3)) if n else np.empty(0, object)
            fields = list(layer.attributes)
            data = [_column(layer.attributes[k]) for k in fields]
            pyogrio.raw.write(
                str(tmp), geoms, data, fields, layer=name, driver=driver,
                geometry_type=_ogr_type(layer.geometry_type), crs=wkt,
                append=False, dataset_options=_DATASET_OPTIONS.get(driver),
            )
    return path


def vector_driver(path: str | os.PathLike) -> str:
    """The OGR driver that writes ``path``, chosen by its suffix; commands call it before any work.

    Raises
    ------
    InputError
        A multi-file format (Shapefile, MapInfo) or an unknown suffix.

    Examples
    --------
    >>> vector_driver("roofs.gpkg"), vector_driver("roofs.fgb")
    ('GPKG', 'FlatGeobuf')
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in _MULTI_FILE:
        raise InputError(f"{path}: {_MULTI_FILE[suffix]} output is not supported, it is several files that cannot "
                         "be replaced atomically; write a GeoPackage (.gpkg) and convert it if needed, e.g. "
                         f"ogr2ogr {path.with_suffix('.shp').name} {path.with_suffix('.gpkg').name}")
    driver = _DRIVERS.get(suffix)
    if driver is None:
        raise InputError(f"{path}: unknown vector format {suffix or '(no suffix)'!r}; use .gpkg, .geojson or .fgb")
    return driver


def _ogr_type(name: str) -> str:
    # DESIGN.md spells types as OGC does ("PolygonZ"); pyogrio wants "Polygon Z"
    if name.endswith("Z") and not name.endswith(" Z"):
        return name[:-1] + " Z"
    return name


def list_layers(path: str | os.PathLike) -> list[str]:
    """Names of the layers of a vector file."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    try:
        return [str(r[0]) for r in pyogrio.list_layers(str(path))]
    except Exception as exc:
        reason = " ".join(str(exc).split(";")[0].split())[:200]
        raise InputError(f"{path}: not a readable vector file ({reason}); give a GeoPackage, GeoJSON, "
                         "Shapefile, FlatGeobuf or another OGR vector format") from None


def read_layer(path: str | os.PathLike, layer: str | None = None, *, missing_ok: bool = False) -> Layer | None:
    """Read one layer (the first when ``layer`` is None) as shapely geometries.

    Returns None when ``missing_ok`` and the file has no such layer.
    """
    path = Path(path)
    names = list_layers(path)
    if layer is not None and layer not in names:
        if missing_ok:
            return None
        raise InputError(f"{path}: no layer {layer!r} (layers: {', '.join(names) or 'none'})")
    try:
        meta, _, wkb, values = pyogrio.raw.read(str(path), layer=layer)
    except Exception as exc:
        raise InputError(f"{path}: cannot read layer {layer!r} ({exc})") from None
    geoms = list(shapely.from_wkb(wkb)) if wkb is not None else []
    attrs = {name: list(col) for name, col in zip(meta["fields"], values)}
    crs = pyproj.CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    return Layer(geoms, attrs, str(meta.get("geometry_type") or "Unknown"), crs)


#: attribute names taken as the footprint id when ``--footprint-id`` is not given, in order (case-insensitive):
#: BAG/BGT building ids first ("identifica": the Shapefile-truncated name), then generic ones; without any of
#: them the feature id (FID)
FOOTPRINT_ID_FIELDS = ("identificatie", "identifica", "identificatiebagpnd", "id", "fid", "gml_id")


def read_footprints(path: str | os.PathLike, crs: pyproj.CRS | None = None, *, id_field: str | None = None):
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
    import warnings

    from rooftrace.footprints import Footprints
    from rooftrace.io.checks import horizontal_crs

    path = Path(path)
    names = list_layers(path)
    try:
        layers = pyogrio.list_layers(str(path))
    except Exception:  # list_layers above has already said why
        layers = []
    polygonal = [str(name) for name, kind in layers if kind and "polygon" in str(kind).lower()]
    unknown = [str(name) for name, kind in layers if not kind or str(kind).lower() in ("unknown", "geometry", "none")]
    candidates = polygonal or unknown
    if not candidates:
        raise InputError(f"{path}: no polygon layer (layers: {', '.join(names) or 'none'}); --footprints needs "
                         "building footprints as polygons")
    layer = candidates[0]
    if len(candidates) > 1:
        log.warning("%s: reading footprints from layer %r (also there: %s)", path, layer, ", ".join(candidates[1:]))
    try:
        meta, fids, wkb, values = pyogrio.raw.read(str(path), layer=layer, return_fids=True)
    except Exception as exc:
        reason = " ".join(str(exc).split())[:200]
        raise InputError(f"{path}: cannot read layer {layer!r} ({reason})") from None
    fields = [str(f) for f in meta["fields"]]
    if id_field is not None:
        lower = {f.lower(): f for f in fields}
        if id_field not in fields and id_field.lower() not in lower and id_field.lower() != "fid":
            raise InputError(f"{path}: no attribute {id_field!r} for --footprint-id (attributes: "
                             f"{', '.join(fields) or 'none'}; 'fid' is the feature id)")
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
        raise InputError(f"{path}: layer {layer!r} holds no polygons ({len(geoms)} features); --footprints needs "
                         "building footprints as polygons")
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
