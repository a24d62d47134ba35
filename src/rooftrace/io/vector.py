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

import os
import types
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyproj
import shapely

from rooftrace.errors import InputError
from rooftrace.io.atomic import atomic_path

__all__ = ["Layer", "write_layers", "read_layer", "list_layers", "load_pyogrio", "vector_driver"]

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

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from shapely import box
    >>> roofs = Layer([box(0, 0, 10, 8)], {"building_id": [1]}, "Polygon")
    >>> path = write_layers(pathlib.Path(tempfile.mkdtemp()) / "roofs.gpkg", {"roof_outlines": roofs},
    ...                     pyproj.CRS("EPSG:28992"))
    >>> layer = read_layer(path, "roof_outlines")
    >>> len(layer), layer.geometries[0].area
    (1, 80.0)
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
            load_pyogrio().raw.write(
                str(tmp), geoms, data, fields, layer=name, driver=driver,
                geometry_type=_ogr_type(layer.geometry_type), crs=wkt,
                append=False, dataset_options=_DATASET_OPTIONS.get(driver),
            )
    return path


def load_pyogrio() -> types.ModuleType:
    """pyogrio, imported when a vector file is read or written: it imports geopandas and pandas (0.3 s CPU)."""
    import pyogrio
    import pyogrio.raw

    return pyogrio


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
    # the layers spell types as OGC does ("PolygonZ"); pyogrio wants "Polygon Z"
    if name.endswith("Z") and not name.endswith(" Z"):
        return name[:-1] + " Z"
    return name


def list_layers(path: str | os.PathLike) -> list[str]:
    """Names of the layers of a vector file."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    try:
        return [str(r[0]) for r in load_pyogrio().list_layers(str(path))]
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
        meta, _, wkb, values = load_pyogrio().raw.read(str(path), layer=layer)
    except Exception as exc:
        raise InputError(f"{path}: cannot read layer {layer!r} ({exc})") from None
    geoms = list(shapely.from_wkb(wkb)) if wkb is not None else []
    attrs = {name: list(col) for name, col in zip(meta["fields"], values)}
    crs = pyproj.CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    return Layer(geoms, attrs, str(meta.get("geometry_type") or "Unknown"), crs)

