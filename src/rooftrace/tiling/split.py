"""Splitting the inputs into buffered tiles: the grid, the sample windows, one streaming pass over the files."""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rooftrace.errors import InputError, OptionError

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
        Side of the square tile cores, metres.  ``None``: derived from the
        inputs' density (:func:`derived_tile_size`).
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
                raise OptionError(f"{{{name}}} must be a number > 0 (metres), got {v}", name)
        if self.workers < 1:
            raise OptionError(f"{{workers}} must be >= 1, got {self.workers}", "workers")
        if self.chunk_size < 1 or self.sample_points < 1000:
            raise InputError(f"tiling: chunk_size must be >= 1 and sample_points >= 1000, got "
                             f"{self.chunk_size}, {self.sample_points}")

    def resolved_tile_size(self, counts: Sequence[int] = (), boxes: Sequence[Sequence[float]] = ()) -> float:
        """``tile_size``, or the one :func:`derived_tile_size` gives for these headers."""
        if self.tile_size is not None:
            return float(self.tile_size)
        return derived_tile_size(counts, boxes, self.resolved_buffer)

    @property
    def resolved_buffer(self) -> float:
        return 60.0 if self.buffer is None else float(self.buffer)


#: points a buffered tile holds, about, when the tile size is derived from the data: a tile's
#: run then peaks near 3 GB (tiling/memory.py), and the buffers add 1.5-2x the work, not 2.6x
#: as 200 m tiles with 60 m buffers do
TARGET_TILE_POINTS = 3_000_000


def derived_tile_size(counts: Sequence[int], boxes: Sequence[Sequence[float]], buffer: float) -> float:
    """Tile side (m) whose buffered tile holds about :data:`TARGET_TILE_POINTS` at the inputs' density.

    The density is the densest file's (header point count over its header
    box), so that a file whose box is partly empty errs towards smaller
    tiles.  The side is rounded down to 50 m and kept within 100-1000 m.
    It depends on the headers only, so a run is the same whatever the
    machine or the number of workers.

    Parameters
    ----------
    counts : sequence of int
        Points of each input file.
    boxes : sequence of (xmin, ymin, zmin, xmax, ymax, zmax)
        Header boxes (m).
    buffer : float
        Buffer around each tile core (m).

    Examples
    --------
    >>> derived_tile_size([13_500_000], [(0, 0, 0, 1000, 1000, 50)], 60.0)  # 13.5 pts/m²
    350.0
    >>> derived_tile_size([], [], 60.0)
    200.0
    """
    densities = [c / max((b[3] - b[0]) * (b[4] - b[1]), 1.0) for c, b in zip(counts, boxes) if c > 0]
    if not densities:
        return 200.0
    side = np.sqrt(TARGET_TILE_POINTS / max(densities)) - 2.0 * buffer
    return float(np.clip(np.floor(side / 50.0) * 50.0, 100.0, 1000.0))


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


def scan_headers(paths: Sequence[Path]) -> dict[str, Any]:
    """Point counts, CRSs and the joint bounds of LAS/LAZ files from their headers (no point is read)."""
    import laspy

    from rooftrace.io.las import check_point_count, las_crs

    bounds, boxes, crss, counts = [], [], [], []
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
                boxes.append([float(v) for v in (*h.mins[:3], *h.maxs[:3])])
                crss.append(las_crs(h, str(p)))
                counts.append(int(h.point_count))
        except laspy.errors.LaspyException as exc:
            raise InputError(f"{p}: not a readable LAS/LAZ file ({exc})") from None
    b = np.asarray(bounds, float)
    return {"bounds": [float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())],
            "crs": crss, "points": int(sum(counts)), "boxes": boxes, "counts": counts}


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

    from rooftrace.io.las import check_header_bounds, laz_backend

    index_path = run_dir / "tiles.json"
    if options.resume and index_path.exists():
        return json.loads(index_path.read_text())
    for sub in ("tiles", "sample"):
        if (run_dir / sub).exists():
            shutil.rmtree(run_dir / sub)
    head = scan_headers(paths)
    bounds = head["bounds"]
    origin = (bounds[0], bounds[1]) if origin is None else (float(origin[0]), float(origin[1]))
    size, buf = options.resolved_tile_size(head["counts"], head["boxes"]), options.resolved_buffer
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
            reader_cm = laspy.open(p, laz_backend=laz_backend())
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
    write_json(index_path, index)
    return index


def write_json(path: Path, data: Any) -> None:
    """Write a run folder's JSON file through a temporary file, so a killed run never leaves half of one."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def load_tile_points(folder: Path, crs) -> Any:
    """The points stored in a tile's folder (``*.npy`` records) as a PointCloud with their ``gidx`` and returns."""
    from rooftrace.cloud import PointCloud

    parts = sorted(folder.glob("*.npy")) if folder.exists() else []
    rec = np.concatenate([np.load(p) for p in parts]) if parts else np.empty(0, POINT_DTYPE)
    xyz = np.column_stack([rec["x"], rec["y"], rec["z"]])
    fields = {"return_number": rec["return_number"].copy(), "number_of_returns": rec["number_of_returns"].copy(),
              "gidx": rec["gidx"].copy()}
    return PointCloud(xyz, fields, crs=crs)


def near_open_side(boxes: np.ndarray, extent: Sequence[float], bounds: Sequence[float],
                   margin: float = 0.0) -> np.ndarray:
    """Which boxes come within ``margin`` of a side of the tile past which the data goes on.

    Parameters
    ----------
    boxes : ndarray of shape (B, 4)
        xmin, ymin, xmax, ymax of each box (m).
    extent : (xmin, ymin, xmax, ymax)
        The buffered tile clipped to the inputs' bounds (m).
    bounds : (xmin, ymin, xmax, ymax)
        The inputs' bounds (m): a side of ``extent`` on them has no data beyond it.
    margin : float
        Metres.

    Returns
    -------
    ndarray of shape (B,), bool

    Examples
    --------
    >>> near_open_side(np.array([[1.0, 5, 3, 6], [97, 5, 99, 6]]), [0, 0, 100, 10], [0, 0, 200, 10], 2.0).tolist()
    [False, True]
    """
    b = np.asarray(boxes, float).reshape(-1, 4)
    e, lim = extent, bounds
    return (((b[:, 0] - e[0] < margin) & (e[0] > lim[0])) | ((b[:, 1] - e[1] < margin) & (e[1] > lim[1]))
            | ((e[2] - b[:, 2] < margin) & (e[2] < lim[2])) | ((e[3] - b[:, 3] < margin) & (e[3] < lim[3])))
