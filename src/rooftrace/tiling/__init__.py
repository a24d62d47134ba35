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
   and store them as ``RUN/results/<i>_<j>.pkl``, their 3D models beside
   it in ``<i>_<j>.models`` (:mod:`rooftrace.tiling.models`).  Tiles run
   in-process (``workers=1``), on a Dask LocalCluster or on a Dask cluster
   (``--scheduler``; the run folder must be on a file system every worker
   sees).
4. ``merge``: join the tile results and number the buildings by their
   lowest (x, y, z) point like the untiled detection does.  With an image,
   the parent then refines all the merged buildings in one pass, as the
   untiled run does; the image is checked before step 1 and never goes to
   the tiles (:mod:`rooftrace.tiling.image`).  The models are not merged
   in memory: they stream from the tiles' files in building order as the
   writer takes them.

:func:`run_tiled` returns the merged layers and models
(:class:`TiledRunResult`); writing them is the caller's, as for
:func:`rooftrace.pipeline.run_pipeline` (``rooftrace run`` writes both the
same way).

Results do not depend on the number of workers: tiles are independent and
merged in a fixed order.  ``--resume`` keeps the split, the parameters and
every finished tile of an earlier run of the same inputs and options
(the image and camera included) in the same run folder.
"""


from __future__ import annotations

import ctypes
import json
import logging
import os
import pickle
import shutil
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rooftrace.errors import InputError, OptionError
from rooftrace.io.vector import Layer
from rooftrace.model.types import BuildingModel
from rooftrace.progress import Reporter
from rooftrace.tiling.image import (
    check_image_inputs,
    cut_neighbourhoods,
    image_fingerprint,
    join_neighbourhoods,
    merged_planes,
    roofs_of_layers,
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
    TileResult,
    TileTask,
    building_numbers,
    estimate_parameters,
    footprints_per_tile,
    merge_tiles,
    merged_models,
    merged_point_labels,
    owned_buildings,
    process_tile,
    tile_core,
    tile_extent,
)

if TYPE_CHECKING:  # rooftrace.config imports TileOptions from this package
    from rooftrace.config import RunOptions
    from rooftrace.footprints import Footprints
    from rooftrace.lidar.detect import DerivedParams
    from rooftrace.refine import RefineResult

__all__ = [
    "TileOptions", "tile_grid", "tile_cell_ranges", "sample_windows", "split_to_tiles", "estimate_parameters",
    "owned_buildings", "TileTask", "TileResult", "process_tile", "merge_tiles", "merged_models", "run_tiled",
    "TiledRunResult",
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
            raise OptionError(f"{{scheduler}} {options.scheduler}: cannot connect ({exc})", "scheduler") from None
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


@dataclass
class TiledRunResult:
    """Everything a tiled run produced (:func:`run_tiled`), merged.

    Attributes
    ----------
    layers : dict of str to Layer
        The output layers, as :attr:`rooftrace.pipeline.RunResult.layers`
        of an untiled run (same names, order and numbering).
    models : iterable of BuildingModel
        3D models of every outlined building, in building-id order.  With
        a ``run_dir`` a :class:`~rooftrace.tiling.models.ModelStream` that
        reads them from the tiles' files as it is iterated (a city's models
        are never all in memory; read it before the folder is removed),
        else a list.
    refined : RefineResult or None
        Image refinement of the merged buildings, when an image was given.
    crs : pyproj.CRS or None
        CRS of the inputs (or the one assigned).
    points : int
        Points of the inputs.
    tiles : int
        Tiles processed.
    tile_size, buffer : float
        Tile side and buffer used (m).
    tile_points : int
        Points over all buffered tiles.
    edge_buildings : int
        Buildings that reach a buffer's open edge (maybe cut; a warning names each).
    parameters : DerivedParams
        The data-derived detection parameters every tile used.
    sample_points : int
        Points they were measured on.
    classification, building_id : ndarray of shape (N,) or None
        Class and merged building id of every input point in input order,
        when asked for (``classified``).
    timings : dict of str to float
        Seconds per step of the tiled run.
    stage_seconds : dict of str to float
        Seconds per pipeline stage, summed over the tiles.
    """

    layers: dict[str, Layer]
    models: Iterable[BuildingModel]
    refined: RefineResult | None
    crs: Any
    points: int
    tiles: int
    tile_size: float
    buffer: float
    tile_points: int
    edge_buildings: int
    parameters: DerivedParams
    sample_points: int
    classification: np.ndarray | None = None
    building_id: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)
    stage_seconds: dict[str, float] = field(default_factory=dict)

    def point_labels(self) -> tuple[np.ndarray, np.ndarray]:
        """Class and building id of every input point, in input order (``classified`` runs)."""
        if self.classification is None or self.building_id is None:
            raise ValueError("run_tiled(classified=False) keeps no point labels")
        return self.classification, self.building_id

    def summary(self) -> dict[str, Any]:
        """A JSON-serialisable summary for ``--json``: counts, the parameters, the seconds of every step."""
        return {
            "points": self.points, "tiles": self.tiles,
            "buildings": len(self.layers["roof_outlines"]), "ridges": len(self.layers["ridges"]),
            "roof_faces": len(self.layers["roof_faces"]), "tile_size": self.tile_size, "buffer": self.buffer,
            "tile_points": self.tile_points, "edge_buildings": self.edge_buildings,
            "parameters": self.parameters.to_dict(), "sample_points": self.sample_points,
            "refined": self.refined is not None,
            # as the untiled summary: the camera's exterior orientation corrected from all buildings' line matches
            **({"orientation": self.refined.summary()["orientation"]}
               if self.refined is not None and self.refined.orientation is not None else {}),
            "timings": {k: round(v, 3) for k, v in self.timings.items()},
            "stage_seconds": {k: round(v, 3) for k, v in self.stage_seconds.items()},
        }


def _footprints_fingerprint(footprints: Footprints) -> str:
    """What ``resume`` compares of the footprints: a hash of their geometries, ids and id field."""
    import hashlib

    import shapely

    digest = hashlib.sha256(footprints.id_field.encode())
    for polygon, fid in zip(footprints.polygons, footprints.ids):
        digest.update(shapely.to_wkb(polygon))
        digest.update(repr(fid).encode())
    return digest.hexdigest()


def _refine_merged(layers: dict[str, Layer], results: list[TileResult], image: Path, camera: Path, cam,
                   options: RunOptions, seed: int, reporter: Reporter):
    """Refine the merged buildings with the image, once (see :mod:`rooftrace.tiling.image`)."""
    from rooftrace.io.checks import check_image_size
    from rooftrace.io.raster import read_image
    from rooftrace.pipeline import refined_layers
    from rooftrace.refine import refine_roofs

    grey = read_image(image)
    check_image_size(grey.shape[::-1], cam, str(image), str(camera))  # the file may have changed since the check
    points = join_neighbourhoods(results)
    roofs = roofs_of_layers(layers, merged_planes(results, building_numbers(results)))
    with reporter.stage("image refinement", total=None):
        refined = refine_roofs(roofs, grey, cam, points_xyz=points, options=options.refine, seed=seed)
    return refined, refined_layers(layers, refined)


def run_tiled(inputs: Sequence[os.PathLike], options: RunOptions | None = None, tiling: TileOptions | None = None,
              *, run_dir: os.PathLike | None = None, crs=None, image: os.PathLike | None = None,
              camera: os.PathLike | None = None, seed: int = 0, reporter: Reporter | None = None,
              classified: bool = False, footprints: Footprints | None = None) -> TiledRunResult:
    """The whole method on inputs of any size, in tiles: split, measure the parameters, process, merge.

    Parameters
    ----------
    inputs : sequence of path-like
        LAS/LAZ files, in any number and layout.
    options : RunOptions, optional
        Every option of the run, as :func:`rooftrace.pipeline.run_pipeline`
        takes them (default: the defaults).
    tiling : TileOptions, optional
        Tile size, buffer, workers, scheduler, resume.
    run_dir : path-like, optional
        Folder of the tiles and their results, kept for ``tiling.resume``
        when the run fails or is killed; the caller removes it once the
        outputs are written.  None: a temporary folder, removed at the end.
    crs : str or pyproj.CRS, optional
        Assign or override the inputs' CRS (all inputs must agree otherwise).
    image, camera : path-like, optional
        Aerial image and its ``camera.json`` (None for a georeferenced
        orthophoto, whose GeoTIFF is its camera): the merged buildings are
        refined with it in one pass, as an untiled run refines them
        (:mod:`rooftrace.tiling.image`).  Checked before any tile work.
    seed : int, default 0
        Seed of everything random.
    reporter : Reporter, optional
        Progress callbacks (silent by default).
    classified : bool, default False
        Also give the class and merged building id of every input point
        (:meth:`TiledRunResult.point_labels`; inputs of one point format, so
        that one LAS file can hold them all).
    footprints : Footprints, optional
        Building footprints in the points' CRS: one building per footprint,
        as :func:`rooftrace.pipeline.run_pipeline` makes them.  They are
        split along the tiles as the points are; each tile outputs the
        footprints whose centre is in its core, so a footprint's building
        is the untiled run's when the buffer holds it and its neighbours.

    Returns
    -------
    TiledRunResult
        The merged layers and models, equal to those of an untiled
        :func:`rooftrace.pipeline.run_pipeline` on the whole input, and the
        counts and seconds of the run.

    Raises
    ------
    InputError
        Unreadable inputs, inputs of different CRSs, an image that does not
        fit them, or ``resume`` with other inputs or options than the run
        folder's.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from rooftrace.io.las import write_las
    >>> from rooftrace.synth import SceneOptions, simulate_scene
    >>> scene = simulate_scene(SceneOptions(seed=1, size=40.0, density=8.0, image=False, trees=False))
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> path = write_las(folder / "scene.laz", scene.cloud)
    >>> result = run_tiled([path], tiling=TileOptions(tile_size=20.0, buffer=20.0))
    >>> result.tiles, len(result.layers["roof_outlines"])
    (4, 1)
    """
    from rooftrace.config import RunOptions
    from rooftrace.io.checks import require_metric_crs
    from rooftrace.io.points import common_crs, parse_crs

    options = options if options is not None else RunOptions()
    tiling = tiling if tiling is not None else TileOptions()
    refine_context = options.refine.context if image is not None else None
    paths = [Path(p) for p in inputs]
    if not paths:
        raise InputError("no input files given")
    head = scan_headers(paths)
    if classified:
        from rooftrace.io.las import check_point_formats

        check_point_formats(paths)
    file_crss = head["crs"]
    user_crs = parse_crs(crs) if isinstance(crs, str) else crs
    crs_obj = user_crs or file_crss[0]
    if user_crs is None:
        common_crs(paths, file_crss)
    b = head["bounds"]  # without a CRS, header bounds within a fraction of a unit of (lon, lat) are degrees
    require_metric_crs(crs_obj, str(paths[0]), np.array([[b[0], b[1]], [b[2], b[3]]]))
    cam = None
    if image is not None:
        # the untiled run's checks, on the headers, before minutes of tile work
        cam = check_image_inputs(Path(image), None if camera is None else Path(camera), crs_obj, head,
                                 ", ".join(map(str, paths)))
    temporary = run_dir is None
    run_dir = Path(tempfile.mkdtemp(prefix="rooftrace-tiles-")) if temporary else Path(run_dir)
    try:
        result = _run_in(run_dir, paths, head, options, tiling, crs_obj, image, camera, cam, seed,
                         reporter or Reporter(), classified, refine_context, footprints)
        if temporary:  # the tiles' model files go with the folder: read them now
            result.models = list(result.models)
    finally:
        if temporary:
            shutil.rmtree(run_dir, ignore_errors=True)
    return result


def _run_in(run_dir: Path, paths: list[Path], head: dict, options: RunOptions, tiling: TileOptions, crs_obj,
            image, camera, cam, seed: int, reporter: Reporter, classified: bool,
            refine_context: float | None, footprints: Footprints | None) -> TiledRunResult:
    """:func:`run_tiled` after its checks, in ``run_dir``."""
    from rooftrace.lidar.detect import DerivedParams
    from rooftrace.pipeline import building_layers

    if run_dir.exists() and not tiling.resume:
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    meta = {"inputs": [str(p.resolve()) for p in paths],
            "tiling": {k: v for k, v in asdict(tiling).items() if k not in ("resume", "workers", "scheduler")},
            "crs": crs_obj.to_wkt() if crs_obj is not None else None,
            "options": asdict(options), "seed": seed, "classified": classified,
            # the tiles do not use the image, but a resumed run must give what a fresh one gives
            **({"image": image_fingerprint(Path(image), None if camera is None else Path(camera))}
               if image is not None else {}),
            **({"footprints": _footprints_fingerprint(footprints)} if footprints is not None else {})}
    meta = json.loads(json.dumps(meta, default=str))
    meta_path = run_dir / "run.json"
    if tiling.resume and meta_path.exists() and json.loads(meta_path.read_text()) != meta:
        raise OptionError(f"{run_dir}: {{resume}} with different inputs or options; rerun without {{resume}}",
                          "resume")
    write_json(meta_path, meta)

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    with reporter.stage("split into tiles"):
        index = split_to_tiles(paths, run_dir, tiling, cell=options.detect.outliers.cell)
    timings["split"] = time.perf_counter() - t0
    derived_path = run_dir / "derived.json"
    t0 = time.perf_counter()
    if tiling.resume and derived_path.exists():
        derived = DerivedParams.from_dict(json.loads(derived_path.read_text()))
    else:
        with reporter.stage("parameters"):
            sample = load_tile_points(run_dir / "sample", crs_obj)
            sample.sources = [str(p) for p in paths]
            derived = estimate_parameters(sample, options.detect, origin=index["origin"], extent=index["bounds"])
            del sample
        write_json(derived_path, derived.to_dict())
    timings["parameters"] = time.perf_counter() - t0
    log.info("parameters of the whole run: s_avg %.3f m, d_avg %.2f pts/m², sigma_H %.3f m, entropy threshold %.3f",
             derived.mean_spacing, derived.density, derived.sigma_h, derived.entropy_threshold)
    keys = sorted(index["tiles"], key=lambda k: tuple(int(v) for v in k.split("_")))
    wkt = crs_obj.to_wkt() if crs_obj is not None else None
    # the tiles get the parameters as the file holds them, so that a resumed run gives what a fresh one gives
    fixed = DerivedParams.from_dict(derived.to_dict())
    per_tile = (footprints_per_tile(footprints, index, keys, reach=2.0 * options.footprints.overhang + 1.0)
                if footprints is not None else {})
    tasks = [TileTask(str(run_dir), k, tuple(tile_core(index, k)), wkt, options, seed, fixed,
                      tuple(tile_extent(index, k)), classified, refine_context, per_tile.get(k)) for k in keys]
    t0 = time.perf_counter()
    with reporter.stage("tiles", total=len(tasks)):
        result_paths = _execute(tasks, [index["tiles"][k]["points"] for k in keys], tiling, reporter)
    timings["tiles"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    results: list[TileResult] = [pickle.loads(Path(r).read_bytes()) for r in result_paths]
    layers = merge_tiles(results)
    empty = building_layers([], [], models=[])
    for name, layer in empty.items():
        layers.setdefault(name, layer)
    layers = {name: layers[name] for name in empty}  # the untiled run's layer order
    models = merged_models(results, result_paths)
    timings["merge"] = time.perf_counter() - t0
    refined = None
    if cam is not None and len(layers["roof_outlines"]):
        for k, res in zip(keys, results):
            for x, y, r in np.asarray(res.refine_discs, float).reshape(-1, 3)[
                    cut_neighbourhoods(res.refine_discs, tile_extent(index, k), index["bounds"])]:
                log.warning("tile %s: the image refinement uses the points within %.1f m of the building at "
                            "(%.1f, %.1f), beyond the tile's buffer; rerun with a larger buffer", k, r, x, y)
        t0 = time.perf_counter()
        refined, layers = _refine_merged(layers, results, Path(image), Path(camera or image), cam, options, seed,
                                         reporter)
        timings["refine"] = time.perf_counter() - t0
    classes = building_id = None
    if classified:
        t0 = time.perf_counter()
        classes, building_id = merged_point_labels(results, result_paths, index["points"])
        timings["classified"] = time.perf_counter() - t0
    stages: dict[str, float] = {}
    for res in results:
        for k, v in res.timings.items():
            stages[k] = stages.get(k, 0.0) + v
    return TiledRunResult(
        layers=layers, models=models, refined=refined, crs=crs_obj, points=index["points"], tiles=len(keys),
        tile_size=index["tile_size"], buffer=index["buffer"], tile_points=int(sum(r.points for r in results)),
        edge_buildings=int(sum(len(r.edge_buildings) for r in results)), parameters=derived,
        sample_points=index["sample_points"], classification=classes, building_id=building_id,
        timings=timings, stage_seconds=stages)
