"""One tile: the pipeline on its buffered points, the buildings it owns, and the merge of all tiles."""

from __future__ import annotations

import dataclasses
import logging
import os
import pickle
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rooftrace.tiling.split import load_tile_points, near_open_side, tile_grid

log = logging.getLogger(__name__)


def estimate_parameters(cloud, config: dict | None = None, *, origin: Sequence[float] | None = None,
                        extent: Sequence[float] | None = None):
    """Measure the data-derived detection parameters once, for every tile.

    Parameters
    ----------
    cloud : PointCloud
        The whole input, or the sample of :func:`sample_windows`.
    config : dict, optional
        Run config (the detection options).
    origin : (float, float), optional
        Anchor of the grids, fixed for the whole run.
    extent : (xmin, ymin, xmax, ymax), optional
        Bounds of the whole input (the ground filter's border).

    Returns
    -------
    DerivedParams
        The values a detection of ``cloud`` resolves: s_avg, d_avg,
        sigma_H, the k-means entropy threshold and centroids, ``origin``.

    Notes
    -----
    This runs the detection on ``cloud`` and keeps what it measured, so
    that on the whole input the parameters are exactly those of an untiled
    run.
    """
    from rooftrace.lidar.detect import DerivedParams, detect_buildings

    fixed = DerivedParams(origin=None if origin is None else (float(origin[0]), float(origin[1])),
                          extent=None if extent is None else tuple(float(v) for v in extent))
    return detect_buildings(cloud, config=config, derived=fixed).derived


def owned_buildings(xyz: np.ndarray, building_id: np.ndarray, core: Sequence[float],
                    origin: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which buildings of a tile belong to its core, and their global sort keys.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        The tile's points (m).
    building_id : ndarray of shape (N,), int
        Building of each point (1..B, 0 = none).
    core : (xmin, xmax, ymin, ymax)
        The tile core, half-open; infinite on the sides facing no tile.
    origin : (float, float)
        The run's grid anchor (the detection's local frame).

    Returns
    -------
    ids : ndarray of shape (B,), int64
        Building ids present in the tile.
    owned : ndarray of shape (B,), bool
        True when the centre of the building's bounding box in plan lies in
        the core.  The box, unlike a mean, does not depend on the order of
        the points, so every tile that sees the whole building agrees.
    key : ndarray of shape (B, 3), float64
        The building's lexicographically smallest point (x, y, z) in the
        detection's local frame: the untiled detection numbers buildings
        by it (:func:`rooftrace.lidar.segment.order_labels`).
    box : ndarray of shape (B, 4), float64
        xmin, ymin, xmax, ymax of each building (m).
    """
    building_id = np.asarray(building_id)
    sel = np.flatnonzero(building_id > 0)
    if len(sel) == 0:
        return np.zeros(0, np.int64), np.zeros(0, bool), np.zeros((0, 3)), np.zeros((0, 4))
    ids, inv = np.unique(building_id[sel], return_inverse=True)
    k = len(ids)
    p = xyz[sel]
    lo = np.full((k, 2), np.inf)
    hi = np.full((k, 2), -np.inf)
    for a in (0, 1):
        np.minimum.at(lo[:, a], inv, p[:, a])
        np.maximum.at(hi[:, a], inv, p[:, a])
    centre = (lo + hi) / 2
    x0, x1, y0, y1 = core
    owned = (centre[:, 0] >= x0) & (centre[:, 0] < x1) & (centre[:, 1] >= y0) & (centre[:, 1] < y1)
    local = p - np.array([origin[0], origin[1], 0.0])
    order = np.lexsort((local[:, 2], local[:, 1], local[:, 0], inv))
    first = order[np.unique(inv[order], return_index=True)[1]]
    return ids.astype(np.int64), owned, local[first], np.column_stack([lo, hi])


@dataclasses.dataclass(frozen=True)
class TileTask:
    """One tile's work as it goes to a worker: the arguments of :func:`process_tile`, by name."""

    run_dir: str
    key: str
    core: tuple[float, float, float, float]
    crs_wkt: str | None
    config: dict | None
    alpha: str | None
    planes: bool
    seed: int
    derived: dict[str, Any]
    extent: tuple[float, float, float, float] | None = None
    classified: bool = False
    refine_context: float | None = None

    def run(self) -> str:
        """:func:`process_tile` with these arguments; the path of the tile's result."""
        return process_tile(**{f.name: getattr(self, f.name) for f in dataclasses.fields(self)})


def process_tile(run_dir: str, key: str, core: Sequence[float], crs_wkt: str | None,
                 config: dict | None, alpha: str | None, planes: bool, seed: int,
                 derived: dict[str, Any], extent: Sequence[float] | None = None, classified: bool = False,
                 refine_context: float | None = None) -> str:
    """Run the pipeline on one buffered tile and keep the buildings whose centre is in its core.

    Parameters
    ----------
    run_dir : str
        Run folder holding ``tiles/<key>``; the result goes to
        ``results/<key>.pkl`` (written atomically, so a killed run leaves
        either a whole result or none).
    key : str
        Tile ``"<i>_<j>"``.
    core : (xmin, xmax, ymin, ymax)
        Half-open core; edge tiles reach to infinity so that a building
        beyond the header bounds still has an owner.
    crs_wkt : str or None
        CRS of the points.
    config, alpha, planes, seed
        As :func:`rooftrace.pipeline.run_pipeline`.
    derived : dict
        :meth:`DerivedParams.to_dict` of the run.
    extent : (xmin, ymin, xmax, ymax), optional
        The buffered tile clipped to the input's bounds: where the ground
        filter lays its border (see :class:`DerivedParams`).
    classified : bool, default False
        Also keep the labels of the core points (``results/<key>.labels.npz``,
        :func:`rooftrace.tiling.classified.core_labels`) for the classified LAZ.
    refine_context : float, optional
        ``[refine] context`` (m) of a run with an image: also keep the roof
        planes of the owned buildings and the points around them that the
        parent's image refinement uses (``planes`` and ``refine_points`` of
        the result, :func:`rooftrace.tiling.image.neighbourhood_points`).

    Returns
    -------
    str
        Path of the result.  An existing result is kept (``--resume``).
    """
    import pyproj
    import shapely

    from rooftrace.lidar.detect import DerivedParams
    from rooftrace.pipeline import run_pipeline

    run = Path(run_dir)
    out = run / "results" / f"{key}.pkl"
    if out.exists():
        return str(out)
    t0 = time.perf_counter()
    crs = pyproj.CRS.from_wkt(crs_wkt) if crs_wkt else None
    cloud = load_tile_points(run / "tiles" / key, crs)
    fixed = DerivedParams.from_dict(derived)
    bounds = fixed.extent  # of the whole input: past it there is no data to miss
    if extent is not None:
        fixed = dataclasses.replace(fixed, extent=tuple(float(v) for v in extent))
    result: dict[str, Any] = {"key": key, "points": len(cloud), "layers": {}, "buildings": {}, "timings": {},
                              "edge_buildings": []}
    labelled = None  # (classification, building_id, ids, keys) of the detection, when it ran
    if len(cloud) >= 3 and np.ptp(cloud.xyz[:, :2], axis=0).min() > 0:
        found: dict[str, np.ndarray] = {}

        def owned_only(xyz: np.ndarray, detection) -> np.ndarray:
            # outlines and roof planes are the costly stages: spend them on
            # the buildings this tile keeps, not on those of its buffer
            found["ids"], found["owned"], found["keys"], found["box"] = owned_buildings(
                xyz, detection.building_id, core, fixed.origin)
            return found["ids"][found["owned"]]

        run_out = run_pipeline(cloud, config=config, alpha=alpha, planes=planes, seed=seed, derived=fixed,
                               buildings=owned_only)
        det = run_out.detection
        ids, owned, keys, box = found["ids"], found["owned"], found["keys"], found["box"]
        labelled = (det.classification, det.building_id, ids, keys)
        keep_ids = ids[owned]
        # a building must be processed with all its points: one that reaches
        # the buffer's outer edge (where the tile stops but the data goes on)
        # may have been cut, so say so
        margin = max(2.0 * float(det.params["segment"]["link_distance"]), 1.0)
        tile_box, data_box = extent, bounds
        if tile_box is None or data_box is None:
            # no boxes given: the tile's points bound it, and the data goes on where the core has a neighbour
            tile_box = (*cloud.xyz[:, :2].min(axis=0), *cloud.xyz[:, :2].max(axis=0))
            neighbour = np.isfinite(np.asarray(core, float)[[0, 2, 1, 3]])
            data_box = np.where(neighbour, [-np.inf, -np.inf, np.inf, np.inf], tile_box)
        near = owned & near_open_side(box, tile_box, data_box, margin)
        result["edge_buildings"] = box[near].tolist()
        for b in box[near]:
            log.warning("tile %s: the building at (%.1f, %.1f)-(%.1f, %.1f) reaches the buffer's edge and may be "
                        "cut; rerun with a larger --buffer", key, *b)
        for name, layer in run_out.layers.items():
            bid = np.asarray(layer.attributes.get("building_id", []), dtype=np.int64)
            keep = np.isin(bid, keep_ids)
            geoms = np.asarray(layer.geometries, dtype=object)[keep] if len(bid) else np.empty(0, object)
            result["layers"][name] = {
                "wkb": [None if g is None else shapely.to_wkb(g, output_dimension=3) for g in geoms],
                "attributes": {a: [v for v, k in zip(col, keep) if k] for a, col in layer.attributes.items()},
                "geometry_type": layer.geometry_type,
            }
        result["buildings"] = {"id": keep_ids.tolist(), "key": keys[owned].tolist()}
        keep = set(keep_ids.tolist())
        result["models"] = [m for m in run_out.models if m.building_id in keep]
        if refine_context is not None:
            _keep_for_refinement(result, cloud, run_out, keep_ids, refine_context)
        result["timings"] = {**det.timings, **run_out.timings}
        result["core_points"] = int(((cloud.xyz[:, 0] >= core[0]) & (cloud.xyz[:, 0] < core[1])
                                     & (cloud.xyz[:, 1] >= core[2]) & (cloud.xyz[:, 1] < core[3])).sum())
    result["seconds"] = time.perf_counter() - t0
    out.parent.mkdir(parents=True, exist_ok=True)
    if classified:
        # before the result: a result file means the tile is finished, labels included
        _save_labels(out.with_suffix(".labels.npz"), cloud, core, labelled)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_bytes(pickle.dumps(result))
    os.replace(tmp, out)
    return str(out)


def _keep_for_refinement(result: dict, cloud, run_out, keep_ids: np.ndarray, context: float) -> None:
    """Store what the parent's image refinement needs of the buildings this tile owns."""
    from rooftrace.tiling.image import neighbourhood_points

    keep = {int(b) for b in keep_ids}
    result["planes"] = {int(s.building_id): np.asarray(s.planes, float) for s in run_out.structures
                        if int(s.building_id) in keep}
    polygons = [o.polygon for o in run_out.outlines if int(o.building_id) in keep]
    result["refine_points"], discs = neighbourhood_points(cloud.xyz, cloud.fields["gidx"], polygons, context)
    result["refine_discs"] = discs.tolist()  # the parent warns about those its tile may have cut


def write_classified_points(paths, out, results, result_paths, n_points, crs, overwrite) -> None:
    """Write the input points with the merged run's classes and building ids (the tiled ``--classified``)."""
    from rooftrace.io.las import write_las_labels
    from rooftrace.tiling.classified import merge_labels

    new_id = {key: n for key, _, _, n in building_numbers(results)}
    parts = []
    for r in result_paths:
        with np.load(Path(r).with_suffix(".labels.npz")) as z:
            parts.append({name: z[name] for name in z.files})
    classes, building_id = merge_labels(parts, new_id, n_points)
    write_las_labels(paths, out, classes, building_id, crs=crs, overwrite=overwrite)


def _save_labels(path: Path, cloud, core: Sequence[float], labelled) -> None:
    from rooftrace.tiling.classified import core_labels

    if labelled is None:  # too few points to detect anything: unclassified
        n = len(cloud)
        labelled = (np.ones(n, np.uint8), np.zeros(n, np.int32), np.zeros(0, np.int64), np.zeros((0, 3)))
    labels = core_labels(cloud.fields["gidx"], cloud.xyz[:, :2], core, *labelled)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **labels)
    os.replace(tmp, path)


def tile_core(index: dict, key: str) -> tuple[float, float, float, float]:
    """The core of tile ``key`` (xmin, ymin, xmax, ymax; infinite on the outer sides of the grid)."""
    size = index["tile_size"]
    xs, ys = tile_grid(index["bounds"], size)
    i, j = (int(v) for v in key.split("_"))
    x0, y0 = xs[i], ys[j]
    return (-np.inf if i == 0 else float(x0), np.inf if i == len(xs) - 1 else float(x0 + size),
            -np.inf if j == 0 else float(y0), np.inf if j == len(ys) - 1 else float(y0 + size))


def tile_extent(index: dict, key: str) -> list[float]:
    """The buffered tile (whole cells) clipped to the input's bounds."""
    (ox, oy), cell, b = index["origin"], index["cell"], index["bounds"]
    cx0, cx1, cy0, cy1 = index["tiles"][key]["cells"]
    return [max(ox + cx0 * cell, b[0]), max(oy + cy0 * cell, b[1]),
            min(ox + (cx1 + 1) * cell, b[2]), min(oy + (cy1 + 1) * cell, b[3])]


def building_numbers(results: Sequence[dict]) -> list[tuple[tuple, int, int, int]]:
    """The merged numbering: ``(key, tile position, id in the tile, new id)`` of every owned building.

    Buildings are numbered 1..B by their sort key (lowest local x, then y,
    then z), the rule of the untiled detection; the layers and the
    classified points both use it.
    """
    entries = sorted((tuple(k), t, old) for t, res in enumerate(results)
                     for old, k in zip(res["buildings"].get("id", []), res["buildings"].get("key", [])))
    return [(k, t, old, n + 1) for n, (k, t, old) in enumerate(entries)]


def merged_models(results: Sequence[dict]) -> list:
    """The tiles' 3D models, renumbered as :func:`merge_tiles` numbers the buildings and in that order."""
    new_id = {(t, old): n for _, t, old, n in building_numbers(results)}
    models = []
    for t, res in enumerate(results):
        for m in res.get("models", []):
            m.building_id = new_id[(t, m.building_id)]
            models.append(m)
    return sorted(models, key=lambda m: m.building_id)


def merge_tiles(results: Sequence[dict]) -> dict:
    """Join tile results into the output layers.

    Buildings are numbered 1..B by their sort key (lowest local x, then y,
    then z), the rule of the untiled detection, and the features of every
    layer are ordered by building and, within a building, as the pipeline
    made them; so the output depends neither on the tiling nor on the
    order in which tiles finished.
    """
    import shapely

    from rooftrace.io.vector import Layer

    new_id = {(t, old): n for _, t, old, n in building_numbers(results)}
    merged: dict[str, dict] = {}
    for t, res in enumerate(results):
        for name, layer in res["layers"].items():
            m = merged.setdefault(name, {"rows": [], "geometry_type": layer["geometry_type"], "fields": []})
            for a in layer["attributes"]:
                if a not in m["fields"]:
                    m["fields"].append(a)
            bids = layer["attributes"].get("building_id", [])
            for r, (w, b) in enumerate(zip(layer["wkb"], bids)):
                attrs = {a: col[r] for a, col in layer["attributes"].items()}
                attrs["building_id"] = new_id[(t, b)]
                m["rows"].append((attrs["building_id"], r, w, attrs))
    out = {}
    for name, m in merged.items():
        rows = sorted(m["rows"], key=lambda row: (row[0], row[1]))
        geoms = [None if w is None else shapely.from_wkb(w) for _, _, w, _ in rows]
        attrs = {a: [row[3].get(a) for row in rows] for a in m["fields"]}
        out[name] = Layer(geoms, attrs, m["geometry_type"])
    return out
