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
   GeoPackage atomically.  With an image, the parent first refines all the
   merged buildings in one pass, as the untiled run does; the image is
   checked before step 1 and never goes to the tiles
   (:mod:`rooftrace.tiling.image`).

Results do not depend on the number of workers: tiles are independent and
merged in a fixed order.  ``--resume`` keeps the split, the parameters and
every finished tile of an earlier run of the same inputs and options
(the image and camera included).
"""


from __future__ import annotations

import ctypes
import json
import logging
import os
import pickle
import shutil
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from rooftrace.errors import InputError
from rooftrace.progress import Reporter
from rooftrace.tiling.image import (
    check_image_inputs,
    cut_neighbourhoods,
    image_fingerprint,
    join_neighbourhoods,
    merged_planes,
)
from rooftrace.tiling.split import (  # noqa: F401
    POINT_DTYPE,
    TileOptions,
    load_tile_points,
    sample_windows,
    scan_headers,
    split_to_tiles,
    tile_cell_ranges,
    tile_grid,
    write_json,
)
from rooftrace.tiling.tile import (
    TileTask,
    building_numbers,
    estimate_parameters,
    merge_tiles,
    merged_models,
    owned_buildings,
    process_tile,
    tile_core,
    tile_extent,
    write_classified_points,
)

__all__ = [
    "TileOptions", "tile_grid", "tile_cell_ranges", "sample_windows", "split_to_tiles", "estimate_parameters",
    "owned_buildings", "TileTask", "process_tile", "merge_tiles", "merged_models", "run_tiled",
]

log = logging.getLogger(__name__)


def _process_and_release(task: TileTask) -> str:
    """:func:`process_tile`, then give the heap pages it freed back to the OS.

    Without Dask's MALLOC_TRIM_THRESHOLD_ (see :func:`_execute`) glibc keeps
    a worker's freed heap after a tile, so two workers would sit at their
    largest tile's size together: the 11 M-point block peaked at 3.96 GiB.
    ``malloc_trim`` once per tile costs nothing next to a tile.
    """
    out = task.run()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass
    return out


def _execute(tasks: list[TileTask], sizes: list[int], options: TileOptions, reporter: Reporter) -> list[str]:
    if options.scheduler is None and options.workers <= 1:
        out = []
        for t in tasks:
            out.append(_process_and_release(t))
            reporter.advance()
        return out
    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if options.scheduler is None:
        # Dask starts its workers with MALLOC_TRIM_THRESHOLD_ set; setting it
        # at all switches off glibc's adaptive mmap threshold, so every numpy
        # temporary above 128 KiB is mapped and unmapped again: on a 1.2 M-point
        # scene in 4 tiles that was 2.8 M page faults and 10.6 s of system time
        # against 0.28 M and 3.7 s without it (total CPU 52 -> 41 s)
        environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
                   if k != "MALLOC_TRIM_THRESHOLD_"}
        # one thread per worker process: the stages hold the GIL in places
        # and the KD-tree queries already use every core of a process
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
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
        futures = [client.submit(_process_and_release, tasks[i], key=f"rooftrace-tile-{tasks[i].key}-{os.getpid()}",
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


def _refine_merged(layers: dict, results: list[dict], image: Path, camera: Path, cam, cfg: dict | None, seed: int,
                   reporter: Reporter):
    """Refine the merged buildings with the image, once (see :mod:`rooftrace.tiling.image`)."""
    from rooftrace.io.checks import check_image_size
    from rooftrace.io.raster import read_image
    from rooftrace.pipeline import refine_layers

    grey = read_image(image)
    check_image_size(grey.shape[::-1], cam, str(image), str(camera))  # the file may have changed since the check
    points = join_neighbourhoods(results)
    planes = merged_planes(results, building_numbers(results))
    with reporter.stage("image refinement", total=None):
        return refine_layers(layers, planes, points, grey, cam, config=cfg, seed=seed)


def run_tiled(inputs: Sequence[os.PathLike], output: os.PathLike, options: TileOptions, *, crs=None,
              config: dict | None = None, alpha: str | None = None, planes: bool = True, image=None, camera=None,
              seed: int = 0, overwrite: bool = False, reporter: Reporter | None = None,
              classified: os.PathLike | None = None, model_outputs: Sequence[os.PathLike] = ()) -> dict[str, Any]:
    """Tile, measure the parameters, process and merge.

    Parameters
    ----------
    inputs : sequence of path-like
        LAS/LAZ files, in any number and layout.
    output : path-like or None
        GeoPackage to write (atomically); None for model files only.
    options : TileOptions
    crs, config, alpha, planes, seed, overwrite
        As ``rooftrace run``.
    reporter : Reporter, optional
        Progress callbacks (silent by default).
    image, camera : path-like, optional
        Aerial image and its ``camera.json`` (None for a georeferenced
        orthophoto, whose GeoTIFF is its camera): the merged buildings are
        refined with it in one pass, as an untiled run refines them
        (:mod:`rooftrace.tiling.image`).  Checked before any tile work.
    classified : path-like, optional
        Also write the input points with the run's classes and building ids
        (LAS/LAZ, every input dimension kept; inputs of one point format).
    model_outputs : sequence of path-like
        CityJSONSeq, CityJSON or OBJ files of the 3D models
        (:func:`rooftrace.io.models.write_models`); each tile builds the
        models of the buildings it owns and the merge writes them in
        building-id order, so the files equal those of an untiled run.

    Returns
    -------
    dict
        A JSON-serialisable summary: counts, the parameters used, whether
        the image refinement ran (``refined``, and the camera's
        ``orientation`` correction when there was one), and the seconds and
        throughput of every step.

    Notes
    -----
    The run folder ``OUTPUT.parts`` (of the first output) is kept when the run fails or is
    killed, for ``--resume``; it is removed after a successful merge.
    """
    from rooftrace.config import validate_config
    from rooftrace.io.atomic import check_output, commit_together
    from rooftrace.io.checks import check_camera_has_image, check_same_crs, require_metric_crs
    from rooftrace.io.models import write_models
    from rooftrace.io.points import parse_crs
    from rooftrace.io.vector import write_layers
    from rooftrace.lidar.detect import DerivedParams, DetectOptions
    from rooftrace.pipeline import building_layers
    from rooftrace.refine import RefineOptions

    check_camera_has_image(image, camera)
    model_outputs = [check_output(p, overwrite) for p in model_outputs]
    if output is None and not model_outputs:
        raise InputError("no output given")
    output = check_output(output, overwrite) if output is not None else None
    if config:
        validate_config(config)
    cfg = {k: v for k, v in (config or {}).items() if k != "__path__"} or None
    try:
        outlier_opts = DetectOptions.from_config(cfg).outliers
        refine_context = RefineOptions.from_config(cfg).context if image is not None else None
    except (TypeError, ValueError) as exc:
        raise InputError(f"config: {exc}") from None
    paths = [Path(p) for p in inputs]
    if not paths:
        raise InputError("no input files given")
    head = scan_headers(paths)
    if classified is not None:
        from rooftrace.io.las import check_point_formats

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
    cam = None
    if image is not None:
        # the untiled run's checks, on the headers, before minutes of tile work
        cam = check_image_inputs(Path(image), None if camera is None else Path(camera), crs_obj, head,
                                 ", ".join(map(str, paths)))
    run_dir = Path(str(output if output is not None else model_outputs[0]) + ".parts")
    if run_dir.exists() and not options.resume:
        shutil.rmtree(run_dir)
    run_dir.mkdir(exist_ok=True)
    meta = {"inputs": [str(p.resolve()) for p in paths],
            "options": {k: v for k, v in asdict(options).items() if k not in ("resume", "workers", "scheduler")},
            "crs": crs_obj.to_wkt() if crs_obj is not None else None,
            "alpha": alpha, "planes": planes, "seed": seed, "config": cfg, "classified": classified is not None,
            # the tiles do not use the image, but a resumed run must give what a fresh one gives
            **({"image": image_fingerprint(Path(image), None if camera is None else Path(camera))}
               if image is not None else {})}
    meta = json.loads(json.dumps(meta))
    meta_path = run_dir / "run.json"
    if options.resume and meta_path.exists() and json.loads(meta_path.read_text()) != meta:
        raise InputError(f"{run_dir}: --resume with different inputs or options; rerun without --resume")
    write_json(meta_path, meta)

    timings: dict[str, float] = {}
    reporter = reporter or Reporter()
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
            sample = load_tile_points(run_dir / "sample", crs_obj)
            sample.sources = [str(p) for p in paths]
            derived = estimate_parameters(sample, cfg, origin=index["origin"], extent=index["bounds"])
            del sample
        write_json(derived_path, derived.to_dict())
    timings["parameters"] = time.perf_counter() - t0
    log.info("parameters of the whole run: s_avg %.3f m, d_avg %.2f pts/m², sigma_H %.3f m, entropy threshold %.3f",
             derived.mean_spacing, derived.density, derived.sigma_h, derived.entropy_threshold)
    keys = sorted(index["tiles"], key=lambda k: tuple(int(v) for v in k.split("_")))
    wkt = crs_obj.to_wkt() if crs_obj is not None else None
    tasks = [TileTask(str(run_dir), k, tuple(tile_core(index, k)), wkt, cfg, alpha, planes, seed, derived.to_dict(),
                      tuple(tile_extent(index, k)), classified is not None, refine_context) for k in keys]
    t0 = time.perf_counter()
    with reporter.stage("tiles", total=len(tasks)):
        result_paths = _execute(tasks, [index["tiles"][k]["points"] for k in keys], options, reporter)
    timings["tiles"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    results = [pickle.loads(Path(r).read_bytes()) for r in result_paths]
    layers = merge_tiles(results)
    empty = building_layers([], [], models=[])
    for name, layer in empty.items():
        layers.setdefault(name, layer)
    layers = {name: layers[name] for name in empty}  # the untiled run's layer order
    merge_seconds = time.perf_counter() - t0
    refined = None
    if cam is not None and len(layers["roof_outlines"]):
        for k, res in zip(keys, results):
            for x, y, r in np.asarray(res.get("refine_discs", []), float).reshape(-1, 3)[
                    cut_neighbourhoods(res.get("refine_discs", []), tile_extent(index, k), index["bounds"])]:
                log.warning("tile %s: the image refinement uses the points within %.1f m of the building at "
                            "(%.1f, %.1f), beyond the tile's buffer; rerun with a larger --buffer", k, r, x, y)
        t0 = time.perf_counter()
        refined, layers = _refine_merged(layers, results, Path(image), Path(camera or image), cam, cfg, seed, reporter)
        timings["refine"] = time.perf_counter() - t0
    with commit_together():  # every output new, or all as they were
        t0 = time.perf_counter()
        if model_outputs:
            write_models(model_outputs, merged_models(results), crs_obj, overwrite=overwrite)
        if output is not None:
            write_layers(output, layers, crs_obj, overwrite=overwrite)
        timings["merge"] = merge_seconds + time.perf_counter() - t0
        if classified is not None:
            t0 = time.perf_counter()
            write_classified_points(paths, classified, results, result_paths, index["points"], crs_obj, overwrite)
            timings["classified"] = time.perf_counter() - t0
    stages: dict[str, float] = {}
    for res in results:
        for k, v in res["timings"].items():
            stages[k] = stages.get(k, 0.0) + v
    shutil.rmtree(run_dir, ignore_errors=True)
    return {
        "output": str(output if output is not None else model_outputs[0]), "points": index["points"], "tiles": len(keys),
        "buildings": len(layers["roof_outlines"]), "ridges": len(layers["ridges"]),
        "roof_faces": len(layers["roof_faces"]), "tile_size": index["tile_size"], "buffer": index["buffer"],
        "tile_points": int(sum(r["points"] for r in results)),
        "edge_buildings": int(sum(len(r["edge_buildings"]) for r in results)),
        "parameters": derived.to_dict(), "sample_points": index["sample_points"],
        "refined": refined is not None,
        # as the untiled summary: the camera's exterior orientation corrected from all buildings' line matches
        **({"orientation": refined.summary()["orientation"]}
           if refined is not None and refined.orientation is not None else {}),
        "timings": {k: round(v, 3) for k, v in timings.items()},
        "stage_seconds": {k: round(v, 3) for k, v in stages.items()},
    }
