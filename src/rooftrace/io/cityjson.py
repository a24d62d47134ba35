"""CityJSON 2.0 (``.city.json``) and CityJSONSeq (``.city.jsonl``) writers, streamed building by building.

Both writers take models one at a time (:meth:`add`), serialise each at
once and keep only its text on disk, so a city-size run never holds all
features in memory:

- **CityJSONSeq**: the first line is a ``CityJSON`` header (``transform``,
  ``metadata`` with ``referenceSystem`` and ``geographicalExtent``), then one
  ``CityJSONFeature`` per building.  The features are written to a
  temporary file as they come; on :meth:`close` the header (whose extent is
  only known then) is written and the features are copied after it.
- **CityJSON**: the ``CityObjects`` and the ``vertices`` go to two temporary
  files as they come and are joined into one document on :meth:`close`
  (``metadata`` last, with the extent).

Vertices are integers: ``round((x - translate) / scale)`` with ``scale``
the models' grid (1 mm), so the coordinates are exact.  ``translate`` is the
first model's lowest corner rounded down to 100 m: it depends only on the
models and their order, so tiled and untiled runs write the same bytes.

Each building is a ``Building``; a building of several parts has its
solids on ``BuildingPart`` children.  Every solid carries its semantic
surfaces (``RoofSurface``, ``WallSurface``, ``GroundSurface``).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from rooftrace.io.atomic import temporary_path, untrack
from rooftrace.io.streamed import StreamedOutput
from rooftrace.model.types import LODS, SURFACE_KINDS

__all__ = ["CityJSONWriter", "CityJSONSeqWriter", "reference_system", "cityobject_id", "VERSION"]

VERSION = "2.0"
_DUMPS = dict(separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def reference_system(crs) -> str | None:
    """The OGC URL of a CRS's EPSG code (a compound code such as 7415 when the CRS is compound), or None."""
    if crs is None:
        return None
    code = crs.to_epsg(min_confidence=70)
    if code is None and crs.is_compound:
        parts = [c.to_epsg() for c in crs.sub_crs_list]
        if all(parts):
            return ("https://www.opengis.net/def/crs-compound?1=https://www.opengis.net/def/crs/EPSG/0/"
                    f"{parts[0]}&2=https://www.opengis.net/def/crs/EPSG/0/{parts[1]}")
    return None if code is None else f"https://www.opengis.net/def/crs/EPSG/0/{code}"


def cityobject_id(model) -> str:
    """``footprint_id`` of the model when it has one (a cadastral identifier), else ``b<building_id>``."""
    ident = model.attributes.get("footprint_id")
    return str(ident) if ident not in (None, "") else f"b{model.building_id}"


def _clean(value: Any) -> Any:
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


class _Vertices:
    """Integer vertices, deduplicated, numbered from ``offset`` in order of first use."""

    def __init__(self, translate: np.ndarray, scale: float, offset: int = 0):
        self.translate, self.scale, self.offset = translate, scale, offset
        self.rows: list[list[int]] = []

    def rings(self, rings: list[np.ndarray]) -> list[list[int]]:
        """Vertex indices of every ring (all rings of one feature at once)."""
        if not rings:
            return []
        bounds = np.r_[0, np.cumsum([len(r) for r in rings])].tolist()
        q = np.ascontiguousarray(np.round((np.vstack(rings) - self.translate) / self.scale).astype(np.int64))
        # one opaque value per row: np.unique over them is much faster than with axis=0, and the
        # numbering (order of first use) does not depend on how the values sort
        _, first, inv = np.unique(q.view(np.dtype((np.void, 3 * q.itemsize))).ravel(), return_index=True,
                                  return_inverse=True)
        order = np.argsort(first, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        ids = (rank[inv.ravel()] + self.offset + len(self.rows)).tolist()
        self.rows.extend(q[first[order]].tolist())
        return [ids[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def _solids(items: list[tuple[str, object]], vertices: _Vertices) -> list[dict]:
    """CityJSON ``Solid`` geometries of ``(lod, solid)`` pairs, their vertices numbered together."""
    kinds = {k: i for i, k in enumerate(SURFACE_KINDS)}
    flat = vertices.rings([np.asarray(r, dtype=np.float64) for _, solid in items for s in solid.surfaces
                           for r in s.rings])
    out, k = [], 0
    for lod, solid in items:
        shell = []
        for s in solid.surfaces:
            shell.append(flat[k:k + len(s.rings)])
            k += len(s.rings)
        out.append({"type": "Solid", "lod": lod, "boundaries": [shell],
                    "semantics": {"surfaces": [{"type": t} for t in SURFACE_KINDS],
                                  "values": [[kinds[s.kind] for s in solid.surfaces]]}})
    return out


def _extent(solids) -> np.ndarray | None:
    pts = [r for s in solids for surface in s.surfaces for r in surface.rings]
    if not pts:
        return None
    xyz = np.vstack(pts)
    return np.r_[xyz.min(axis=0), xyz.max(axis=0)]


def _objects(model, vertices: _Vertices) -> dict[str, dict]:
    """The ``Building`` (and its ``BuildingPart``\\ s) of one model."""
    bid = cityobject_id(model)
    attrs = {k: _clean(v) for k, v in model.attributes.items()}  # footprint_id too: the id and an attribute
    attrs["building_id"] = int(model.building_id)
    building: dict[str, Any] = {"type": "Building", "attributes": attrs}
    solids = [s for p in model.parts for s in p.lods.values()]
    ext = _extent(solids)
    if ext is not None:
        building["geographicalExtent"] = [round(float(v), 3) for v in ext]
    objects = {bid: building}
    items = [(part, lod) for part in model.parts for lod in LODS if lod in part.lods]
    geometry = _solids([(lod, part.lods[lod]) for part, lod in items], vertices)
    if len(model.parts) == 1:
        building["geometry"] = geometry
        return objects
    building["geometry"] = []
    building["children"] = []
    for part in model.parts:
        pid = f"{bid}-{part.part_id}"
        building["children"].append(pid)
        objects[pid] = {"type": "BuildingPart", "parents": [bid],
                        "attributes": {k: _clean(v) for k, v in part.attributes.items()},
                        "geometry": [g for (p, _), g in zip(items, geometry) if p is part]}
    return objects


class _Writer(StreamedOutput):
    """Shared by both writers: transform from the first model, extent, metadata, atomic output."""

    def __init__(self, path: str | os.PathLike, crs=None, *, overwrite: bool = False, scale: float = 0.001,
                 title: str = "3D buildings reconstructed by rooftrace"):
        super().__init__(path, overwrite)
        self.crs, self.scale, self.title = crs, float(scale), title
        self.extent: np.ndarray | None = None

    def _start(self, model) -> None:
        self._origin([s for p in model.parts for s in p.lods.values()])

    def _grow(self, model) -> None:
        ext = _extent([s for p in model.parts for s in p.lods.values()])
        if ext is not None:
            self.extent = ext if self.extent is None else np.r_[np.minimum(self.extent[:3], ext[:3]),
                                                                 np.maximum(self.extent[3:], ext[3:])]

    def _header(self) -> dict:
        translate = self.translate if self.translate is not None else np.zeros(3)
        meta: dict[str, Any] = {"title": self.title}
        ref = reference_system(self.crs)
        if ref is not None:
            meta["referenceSystem"] = ref
        if self.extent is not None:
            meta["geographicalExtent"] = [round(float(v), 3) for v in self.extent]
        return {"type": "CityJSON", "version": VERSION,
                "transform": {"scale": [self.scale] * 3, "translate": [float(v) for v in translate]},
                "metadata": meta}

    def _tempfile(self, suffix: str):
        """A scratch file beside the output, removed at the end (and by an interrupt: it is recorded)."""
        name = temporary_path(self.path.with_name(self.path.name + suffix))
        handle = open(name, "w+", encoding="utf-8")  # noqa: SIM115 - closed by the writer's exit stack

        def drop():
            handle.close()
            name.unlink(missing_ok=True)
            untrack(name)

        self._stack.callback(drop)
        return handle


class CityJSONSeqWriter(_Writer):
    """Write a CityJSONSeq file (``.city.jsonl``) one building at a time.

    Examples
    --------
    >>> import shapely, tempfile, pathlib
    >>> from rooftrace.model import BuildingModel, PartModel, prism_solid, horizontal_plane
    >>> solid = prism_solid([(shapely.box(0, 0, 5, 5), horizontal_plane(3.0))], 0.0)
    >>> model = BuildingModel(1, [PartModel(1, shapely.box(0, 0, 5, 5), {"1.2": solid})], {"status": "ok"})
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.city.jsonl"
    >>> with CityJSONSeqWriter(out) as w:
    ...     w.add(model)
    >>> [line[:30] for line in out.read_text().splitlines()]
    ['{"type":"CityJSON","version":"', '{"type":"CityJSONFeature","id"']
    """

    def __init__(self, path, crs=None, **kw):
        super().__init__(path, crs, **kw)
        self._features = self._tempfile(".features")

    def add(self, model) -> None:
        """Serialise one building as a ``CityJSONFeature`` line."""
        self._start(model)
        self._grow(model)
        vertices = _Vertices(self.translate, self.scale)
        objects = _objects(model, vertices)
        feature = {"type": "CityJSONFeature", "id": cityobject_id(model), "CityObjects": objects,
                   "vertices": vertices.rows}
        self._features.write(json.dumps(feature, **_DUMPS) + "\n")
        self.count += 1

    def close(self) -> Path:
        """Write the header and the features, rename onto the output."""
        with open(self._final, "w", encoding="utf-8") as out:
            header = self._header()
            header.update({"CityObjects": {}, "vertices": []})
            out.write(json.dumps(header, **_DUMPS) + "\n")
            self._features.seek(0)
            shutil.copyfileobj(self._features, out)
        return super().close()


class CityJSONWriter(_Writer):
    """Write a CityJSON 2.0 file (``.city.json``) one building at a time (see the module notes)."""

    def __init__(self, path, crs=None, **kw):
        super().__init__(path, crs, **kw)
        self._objects = self._tempfile(".objects")
        self._vertices = self._tempfile(".vertices")
        self._n_vertices = 0
        self._n_objects = 0

    def add(self, model) -> None:
        """Serialise one building's city objects and append its vertices to the shared list."""
        self._start(model)
        self._grow(model)
        vertices = _Vertices(self.translate, self.scale, offset=self._n_vertices)
        objects = _objects(model, vertices)
        for key, obj in objects.items():
            self._objects.write(("," if self._n_objects else "") + json.dumps(key) + ":" + json.dumps(obj, **_DUMPS))
            self._n_objects += 1
        self.count += 1
        if vertices.rows:
            text = json.dumps(vertices.rows, separators=(",", ":"))[1:-1]
            self._vertices.write(("," if self._n_vertices else "") + text)
            self._n_vertices += len(vertices.rows)

    def close(self) -> Path:
        """Join transform, city objects, vertices and metadata into the output, renamed into place."""
        header = self._header()
        meta = header.pop("metadata")
        with open(self._final, "w", encoding="utf-8") as out:
            head = json.dumps(header, **_DUMPS)
            out.write(head[:-1] + ',"CityObjects":{')
            self._objects.seek(0)
            shutil.copyfileobj(self._objects, out)
            out.write('},"vertices":[')
            self._vertices.seek(0)
            shutil.copyfileobj(self._vertices, out)
            out.write('],"metadata":' + json.dumps(meta, **_DUMPS) + "}\n")
        return super().close()
