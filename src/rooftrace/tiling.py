"""City-scale runs: square tiles with buffers, a local pool or Dask, resumable.

Why not just ``dask.dataframe``?  The unit of work is a *tile with its
buffer*, and the rule that keeps seams clean is about buildings, not points:
every tile is processed with a buffer wide enough for the ground filter and
the largest building, and a building belongs to the tile whose core holds
its centre (the centre of its points' bounding box in plan), so nothing is
duplicated and nothing is cut.

A tile gives the same buildings as the whole cloud only if it detects them
with the same numbers.  Every data-derived detection parameter (s_avg,
d_avg, sigma_H, the k-means entropy threshold, the corner the outlier and
ground grids are anchored at) is therefore measured once on the whole input
(or, above ``sample_points``, on a fixed spatial sample of it) and passed to
every tile (:class:`rooftrace.lidar.detect.DerivedParams`).  An input that
fits the sample is measured whole, which is exactly what an untiled
``rooftrace run`` does, so tiled and untiled runs agree.  The buffered
extents follow the outlier filter's cell lines, so that the cells a tile
judges are whole.

Flow (each step restartable):

1. ``split``: stream every input file once, in chunks, and append each
   point to the buffered tiles it falls in (``RUN/tiles/<i>_<j>/*.npy``)
   and, when it is in the sample, to ``RUN/sample``.  Peak memory is one
   chunk plus the sample, not the input.
2. ``estimate``: detect on the sample and keep its resolved parameters
   (``RUN/derived.json``).
3. ``process``: run :func:`rooftrace.pipeline.run_pipeline` per tile with
   those parameters, keep the buildings whose centre lies in the tile core
   and store them as ``RUN/results/<i>_<j>.pkl``.  Tiles run in-process
   (``workers=1``), on a Dask LocalCluster or on a Dask cluster
   (``--scheduler``; the run folder must be on a file system every worker
   sees).
4. ``merge``: join the tile results, number the buildings by their lowest
   (x, y, z) point like the untiled detection does, and write the
   GeoPackage atomically.

Results do not depend on the number of workers: tiles are independent and
merged in a fixed order.  ``--resume`` keeps the split, the parameters and
every finished tile of an earlier run of the same inputs and options.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import pickle
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from rooftrace.errors import InputError

__all__ = [
    "TileOptions", "tile_grid", "tile_cell_ranges", "sample_windows", "split_to_tiles", "estimate_parameters",
    "owned_buildings", "process_tile", "merge_tiles", "run_tiled",
]

log = logging.getLogger(__name__)

# one record per point in the tile files: what the detection reads from a LAS file
POINT_DTYPE = np.dtype([("x", "f8"), ("y", "f8"), ("z", "f8"), ("return_number", "u1"), ("number_of_returns", "u1"),
                        ("gidx", "i8")])  # gidx: the point's index in the input files, for the classified points


@dataclass(frozen=True)
class TileOptions:
    """Tiling and execution options.

    Attributes
    ----------
    tile_size : float or None
        Side of the square tile cores, metres.  ``None``: 200 m.
    buffer : float or None
        Buffer around each core, metres, rounded up so that the buffered
        tile follows the outlier filter's cell lines.  ``None``: 60 m, wider
        than the ground filter's seed cell (30 m) and the largest buildings
        of a historic centre; a building must fit in the buffer to be
        processed with all its points (a warning names those that touch the
        buffer's edge).
    workers : int
        Worker processes of the local Dask cluster; 1 runs in-process.
    scheduler : str or None
        Address of an existing Dask scheduler (``tcp://host:8786``).
    resume : bool
        Keep the split, the parameters and the tile results of an earlier run.
    chunk_size : int
        Points decoded at once while splitting.
    sample_points : int
        Largest number of points the data-derived parameters are measured
        on.  Inputs up to this size are measured whole (the parameters of
        an untiled run); larger ones on four square windows of about
        ``sample_points / 4`` points each, centred in the quarters of the
        input's extent.
    """

    section = "tiling"

    tile_size: float | None = None
    buffer: float | None = None
    workers: int = 1
    scheduler: str | None = None
    resume: bool = False
    chunk_size: int = 1_000_000
    sample_points: int = 2_000_000

    def __post_init__(self) -> None:
        for name in ("tile_size", "buffer"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise InputError(f"--{name.replace('_', '-')} must be a number > 0 (metres), got {v}")
        if self.workers < 1:
            raise InputError(f"--workers must be >= 1, got {self.workers}")
        if self.chunk_size < 1 or self.sample_points < 1000:
            raise InputError(f"tiling: chunk_size must be >= 1 and sample_points >= 1000, got "
                             f"{self.chunk_size}, {self.sample_points}")

    @property
    def resolved_tile_size(self) -> float:
        return 200.0 if self.tile_size is None else float(self.tile_size)

    @property
    def resolved_buffer(self) -> float:
        return 60.0 if self.buffer is None else float(self.buffer)


def tile_grid(bounds: Sequence[float], tile_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Tile core origins covering ``bounds``.

    Parameters
    ----------
    bounds : sequence of 4 floats
        xmin, ymin, xmax, ymax (m).
    tile_size : float
        Side of the tile cores (m).

    Returns
    -------
    xs, ys : ndarray of float64
        Lower-left corners of the columns and rows.  The grid is anchored at
        multiples of ``tile_size`` so that the same data always gives the
        same tiles.

    Examples
    --------
    >>> tile_grid([1030.0, 2010.0, 1190.0, 2100.0], 100.0)
    (array([1000., 1100.]), array([2000., 2100.]))
    """
    xmin, ymin, xmax, ymax = bounds
    x0 = np.floor(xmin / tile_size) * tile_size
    y0 = np.floor(ymin / tile_size) * tile_size
    nx = max(1, int(np.floor((xmax - x0) / tile_size)) + 1)
    ny = max(1, int(np.floor((ymax - y0) / tile_size)) + 1)
    return x0 + tile_size * np.arange(nx), y0 + tile_size * np.arange(ny)


def _cells(v: np.ndarray, origin: float, cell: float) -> np.ndarray:
    # the same expression as the outlier filter's cell index, so that a tile
    # and the filter agree on every point, rounding included
    return np.floor((v - origin) / cell).astype(np.int64)


def tile_cell_ranges(starts: np.ndarray, size: float, buffer: float, origin: float, cell: float) -> np.ndarray:
    """First and last cell (inclusive) of each buffered tile along one axis.

    Parameters
    ----------
    starts : ndarray of shape (T,)
        Core starts along the axis (m), from :func:`tile_grid`.
    size, buffer : float
        Core side and buffer (m).
    origin, cell : float
        Anchor and side (m) of the outlier filter's cells.

    Returns
    -------
    ndarray of shape (T, 2), int64
        The buffered tile ``[start - buffer, start + size + buffer)`` widened
        to whole cells.  Both columns increase with the tile index.
    """
    starts = np.asarray(starts, np.float64)
    lo = np.floor((starts - buffer - origin) / cell).astype(np.int64)
    hi = np.ceil((starts + size + buffer - origin) / cell).astype(np.int64) - 1
    return np.column_stack([lo, hi])


def _members(k: np.ndarray, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last tile (inclusive) whose cell range holds each cell index ``k``."""
    first = np.searchsorted(ranges[:, 1], k, side="left")
    last = np.searchsorted(ranges[:, 0], k, side="right") - 1
    return first, last


def sample_windows(bounds: Sequence[float], n_points: int, sample_points: int, origin: Sequence[float],
                   cell: float) -> np.ndarray | None:
    """Cell ranges of the windows the parameters are measured on; ``None``: the whole input.

    Four square windows of about ``sample_points / 4`` points each (at the
    mean density of the extent), centred in the quarters of the extent and
    made of whole outlier cells.  Fixed by the headers only, so a resumed
    or re-run job samples the same points.

    Returns
    -------
    ndarray of shape (W, 4), int64 or None
        Per window the first and last cell in x, then in y (inclusive).
    """
    if n_points <= sample_points:
        return None
    xmin, ymin, xmax, ymax = bounds
    area = max((xmax - xmin) * (ymax - ymin), 1.0)
    side = np.sqrt(area * (sample_points / 4) / n_points)
    half = max(1, int(np.ceil(side / cell / 2)))
    out = []
    for fx in (0.25, 0.75):
        for fy in (0.25, 0.75):
            cx = int(np.floor((xmin + fx * (xmax - xmin) - origin[0]) / cell))
            cy = int(np.floor((ymin + fy * (ymax - ymin) - origin[1]) / cell))
            out.append([cx - half + 1, cx + half, cy - half + 1, cy + half])
    return np.asarray(out, np.int64)


def _scan_headers(paths: Sequence[Path]) -> dict[str, Any]:
    import laspy

    from rooftrace.io.las import check_point_count, las_crs

    bounds, crss, counts = [], [], []
    for p in paths:
        if not p.is_file():
            raise InputError(f"{p}: no such file")
        if p.suffix.lower() not in (".las", ".laz"):
            raise InputError(f"{p}: tiled runs read LAS/LAZ only")
        try:
            with laspy.open(p) as r:
                h = r.header
                check_point_count(p, h)
                bounds.append([*h.mins[:2], *h.maxs[:2]])
                crss.append(las_crs(h, str(p)))
                counts.append(int(h.point_count))
        except laspy.errors.LaspyException as exc:
            raise InputError(f"{p}: not a readable LAS/LAZ file ({exc})") from None
    b = np.asarray(bounds, float)
    return {"bounds": [float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())],
            "crs": crss, "points": int(sum(counts))}


def _records(chunk, start: int) -> np.ndarray:
    rec = np.empty(len(chunk), POINT_DTYPE)
    rec["gidx"] = start + np.arange(len(chunk))
    rec["x"], rec["y"], rec["z"] = chunk.x, chunk.y, chunk.z
    rec["return_number"] = np.asarray(chunk.return_number)
    rec["number_of_returns"] = np.asarray(chunk.number_of_returns)
    return rec


def split_to_tiles(paths: Sequence[Path], run_dir: Path, options: TileOptions, *,
                   origin: Sequence[float] | None = None, cell: float = 50.0) -> dict[str, Any]:
    """Stream the inputs once into buffered tiles (and the parameter sample) under ``run_dir``.

    Parameters
    ----------
    paths : sequence of Path
        LAS/LAZ files.
    run_dir : Path
        Run folder; ``tiles/<i>_<j>/<file>_<chunk>.npy`` and
        ``sample/<file>_<chunk>.npy`` are written there, then ``tiles.json``.
    options : TileOptions
    origin : (float, float), optional
        Anchor of the cells the buffered tiles are made of; default the
        lower-left corner of the headers' bounds.
    cell : float, default 50.0
        The outlier filter's cell side (m).

    Returns
    -------
    dict
        The tile index: ``tile_size``, ``buffer``, ``bounds``, ``origin``,
        ``cell``, ``points`` and per tile its ``origin`` (core corner),
        ``cells`` (x and y cell ranges) and ``points``.

    Notes
    -----
    Points keep their file and chunk order inside every tile and in the
    sample, so a tile holds its points in the order of the whole cloud.
    """
    import laspy

    from rooftrace.io.las import _backend, check_header_bounds

    index_path = run_dir / "tiles.json"
    if options.resume and index_path.exists():
        return json.loads(index_path.read_text())
    for sub in ("tiles", "sample"):
        if (run_dir / sub).exists():
            shutil.rmtree(run_dir / sub)
    head = _scan_headers(paths)
    bounds = head["bounds"]
    origin = (bounds[0], bounds[1]) if origin is None else (float(origin[0]), float(origin[1]))
    size, buf = options.resolved_tile_size, options.resolved_buffer
    xs, ys = tile_grid(bounds, size)
    rx = tile_cell_ranges(xs, size, buf, origin[0], cell)
    ry = tile_cell_ranges(ys, size, buf, origin[1], cell)
    windows = sample_windows(bounds, head["points"], options.sample_points, origin, cell)
    counts = np.zeros((len(xs), len(ys)), np.int64)
    n_sample = 0
    total = 0
    (run_dir / "sample").mkdir(parents=True, exist_ok=True)
    for f_index, p in enumerate(paths):
        try:
            reader_cm = laspy.open(p, laz_backend=_backend())
        except (laspy.errors.LaspyException, OSError) as exc:
            raise InputError(f"{p}: not a readable LAS/LAZ file ({exc})") from None
        with reader_cm as reader:
            try:
                for c_index, chunk in enumerate(reader.chunk_iterator(options.chunk_size)):
                    rec = _records(chunk, total)
                    total += len(rec)
                    name = f"{f_index:05d}_{c_index:06d}.npy"
                    xyz = np.column_stack([rec["x"], rec["y"], rec["z"]])
                    if not np.isfinite(xyz).all():
                        raise InputError(f"{p}: NaN or infinite coordinates; remove them and retry")
                    check_header_bounds(p, reader.header, xyz)  # the tile grid comes from the header bounds
                    kx, ky = _cells(rec["x"], origin[0], cell), _cells(rec["y"], origin[1], cell)
                    i0, i1 = _members(kx, rx)
                    j0, j1 = _members(ky, ry)
                    # a point lies in up to a few buffered tiles: repeat it once per
                    # tile, then one stable sort groups the chunk by tile, in point order
                    ni, nj = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
                    reps = ni * nj
                    point = np.repeat(np.arange(len(rec)), reps)
                    within = np.arange(len(point)) - np.repeat(np.cumsum(reps) - reps, reps)
                    ti = i0[point] + within // np.maximum(nj[point], 1)
                    tj = j0[point] + within % np.maximum(nj[point], 1)
                    tile_id = ti * len(ys) + tj
                    order = np.argsort(tile_id, kind="stable")
                    tile_id, point = tile_id[order], point[order]
                    uniq, starts = np.unique(tile_id, return_index=True)
                    for t, part in zip(uniq, np.split(point, starts[1:])):
                        i, j = divmod(int(t), len(ys))
                        d = run_dir / "tiles" / f"{i}_{j}"
                        d.mkdir(parents=True, exist_ok=True)
                        np.save(d / name, rec[part])
                        counts[i, j] += len(part)
                    if windows is None:
                        in_sample = np.ones(len(rec), bool)
                    else:
                        in_sample = np.zeros(len(rec), bool)
                        for wx0, wx1, wy0, wy1 in windows:
                            in_sample |= (kx >= wx0) & (kx <= wx1) & (ky >= wy0) & (ky <= wy1)
                    if in_sample.any():
                        np.save(run_dir / "sample" / name, rec[in_sample])
                        n_sample += int(in_sample.sum())
            except InputError:
                raise
            except (laspy.errors.LaspyException, OSError, ValueError, RuntimeError, EOFError) as exc:
                # lazrs reports a cut-off LAZ as a RuntimeError (LazrsError)
                raise InputError(f"{p}: cannot read the point cloud, the file may be truncated or corrupt ({exc}); "
                                 "re-download or re-export it") from None
    if total == 0:
        raise InputError(f"{', '.join(map(str, paths))}: the point cloud is empty")
    index = {
        "tile_size": size, "buffer": buf, "bounds": bounds, "origin": list(origin), "cell": cell,
        "points": total, "sample_points": n_sample,
        "tiles": {f"{i}_{j}": {"origin": [float(xs[i]), float(ys[j])],
                               "cells": [int(rx[i, 0]), int(rx[i, 1]), int(ry[j, 0]), int(ry[j, 1])],
                               "points": int(counts[i, j])}
                  for i in range(len(xs)) for j in range(len(ys)) if counts[i, j] > 0},
    }
    _write_json(index_path, index)
    return index


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def _load_cloud(folder: Path, crs) -> "Any":
    from rooftrace.cloud import PointCloud

    parts = sorted(folder.glob("*.npy")) if folder.exists() else []
    rec = np.concatenate([np.load(p) for p in parts]) if parts else np.empty(0, POINT_DTYPE)
    xyz = np.column_stack([rec["x"], rec["y"], rec["z"]])
    fields = {"return_number": rec["return_number"].copy(), "number_of_returns": rec["number_of_returns"].copy(),
              "gidx": rec["gidx"].copy()}
    return PointCloud(xyz, fields, crs=crs)


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


def process_tile(run_dir: str, key: str, core: Sequence[float], crs_wkt: str | None,
                 config: dict | None, alpha: str | None, planes: bool, seed: int,
                 derived: dict[str, Any], extent: Sequence[float] | None = None, classified: bool = False) -> str:
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
        :func:`rooftrace.tile_points.core_labels`) for the classified LAZ.

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
    cloud = _load_cloud(run / "tiles" / key, crs)
    fixed = DerivedParams.from_dict(derived)
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
        lo, hi = cloud.xyz[:, :2].min(axis=0), cloud.xyz[:, :2].max(axis=0)
        near = owned & (((box[:, 0] - lo[0] < margin) & np.isfinite(core[0]))
                        | ((hi[0] - box[:, 2] < margin) & np.isfinite(core[1]))
                        | ((box[:, 1] - lo[1] < margin) & np.isfinite(core[2]))
                        | ((hi[1] - box[:, 3] < margin) & np.isfinite(core[3])))
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


def _write_classified(paths, out, results, result_paths, n_points, crs, overwrite) -> None:
    from rooftrace.tile_points import merge_labels, write_classified

    # the merge's numbering: buildings sorted by their key (see merge_tiles)
    keys = sorted(tuple(k) for res in results for k in res["buildings"].get("key", []))
    new_id = {k: n + 1 for n, k in enumerate(keys)}
    parts = []
    for r in result_paths:
        with np.load(Path(r).with_suffix(".labels.npz")) as z:
            parts.append({name: z[name] for name in z.files})
    classes, building_id = merge_labels(parts, new_id, n_points)
    write_classified(paths, out, classes, building_id, crs=crs, overwrite=overwrite)


def _save_labels(path: Path, cloud, core: Sequence[float], labelled) -> None:
    from rooftrace.tile_points import core_labels

    if labelled is None:  # too few points to detect anything: unclassified
        n = len(cloud)
        labelled = (np.ones(n, np.uint8), np.zeros(n, np.int32), np.zeros(0, np.int64), np.zeros((0, 3)))
    labels = core_labels(cloud.fields["gidx"], cloud.xyz[:, :2], core, *labelled)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **labels)
    os.replace(tmp, path)


def _core(index: dict, key: str) -> tuple[float, float, float, float]:
    size = index["tile_size"]
    xs, ys = tile_grid(index["bounds"], size)
    i, j = (int(v) for v in key.split("_"))
    x0, y0 = xs[i], ys[j]
    return (-np.inf if i == 0 else float(x0), np.inf if i == len(xs) - 1 else float(x0 + size),
            -np.inf if j == 0 else float(y0), np.inf if j == len(ys) - 1 else float(y0 + size))


def _extent(index: dict, key: str) -> list[float]:
    """The buffered tile (whole cells) clipped to the input's bounds."""
    (ox, oy), cell, b = index["origin"], index["cell"], index["bounds"]
    cx0, cx1, cy0, cy1 = index["tiles"][key]["cells"]
    return [max(ox + cx0 * cell, b[0]), max(oy + cy0 * cell, b[1]),
            min(ox + (cx1 + 1) * cell, b[2]), min(oy + (cy1 + 1) * cell, b[3])]


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

    entries = []  # (key..., tile position, old id)
    for t, res in enumerate(results):
        for old, k in zip(res["buildings"].get("id", []), res["buildings"].get("key", [])):
            entries.append((*k, t, old))
    entries.sort()
    new_id = {(e[3], e[4]): n + 1 for n, e in enumerate(entries)}
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


def _execute(tasks: list[tuple], sizes: list[int], options: TileOptions, reporter) -> list[str]:
    if options.scheduler is None and options.workers <= 1:
        out = []
        for t in tasks:
            out.append(process_tile(*t))
            reporter.advance()
        return out
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if options.scheduler is None:
        # one thread per worker process: the stages hold the GIL in places
        # and the KD-tree queries already use every core of a process
        cluster = LocalCluster(n_workers=options.workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        try:
            client = Client(options.scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"--scheduler {options.scheduler}: cannot connect ({exc})") from None
    try:
        # the biggest tiles first, so that the last task to finish is a short
        # one; the merge does not depend on the order results come back in
        order = sorted(range(len(tasks)), key=lambda i: -sizes[i])
        futures = [client.submit(process_tile, *tasks[i], key=f"rooftrace-tile-{tasks[i][1]}-{os.getpid()}",
                                 pure=False) for i in order]
        for _ in as_completed(futures):
            reporter.advance()
        done = client.gather(futures)
        out = [""] * len(tasks)
        for i, path in zip(order, done):
            out[i] = path
        return out
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_tiled(inputs: Sequence[os.PathLike], output: os.PathLike, options: TileOptions, *, crs=None,
              config: dict | None = None, alpha: str | None = None, planes: bool = True, image=None, camera=None,
              seed: int = 0, overwrite: bool = False, quiet: bool = False,
              classified: os.PathLike | None = None) -> dict[str, Any]:
    """Tile, measure the parameters, process and merge.

    Parameters
    ----------
    inputs : sequence of path-like
        LAS/LAZ files, in any number and layout.
    output : path-like
        GeoPackage to write (atomically).
    options : TileOptions
    crs, config, alpha, planes, seed, overwrite, quiet
        As ``rooftrace run``.
    image, camera
        Refused: image refinement runs untiled.
    classified : path-like, optional
        Also write the input points with the run's classes and building ids
        (LAS/LAZ, every input dimension kept; inputs of one point format).

    Returns
    -------
    dict
        A JSON-serialisable summary: counts, the parameters used, and the
        seconds and throughput of every step.

    Notes
    -----
    The run folder ``OUTPUT.parts`` is kept when the run fails or is
    killed, for ``--resume``; it is removed after a successful merge.
    """
    from rooftrace.cli.app import reporter_for
    from rooftrace.io.atomic import check_output
    from rooftrace.io.checks import check_same_crs, require_metric_crs
    from rooftrace.io.points import parse_crs
    from rooftrace.io.vector import Layer, write_layers
    from rooftrace.lidar.detect import DerivedParams, DetectOptions
    from rooftrace.pipeline import check_config

    if image is not None or camera is not None:
        raise InputError("image refinement runs per building on one image; run it without tiling "
                         "(or use 'rooftrace refine' on the tiled result)")
    output = check_output(output, overwrite)
    cfg = {k: v for k, v in (config or {}).items() if k != "__path__"} or None
    check_config(cfg)
    try:
        outlier_opts = DetectOptions.from_config(cfg).outliers
    except (TypeError, ValueError) as exc:
        raise InputError(f"config: {exc}") from None
    paths = [Path(p) for p in inputs]
    if not paths:
        raise InputError("no input files given")
    head = _scan_headers(paths)
    if classified is not None:
        from rooftrace.tile_points import check_point_formats

        classified = check_output(classified, overwrite)
        check_point_formats(paths)
    file_crss = head["crs"]
    user_crs = parse_crs(crs) if isinstance(crs, str) else crs
    crs_obj = user_crs or file_crss[0]
    if user_crs is None:
        for p, c in zip(paths[1:], file_crss[1:]):
            if (c is None) != (crs_obj is None):
                raise InputError(f"{p}: CRS differs from {paths[0]}; assign one with --crs")
            check_same_crs(crs_obj, c, str(paths[0]), str(p))
    b = head["bounds"]  # without a CRS, header bounds within a fraction of a unit of (lon, lat) are degrees
    require_metric_crs(crs_obj, str(paths[0]), np.array([[b[0], b[1]], [b[2], b[3]]]))
    run_dir = Path(str(output) + ".parts")
    if run_dir.exists() and not options.resume:
        shutil.rmtree(run_dir)
    run_dir.mkdir(exist_ok=True)
    meta = {"inputs": [str(p.resolve()) for p in paths],
            "options": {k: v for k, v in asdict(options).items() if k not in ("resume", "workers", "scheduler")},
            "crs": crs_obj.to_wkt() if crs_obj is not None else None,
            "alpha": alpha, "planes": planes, "seed": seed, "config": cfg, "classified": classified is not None}
    meta = json.loads(json.dumps(meta))
    meta_path = run_dir / "run.json"
    if options.resume and meta_path.exists() and json.loads(meta_path.read_text()) != meta:
        raise InputError(f"{run_dir}: --resume with different inputs or options; rerun without --resume")
    _write_json(meta_path, meta)

    timings: dict[str, float] = {}
    reporter = reporter_for(quiet)
    try:
        t0 = time.perf_counter()
        with reporter.stage("split into tiles"):
            index = split_to_tiles(paths, run_dir, options, cell=outlier_opts.cell)
        timings["split"] = time.perf_counter() - t0
        derived_path = run_dir / "derived.json"
        t0 = time.perf_counter()
        if options.resume and derived_path.exists():
            derived = DerivedParams.from_dict(json.loads(derived_path.read_text()))
        else:
            with reporter.stage("parameters"):
                sample = _load_cloud(run_dir / "sample", crs_obj)
                sample.sources = [str(p) for p in paths]
                derived = estimate_parameters(sample, cfg, origin=index["origin"], extent=index["bounds"])
                del sample
            _write_json(derived_path, derived.to_dict())
        timings["parameters"] = time.perf_counter() - t0
        log.info("parameters of the whole run: s_avg %.3f m, d_avg %.2f pts/m², sigma_H %.3f m, entropy threshold %.3f",
                 derived.mean_spacing, derived.density, derived.sigma_h, derived.entropy_threshold)
        keys = sorted(index["tiles"], key=lambda k: tuple(int(v) for v in k.split("_")))
        wkt = crs_obj.to_wkt() if crs_obj is not None else None
        tasks = [(str(run_dir), k, _core(index, k), wkt, cfg, alpha, planes, seed, derived.to_dict(), _extent(index, k),
                  classified is not None) for k in keys]
        t0 = time.perf_counter()
        with reporter.stage("tiles", total=len(tasks)):
            result_paths = _execute(tasks, [index["tiles"][k]["points"] for k in keys], options, reporter)
        timings["tiles"] = time.perf_counter() - t0
    finally:
        reporter.close()
    t0 = time.perf_counter()
    results = [pickle.loads(Path(r).read_bytes()) for r in result_paths]
    layers = merge_tiles(results)
    for name, gtype in (("roof_outlines", "PolygonZ"), ("ridges", "LineStringZ"), ("roof_faces", "PolygonZ")):
        layers.setdefault(name, Layer([], {"building_id": []}, gtype))
    write_layers(output, layers, crs_obj, overwrite=overwrite)
    timings["merge"] = time.perf_counter() - t0
    if classified is not None:
        t0 = time.perf_counter()
        _write_classified(paths, classified, results, result_paths, index["points"], crs_obj, overwrite)
        timings["classified"] = time.perf_counter() - t0
    stages: dict[str, float] = {}
    for res in results:
        for k, v in res["timings"].items():
            stages[k] = stages.get(k, 0.0) + v
    shutil.rmtree(run_dir, ignore_errors=True)
    return {
        "output": str(output), "points": index["points"], "tiles": len(keys),
        "buildings": len(layers["roof_outlines"]), "ridges": len(layers["ridges"]),
        "roof_faces": len(layers["roof_faces"]), "tile_size": index["tile_size"], "buffer": index["buffer"],
        "tile_points": int(sum(r["points"] for r in results)),
        "edge_buildings": int(sum(len(r["edge_buildings"]) for r in results)),
        "parameters": derived.to_dict(), "sample_points": index["sample_points"],
        "timings": {k: round(v, 3) for k, v in timings.items()},
        "stage_seconds": {k: round(v, 3) for k, v in stages.items()},
    }
