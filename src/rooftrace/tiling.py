"""City-scale runs: square tiles with buffers, a local pool or Dask, resumable.

Why not just ``dask.dataframe``?  The unit of work is a *tile with its
buffer*, and the rule that keeps seams clean is about buildings, not points:
every tile is processed with a buffer wide enough for the ground filter and
the largest building, and a building belongs to the tile whose core holds
its outline's centroid.  So nothing is duplicated and nothing is cut.

Flow (each step restartable):

1. ``split``: stream every input file once, in chunks, and append each
   point to the buffered tiles it falls in (``RUN/tiles/<i>_<j>/*.npy``).
   Peak memory is one chunk plus one tile, not the input.
2. ``process``: run :func:`rooftrace.pipeline.run_pipeline` per tile, keep
   the buildings whose centroid lies in the tile core and store them as
   ``RUN/results/<i>_<j>.pkl``.  Tiles run in a process pool (Dask
   LocalCluster) or on a Dask cluster (``--scheduler``).
3. ``merge``: concatenate the tile results in tile order, renumber the
   buildings and write the GeoPackage atomically.

Results do not depend on the number of workers: tiles are independent and
merged in a fixed order.  ``--resume`` skips split chunks and tiles already
finished.
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from rooftrace.errors import InputError

__all__ = ["TileOptions", "tile_grid", "split_to_tiles", "process_tile", "merge_tiles", "run_tiled"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TileOptions:
    """Tiling and execution options.

    Attributes
    ----------
    tile_size : float or None
        Side of the square tile cores, metres.  ``None``: 250 m.
    buffer : float or None
        Buffer around each core, metres.  ``None``: 60 m, wider than the
        ground filter's seed cell (50 m) and the largest buildings of a
        historic centre.
    workers : int
        Worker processes of the local Dask cluster; 1 runs in-process.
    scheduler : str or None
        Address of an existing Dask scheduler (``tcp://host:8786``).
    resume : bool
        Keep finished split chunks and tile results of an earlier run.
    chunk_size : int
        Points decoded at once while splitting.
    """

    section = "tiling"

    tile_size: float | None = None
    buffer: float | None = None
    workers: int = 1
    scheduler: str | None = None
    resume: bool = False
    chunk_size: int = 1_000_000

    @property
    def resolved_tile_size(self) -> float:
        return 250.0 if self.tile_size is None else float(self.tile_size)

    @property
    def resolved_buffer(self) -> float:
        return 60.0 if self.buffer is None else float(self.buffer)


def tile_grid(bounds: Sequence[float], tile_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Tile core origins covering ``bounds`` (xmin, ymin, xmax, ymax); the grid is anchored at
    multiples of ``tile_size`` so that the same data always gives the same tiles."""
    xmin, ymin, xmax, ymax = bounds
    x0 = np.floor(xmin / tile_size) * tile_size
    y0 = np.floor(ymin / tile_size) * tile_size
    nx = max(1, int(np.ceil((xmax - x0) / tile_size + 1e-12)))
    ny = max(1, int(np.ceil((ymax - y0) / tile_size + 1e-12)))
    return x0 + tile_size * np.arange(nx), y0 + tile_size * np.arange(ny)


def _scan_headers(paths: Sequence[Path]) -> tuple[np.ndarray, list]:
    import laspy

    from rooftrace.io.las import las_crs

    bounds = []
    crss = []
    for p in paths:
        if not p.is_file():
            raise InputError(f"{p}: no such file")
        if p.suffix.lower() not in (".las", ".laz"):
            raise InputError(f"{p}: tiled runs read LAS/LAZ only")
        try:
            with laspy.open(p) as r:
                h = r.header
                bounds.append([*h.mins[:2], *h.maxs[:2]])
                crss.append(las_crs(h, str(p)))
        except laspy.errors.LaspyException as exc:
            raise InputError(f"{p}: not a readable LAS/LAZ file ({exc})") from None
    b = np.asarray(bounds, float)
    return np.array([b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()]), crss


def split_to_tiles(paths: Sequence[Path], run_dir: Path, options: TileOptions) -> dict[str, Any]:
    """Stream the inputs once into buffered tiles under ``run_dir/tiles``; returns the tile index."""
    import laspy

    index_path = run_dir / "tiles.json"
    if options.resume and index_path.exists():
        return json.loads(index_path.read_text())
    if (run_dir / "tiles").exists():
        shutil.rmtree(run_dir / "tiles")
    bounds, _ = _scan_headers(paths)
    size, buf = options.resolved_tile_size, options.resolved_buffer
    xs, ys = tile_grid(bounds, size)
    tiles = {f"{i}_{j}": [float(x), float(y)] for i, x in enumerate(xs) for j, y in enumerate(ys)}
    counts = {k: 0 for k in tiles}
    for f_index, p in enumerate(paths):
        with laspy.open(p) as reader:
            for c_index, chunk in enumerate(reader.chunk_iterator(options.chunk_size)):
                xyz = np.column_stack([chunk.x, chunk.y, chunk.z]).astype(np.float64)
                if not np.isfinite(xyz).all():
                    raise InputError(f"{p}: NaN or infinite coordinates; remove them and retry")
                # a point belongs to every tile whose buffered square holds it: index ranges, no loop over points
                i_lo = np.floor((xyz[:, 0] - buf - xs[0]) / size).astype(int).clip(0, len(xs) - 1)
                i_hi = np.floor((xyz[:, 0] + buf - xs[0]) / size).astype(int).clip(0, len(xs) - 1)
                j_lo = np.floor((xyz[:, 1] - buf - ys[0]) / size).astype(int).clip(0, len(ys) - 1)
                j_hi = np.floor((xyz[:, 1] + buf - ys[0]) / size).astype(int).clip(0, len(ys) - 1)
                for i in range(int(i_lo.min()), int(i_hi.max()) + 1):
                    for j in range(int(j_lo.min()), int(j_hi.max()) + 1):
                        sel = (i_lo <= i) & (i <= i_hi) & (j_lo <= j) & (j <= j_hi)
                        if not sel.any():
                            continue
                        d = run_dir / "tiles" / f"{i}_{j}"
                        d.mkdir(parents=True, exist_ok=True)
                        np.save(d / f"{f_index:05d}_{c_index:06d}.npy", xyz[sel])
                        counts[f"{i}_{j}"] += int(sel.sum())
    index = {"tile_size": size, "buffer": buf, "bounds": bounds.tolist(),
             "tiles": {k: {"origin": v, "points": counts[k]} for k, v in tiles.items() if counts[k] > 0}}
    tmp = index_path.with_suffix(".tmp")
    tmp.write_text(json.dumps(index, indent=1))
    os.replace(tmp, index_path)
    return index


def process_tile(run_dir: str, key: str, core: Sequence[float], crs_wkt: str | None,
                 config: dict | None, alpha: str | None, planes: bool, seed: int) -> str:
    """Run the pipeline on one buffered tile and keep the buildings whose centroid is in its core.

    ``core`` is (xmin, xmax, ymin, ymax), half-open; edge tiles reach to
    infinity so that a building beyond the header bounds still has an owner.
    Runs in a worker process; reads and writes only inside ``run_dir``.
    """
    import pyproj
    import shapely

    from rooftrace.cloud import PointCloud
    from rooftrace.pipeline import run_pipeline

    run = Path(run_dir)
    out = run / "results" / f"{key}.pkl"
    if out.exists():
        return str(out)
    parts = sorted((run / "tiles" / key).glob("*.npy"))
    xyz = np.concatenate([np.load(p) for p in parts]) if parts else np.empty((0, 3))
    crs = pyproj.CRS.from_wkt(crs_wkt) if crs_wkt else None
    layers: dict[str, Any] = {}
    if len(xyz) >= 3:
        result = run_pipeline(PointCloud(xyz, crs=crs), config=config, alpha=alpha, planes=planes, seed=seed)
        outlines = result.layers["roof_outlines"]
        ids = np.asarray(outlines.attributes.get("building_id", []), dtype=np.int64)
        cent = shapely.get_coordinates(shapely.centroid(np.asarray(outlines.geometries, dtype=object))) if len(ids) else np.empty((0, 2))
        x0, x1, y0, y1 = core
        keep_ids = set(ids[(cent[:, 0] >= x0) & (cent[:, 0] < x1) & (cent[:, 1] >= y0) & (cent[:, 1] < y1)].tolist())
        for name, layer in result.layers.items():
            bid = np.asarray(layer.attributes.get("building_id", []), dtype=np.int64)
            keep = np.array([b in keep_ids for b in bid], bool) if len(bid) else np.zeros(0, bool)
            layers[name] = {
                "wkb": [shapely.to_wkb(g, output_dimension=3) for g, k in zip(layer.geometries, keep) if k],
                "attributes": {a: [v for v, k in zip(col, keep) if k] for a, col in layer.attributes.items()},
                "geometry_type": layer.geometry_type,
            }
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(layers))
    os.replace(tmp, out)
    return str(out)


def _core(index: dict, key: str) -> tuple[float, float, float, float]:
    size = index["tile_size"]
    xs, ys = tile_grid(index["bounds"], size)
    i, j = (int(v) for v in key.split("_"))
    x0, y0 = xs[i], ys[j]
    return (-np.inf if i == 0 else x0, np.inf if i == len(xs) - 1 else x0 + size,
            -np.inf if j == 0 else y0, np.inf if j == len(ys) - 1 else y0 + size)


def merge_tiles(result_paths: Sequence[Path]) -> dict:
    """Join tile results in the given order; buildings renumbered 1..B in that order."""
    import shapely

    from rooftrace.io.vector import Layer

    merged: dict[str, dict] = {}
    next_id = 1
    for path in result_paths:
        layers = pickle.loads(Path(path).read_bytes())
        outl = layers.get("roof_outlines")
        if not outl:
            continue
        renumber = {old: next_id + k for k, old in enumerate(outl["attributes"].get("building_id", []))}
        next_id += len(renumber)
        for name, layer in layers.items():
            m = merged.setdefault(name, {"geoms": [], "attributes": {}, "geometry_type": layer["geometry_type"]})
            n_before = len(m["geoms"])
            m["geoms"].extend(shapely.from_wkb(w) for w in layer["wkb"])
            n_new = len(layer["wkb"])
            for a, col in layer["attributes"].items():
                if a == "building_id":
                    col = [renumber[v] for v in col]
                m["attributes"].setdefault(a, [None] * n_before).extend(col)
            for a in m["attributes"]:
                if len(m["attributes"][a]) < n_before + n_new:
                    m["attributes"][a].extend([None] * (n_before + n_new - len(m["attributes"][a])))
    return {name: Layer(m["geoms"], m["attributes"], m["geometry_type"]) for name, m in merged.items()}


def _execute(tasks: list[tuple], options: TileOptions, reporter) -> list[str]:
    if options.scheduler is None and options.workers <= 1:
        out = []
        for t in tasks:
            out.append(process_tile(*t))
            reporter.advance()
        return out
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if options.scheduler is None:
        cluster = LocalCluster(n_workers=options.workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        try:
            client = Client(options.scheduler, timeout="20s")
        except OSError as exc:
            raise InputError(f"--scheduler {options.scheduler}: cannot connect ({exc})") from None
    try:
        futures = [client.submit(process_tile, *t, key=f"rooftrace-tile-{t[1]}", pure=False) for t in tasks]
        for _ in as_completed(futures):
            reporter.advance()
        return client.gather(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_tiled(inputs: Sequence[os.PathLike], output: os.PathLike, options: TileOptions, *, crs=None,
              config: dict | None = None, alpha: str | None = None, planes: bool = True, image=None, camera=None,
              seed: int = 0, overwrite: bool = False, quiet: bool = False) -> dict[str, Any]:
    """Tile, process and merge; the run folder ``OUTPUT.parts`` is kept on failure for ``--resume``."""
    from rooftrace.cli.app import reporter_for
    from rooftrace.io.atomic import check_output
    from rooftrace.io.checks import check_same_crs, require_metric_crs
    from rooftrace.io.points import parse_crs
    from rooftrace.io.vector import write_layers

    if image is not None or camera is not None:
        raise InputError("image refinement runs per building on one image; run it without tiling "
                         "(or use 'rooftrace refine' on the tiled result)")
    output = check_output(output, overwrite)
    paths = [Path(p) for p in inputs]
    _, file_crss = _scan_headers(paths)
    user_crs = parse_crs(crs) if isinstance(crs, str) else crs
    crs_obj = user_crs or file_crss[0]
    if user_crs is None:
        for p, c in zip(paths[1:], file_crss[1:]):
            if (c is None) != (crs_obj is None):
                raise InputError(f"{p}: CRS differs from {paths[0]}; assign one with --crs")
            check_same_crs(crs_obj, c, str(paths[0]), str(p))
    require_metric_crs(crs_obj, str(paths[0]))
    run_dir = Path(str(output) + ".parts")
    if run_dir.exists() and not options.resume:
        shutil.rmtree(run_dir)
    run_dir.mkdir(exist_ok=True)
    meta = {"inputs": [str(p) for p in paths], "options": {k: v for k, v in asdict(options).items() if k != "resume"},
            "alpha": alpha, "planes": planes, "seed": seed, "config": {k: v for k, v in (config or {}).items() if k != "__path__"}}
    meta_path = run_dir / "run.json"
    if options.resume and meta_path.exists() and json.loads(meta_path.read_text()) != json.loads(json.dumps(meta)):
        raise InputError(f"{run_dir}: --resume with different inputs or options; rerun without --resume")
    meta_path.write_text(json.dumps(meta, indent=1))

    reporter = reporter_for(quiet)
    try:
        with reporter.stage("split into tiles"):
            index = split_to_tiles(paths, run_dir, options)
        keys = sorted(index["tiles"], key=lambda k: tuple(int(v) for v in k.split("_")))
        wkt = crs_obj.to_wkt() if crs_obj is not None else None
        tasks = [(str(run_dir), k, _core(index, k), wkt, meta["config"] or None, alpha, planes, seed) for k in keys]
        with reporter.stage("tiles", total=len(tasks)):
            results = _execute(tasks, options, reporter)
    finally:
        reporter.close()
    layers = merge_tiles([Path(r) for r in results])
    from rooftrace.io.vector import Layer

    for name, gtype in (("roof_outlines", "PolygonZ"), ("ridges", "LineStringZ"), ("roof_faces", "PolygonZ")):
        layers.setdefault(name, Layer([], {"building_id": []}, gtype))
    write_layers(output, layers, crs_obj, overwrite=overwrite)
    shutil.rmtree(run_dir, ignore_errors=True)
    return {"output": str(output), "tiles": len(keys), "buildings": len(layers["roof_outlines"]),
            "ridges": len(layers["ridges"]), "roof_faces": len(layers["roof_faces"]),
            "tile_size": index["tile_size"], "buffer": index["buffer"]}
