"""One tile: the pipeline on its buffered points, the buildings it owns, and the merge of all tiles."""

from __future__ import annotations

import dataclasses
import logging
import os
import pickle
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rooftrace.footprints import Footprints
from rooftrace.io.vector import Layer
from rooftrace.lidar.detect import DerivedParams, DetectOptions
from rooftrace.model.types import BuildingModel
from rooftrace.tiling.models import ModelStream, save_models
from rooftrace.tiling.split import load_tile_points, near_open_side, tile_grid

if TYPE_CHECKING:  # rooftrace.config imports TileOptions from this package
    from rooftrace.config import RunOptions

log = logging.getLogger(__name__)


def estimate_parameters(cloud, options: DetectOptions | None = None, *, origin: Sequence[float] | None = None,
                        extent: Sequence[float] | None = None) -> DerivedParams:
    """Measure the data-derived detection parameters once, for every tile.

    Parameters
    ----------
    cloud : PointCloud
        The whole input, or the sample of :func:`sample_windows`.
    options : DetectOptions, optional
        The run's detection options.
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
    from rooftrace.lidar.detect import detect_buildings

    fixed = DerivedParams(origin=None if origin is None else (float(origin[0]), float(origin[1])),
                          extent=None if extent is None else tuple(float(v) for v in extent))
    return detect_buildings(cloud, options, derived=fixed).derived


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
class TileFootprints:
    """The footprints of a run as one tile sees them.

    Attributes
    ----------
    footprints : Footprints
        Every footprint near the buffered tile (within reach of its points'
        assignment and of the outline clipping) and every footprint the tile
        owns, in the run's order.
    index : ndarray of shape (F,), int64
        Position of each in the run's footprints: the merge numbers the
        buildings by it, as the untiled run does (building id = position + 1).
    owned : ndarray of shape (F,), bool
        The footprints whose building this tile outputs: each footprint is
        owned by exactly one tile (:func:`footprints_per_tile`).
    """

    footprints: Footprints
    index: np.ndarray
    owned: np.ndarray


@dataclasses.dataclass(frozen=True)
class TileTask:
    """One tile's work as it goes to a worker.

    Attributes
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
    options : RunOptions
        The run's options (:func:`rooftrace.pipeline.run_pipeline`).
    seed : int
        Seed of the run.
    derived : DerivedParams
        The data-derived detection parameters of the whole run.
    extent : (xmin, ymin, xmax, ymax), optional
        The buffered tile clipped to the input's bounds: where the ground
        filter lays its border (see :class:`DerivedParams`).
    classified : bool, default False
        Also keep the labels of the core points (``results/<key>.labels.npz``,
        :func:`rooftrace.tiling.classified.core_labels`) for the classified points.
    refine_context : float, optional
        ``[refine] context`` (m) of a run with an image: also keep the roof
        planes of the owned buildings and the points around them that the
        parent's image refinement uses (:func:`rooftrace.tiling.image.neighbourhood_points`).
    footprints : TileFootprints, optional
        The footprints this tile sees and those it owns (a run with
        footprints: one building per footprint).
    """

    run_dir: str
    key: str
    core: tuple[float, float, float, float]
    crs_wkt: str | None
    options: RunOptions
    seed: int
    derived: DerivedParams
    extent: tuple[float, float, float, float] | None = None
    classified: bool = False
    refine_context: float | None = None
    footprints: TileFootprints | None = None

    def run(self) -> str:
        """:func:`process_tile` of this task; the path of the tile's result."""
        return process_tile(self)


@dataclasses.dataclass
class TileResult:
    """What one tile gives the merge: the buildings whose centre is in its core.

    Attributes
    ----------
    key : str
        Tile ``"<i>_<j>"``.
    points : int
        Points of the buffered tile.
    layers : dict of str to Layer
        The pipeline's layers, only the features of the owned buildings,
        with the tile's building ids.
    building_ids : ndarray of shape (B,), int64
        Tile ids of the owned buildings.
    building_keys : ndarray of shape (B, 3), float64
        Their sort keys (:func:`owned_buildings`): the merge numbers by them.
    models : list of BuildingModel
        3D models of the owned buildings, with the tile's ids, when held in
        memory; :func:`process_tile` writes them to ``models_file`` instead
        and leaves this empty.
    models_file : str or None
        Name, in the result's folder, of the file holding the owned
        buildings' models (:func:`rooftrace.tiling.models.save_models`), in
        the merge's order.
    timings : dict of str to float
        Seconds per pipeline stage.
    edge_buildings : ndarray of shape (E, 4), float64
        Boxes of owned buildings that reach the buffer's open edge (maybe cut).
    core_points : int
        Points in the core.
    seconds : float
        Wall time of the tile.
    planes : dict of int to ndarray of shape (K, 4)
        Roof planes of the owned buildings, by tile id (runs with an image).
    refine_points : dict of str to ndarray
        ``gidx`` and ``xyz`` of the points around the owned buildings that
        the image refinement uses (runs with an image).
    refine_discs : ndarray of shape (D, 3), float64
        Centre and radius (m) of those neighbourhoods.
    """

    key: str
    points: int = 0
    layers: dict[str, Layer] = dataclasses.field(default_factory=dict)
    building_ids: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    building_keys: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    models: list[BuildingModel] = dataclasses.field(default_factory=list)
    models_file: str | None = None
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    edge_buildings: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4)))
    core_points: int = 0
    seconds: float = 0.0
    planes: dict[int, np.ndarray] = dataclasses.field(default_factory=dict)
    refine_points: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    refine_discs: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))


def process_tile(task: TileTask) -> str:
    """Run the pipeline on one buffered tile and keep the buildings whose centre is in its core.

    Parameters
    ----------
    task : TileTask

    Returns
    -------
    str
        Path of the pickled :class:`TileResult`.  An existing result is
        kept (``resume``).
    """
    import pyproj

    from rooftrace.pipeline import run_pipeline

    run = Path(task.run_dir)
    core, key = task.core, task.key
    out = run / "results" / f"{key}.pkl"
    if out.exists():
        return str(out)
    t0 = time.perf_counter()
    crs = pyproj.CRS.from_wkt(task.crs_wkt) if task.crs_wkt else None
    cloud = load_tile_points(run / "tiles" / key, crs)
    fixed = task.derived
    bounds = fixed.extent  # of the whole input: past it there is no data to miss
    if task.extent is not None:
        fixed = dataclasses.replace(fixed, extent=tuple(float(v) for v in task.extent))
    result = TileResult(key=key, points=len(cloud))
    labelled = None  # (classification, building_id, ids, keys) of the detection, when it ran
    prints = task.footprints
    if len(cloud) >= 3 and np.ptp(cloud.xyz[:, :2], axis=0).min() > 0:
        found: dict[str, np.ndarray] = {}

        def owned_only(xyz: np.ndarray, detection) -> np.ndarray:
            # outlines and roof planes are the costly stages: spend them on
            # the buildings this tile keeps, not on those of its buffer
            if prints is not None:  # a footprint's building: where the parent said
                found.update(footprint_buildings(prints))
            else:
                found["ids"], found["owned"], found["keys"], found["box"] = owned_buildings(
                    xyz, detection.building_id, core, fixed.origin)
            return found["ids"][found["owned"]]

        run_out = run_pipeline(cloud, task.options, seed=task.seed, derived=fixed, buildings=owned_only,
                               footprints=None if prints is None else prints.footprints)
        det = run_out.detection
        ids, owned, keys, box = found["ids"], found["owned"], found["keys"], found["box"]
        # with footprints, a point's building is its footprint's, owned here or not
        labelled = (det.classification, det.building_id if prints is None else run_out.assignment.building_id,
                    ids, keys)
        keep_ids = ids[owned]
        # a building must be processed with all its points: one that reaches
        # the buffer's outer edge (where the tile stops but the data goes on)
        # may have been cut, so say so
        margin = max(2.0 * float(det.params["segment"]["link_distance"]), 1.0)
        tile_box, data_box = task.extent, bounds
        if tile_box is None or data_box is None:
            # no boxes given: the tile's points bound it, and the data goes on where the core has a neighbour
            tile_box = (*cloud.xyz[:, :2].min(axis=0), *cloud.xyz[:, :2].max(axis=0))
            neighbour = np.isfinite(np.asarray(core, float)[[0, 2, 1, 3]])
            data_box = np.where(neighbour, [-np.inf, -np.inf, np.inf, np.inf], tile_box)
        near = owned & near_open_side(box, tile_box, data_box, margin)
        result.edge_buildings = box[near]
        for b in box[near]:
            log.warning("tile %s: the building at (%.1f, %.1f)-(%.1f, %.1f) reaches the buffer's edge and may be "
                        "cut; rerun with a larger buffer", key, *b)
        result.layers = {name: _owned_features(layer, keep_ids) for name, layer in run_out.layers.items()}
        result.building_ids, result.building_keys = keep_ids, keys[owned]
        # the models go to a file of their own in the merge's order (sort key, then id), so that the
        # parent streams them instead of holding every tile's (tiling.models)
        rank = {int(b): (tuple(k), int(b)) for b, k in zip(keep_ids.tolist(), keys[owned].tolist())}
        models = sorted((m for m in run_out.models if m.building_id in rank), key=lambda m: rank[m.building_id])
        result.models_file = out.with_suffix(".models").name
        out.parent.mkdir(parents=True, exist_ok=True)
        save_models(out.with_suffix(".models"), models)
        del models
        if task.refine_context is not None:
            _keep_for_refinement(result, cloud, run_out, keep_ids, task.refine_context)
        result.timings = {**det.timings, **run_out.timings}
        result.core_points = int(((cloud.xyz[:, 0] >= core[0]) & (cloud.xyz[:, 0] < core[1])
                                  & (cloud.xyz[:, 1] >= core[2]) & (cloud.xyz[:, 1] < core[3])).sum())
    result.seconds = time.perf_counter() - t0
    out.parent.mkdir(parents=True, exist_ok=True)
    if task.classified:
        # before the result: a result file means the tile is finished, labels included
        _save_labels(out.with_suffix(".labels.npz"), cloud, core, labelled)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_bytes(pickle.dumps(result))
    os.replace(tmp, out)
    return str(out)


def footprint_buildings(prints: TileFootprints) -> dict[str, np.ndarray]:
    """The buildings of a tile with footprints, as :func:`owned_buildings` gives those of the detection.

    Building ``i + 1`` of the tile is its footprint ``i``; its sort key is
    the footprint's position in the run (so the merge numbers it as the
    untiled run does) and its box the footprint's bounds.
    """
    import shapely

    n = len(prints.footprints)
    keys = np.zeros((n, 3))
    keys[:, 0] = prints.index
    box = shapely.bounds(np.asarray(prints.footprints.polygons, dtype=object)).reshape(-1, 4)
    return {"ids": np.arange(1, n + 1, dtype=np.int64), "owned": np.asarray(prints.owned, bool), "keys": keys,
            "box": box}


def footprints_per_tile(footprints: Footprints, index: dict, keys: Sequence[str], reach: float
                        ) -> dict[str, TileFootprints]:
    """Split a run's footprints along its tiles, as the points are split.

    Parameters
    ----------
    footprints : Footprints
        The run's footprints, in the points' CRS.
    index : dict
        The split's index (:func:`rooftrace.tiling.split.split_to_tiles`).
    keys : sequence of str
        The tiles.
    reach : float
        How far (m) beyond a tile's buffered extent a footprint still
        matters to the tile's footprints (the assignment's overhang band and
        the search for neighbours that clip an outline).

    Returns
    -------
    dict of str to TileFootprints
        Per tile, the footprints that touch its buffered extent grown by
        ``reach``, and those it owns.  A footprint is owned by the tile
        whose core holds the centre of its bounding box, or when that tile
        has no points, by the tile with the nearest core; so every footprint
        is output once, even one over no data.
    """
    import shapely

    polygons = np.asarray(footprints.polygons, dtype=object)
    bounds = shapely.bounds(polygons).reshape(-1, 4)
    centre = (bounds[:, :2] + bounds[:, 2:]) / 2
    cores = np.array([tile_core(index, k) for k in keys], float).reshape(-1, 4)  # xmin, xmax, ymin, ymax
    # distance from each centre to each core box (0 inside); the first of equals, in tile order, wins
    dx = np.maximum(np.maximum(cores[None, :, 0] - centre[:, None, 0], centre[:, None, 0] - cores[None, :, 1]), 0.0)
    dy = np.maximum(np.maximum(cores[None, :, 2] - centre[:, None, 1], centre[:, None, 1] - cores[None, :, 3]), 0.0)
    owner = np.argmin(np.nan_to_num(np.hypot(dx, dy), nan=np.inf), axis=1) if len(keys) else np.zeros(0, int)
    tree = shapely.STRtree(polygons)
    out = {}
    for t, k in enumerate(keys):
        near = tree.query(shapely.box(*tile_extent(index, k)).buffer(reach, join_style="mitre"))
        mine = np.union1d(near, np.flatnonzero(owner == t)).astype(np.int64)  # sorted: the run's order
        out[k] = TileFootprints(
            Footprints(tuple(polygons[mine]), tuple(footprints.ids[i] for i in mine), footprints.id_field),
            mine, owner[mine] == t)
    return out


def _owned_features(layer: Layer, keep_ids: np.ndarray) -> Layer:
    """The features of ``layer`` that belong to the buildings ``keep_ids``, in the pipeline's order."""
    bid = np.asarray(layer.attributes.get("building_id", []), dtype=np.int64)
    keep = np.isin(bid, keep_ids)
    geoms = list(np.asarray(layer.geometries, dtype=object)[keep]) if len(bid) else []
    return Layer(geoms, {a: [v for v, k in zip(col, keep) if k] for a, col in layer.attributes.items()},
                 layer.geometry_type)


def _keep_for_refinement(result: TileResult, cloud, run_out, keep_ids: np.ndarray, context: float) -> None:
    """Store what the parent's image refinement needs of the buildings this tile owns."""
    from rooftrace.tiling.image import neighbourhood_points

    keep = {int(b) for b in keep_ids}
    result.planes = {int(s.building_id): np.asarray(s.planes, float) for s in run_out.structures
                     if int(s.building_id) in keep}
    polygons = [o.polygon for o in run_out.outlines if int(o.building_id) in keep]
    # the discs: the parent warns about those its tile may have cut
    result.refine_points, result.refine_discs = neighbourhood_points(cloud.xyz, cloud.fields["gidx"], polygons,
                                                                     context)


def merged_point_labels(results: Sequence[TileResult], result_paths: Sequence[str], n_points: int
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Classes and merged building ids of every input point, in input order (the tiled classified points)."""
    from rooftrace.tiling.classified import merge_labels

    new_id = {key: n for key, _, _, n in building_numbers(results)}
    parts = []
    for r in result_paths:
        with np.load(Path(r).with_suffix(".labels.npz")) as z:
            parts.append({name: z[name] for name in z.files})
    return merge_labels(parts, new_id, n_points)


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
    """The core of tile ``key`` (xmin, xmax, ymin, ymax, half-open; infinite on the outer sides of the grid)."""
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


def building_numbers(results: Sequence[TileResult]) -> list[tuple[tuple, int, int, int]]:
    """The merged numbering: ``(key, tile position, id in the tile, new id)`` of every owned building.

    Buildings are numbered 1..B by their sort key (lowest local x, then y,
    then z), the rule of the untiled detection; the layers and the
    classified points both use it.
    """
    entries = sorted((tuple(k), t, old) for t, res in enumerate(results)
                     for old, k in zip(res.building_ids.tolist(), res.building_keys.tolist()))
    return [(k, t, old, n + 1) for n, (k, t, old) in enumerate(entries)]


def merged_models(results: Sequence[TileResult], result_paths: Sequence[str] | None = None) -> ModelStream:
    """The tiles' 3D models, renumbered as :func:`merge_tiles` numbers the buildings and in that order.

    Streamed (:class:`~rooftrace.tiling.models.ModelStream`): a tile's
    models are read from its ``models_file`` (beside its result in
    ``result_paths``) one at a time as the stream is iterated, or taken from
    ``models`` when it holds them.  The files must stay until it is read.
    """
    new_id = {(t, old): n for _, t, old, n in building_numbers(results)}
    sources = []
    for t, res in enumerate(results):
        if res.models_file is not None and result_paths is not None:
            sources.append(str(Path(result_paths[t]).with_name(res.models_file)))
        else:
            sources.append(sorted(res.models, key=lambda m: new_id[(t, m.building_id)]))
    return ModelStream(sources, new_id)


def merge_tiles(results: Sequence[TileResult]) -> dict[str, Layer]:
    """Join tile results into the output layers.

    Buildings are numbered 1..B by their sort key (lowest local x, then y,
    then z), the rule of the untiled detection, and the features of every
    layer are ordered by building and, within a building, as the pipeline
    made them; so the output depends neither on the tiling nor on the
    order in which tiles finished.
    """
    new_id = {(t, old): n for _, t, old, n in building_numbers(results)}
    merged: dict[str, dict] = {}
    for t, res in enumerate(results):
        for name, layer in res.layers.items():
            m = merged.setdefault(name, {"rows": [], "geometry_type": layer.geometry_type, "fields": []})
            for a in layer.attributes:
                if a not in m["fields"]:
                    m["fields"].append(a)
            bids = layer.attributes.get("building_id", [])
            for r, (g, b) in enumerate(zip(layer.geometries, bids)):
                attrs = {a: col[r] for a, col in layer.attributes.items()}
                attrs["building_id"] = new_id[(t, b)]
                m["rows"].append((attrs["building_id"], r, g, attrs))
    out = {}
    for name, m in merged.items():
        rows = sorted(m["rows"], key=lambda row: (row[0], row[1]))
        attrs = {a: [row[3].get(a) for row in rows] for a in m["fields"]}
        out[name] = Layer([g for _, _, g, _ in rows], attrs, m["geometry_type"])
    return out
