"""``rooftrace run``: the whole method, from LAS/LAZ (and an image) to a GeoPackage and 3D city models."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, reporter_for, setup_logging

log = logging.getLogger("rooftrace.cli")


@app.command("run")
def run(
    inputs: opt.Inputs,
    outputs: opt.Outputs,
    image: opt.Image = None,
    camera: opt.Camera = None,
    alpha: opt.Alpha = None,
    no_planes: Annotated[bool, typer.Option("--no-planes", help="Skip roof planes, ridges and faces.")] = False,
    classified: Annotated[Path | None, typer.Option("--classified", help="Also write the classified points (LAZ).")] = None,
    footprints: Annotated[Path | None, typer.Option(
        "--footprints", help="Building footprints (any OGR vector: GPKG, GeoJSON, Shapefile, FlatGeobuf, SQLite), "
        "reprojected to the cloud's CRS: one building per footprint.")] = None,
    footprint_id: Annotated[str | None, typer.Option(
        "--footprint-id", help="Attribute of --footprints carried as footprint_id (default: identificatie, "
        "identificatiebagpnd, id, fid or gml_id if present, else the feature id).")] = None,
    crs: opt.Crs = None,
    config: opt.Config = None,
    seed: opt.Seed = 0,
    workers: opt.Workers = 1,
    scheduler: opt.Scheduler = None,
    tile_size: opt.TileSize = None,
    buffer: opt.Buffer = None,
    resume: opt.Resume = False,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Detect buildings, trace and regularise roof outlines, find roof planes and ridges, build
    LoD 1.2 / 1.3 / 2.2 models; refine the outlines with the image when --image is given.

    \b
    An orthophoto (a georeferenced GeoTIFF) needs no camera file:
      rooftrace run tile.laz --image ortho.tif -o roofs.gpkg
    An aerial frame image needs its orientation:
      rooftrace run tile.laz --image photo.tif --camera camera.json -o roofs.gpkg
    Several outputs, the format by the name (.gpkg, .city.jsonl, .city.json, .obj):
      rooftrace run tile.laz -o roofs.gpkg -o city.city.jsonl
    """
    from rooftrace.config import RunOptions, load_config
    from rooftrace.contour.buildings import warn_failed_outlines
    from rooftrace.errors import InputError
    from rooftrace.io.atomic import check_output
    from rooftrace.io.checks import (
        check_camera_has_image,
        check_image_covers,
        check_image_size,
        check_points,
        check_same_crs,
        require_metric_crs,
    )
    from rooftrace.io.models import output_format
    from rooftrace.io.points import read_points
    from rooftrace.options import make_options
    from rooftrace.pipeline import run_pipeline
    from rooftrace.tiling import TileOptions
    from rooftrace.tiling.memory import available_bytes, fits_in_memory, header_points, untiled_bytes

    setup_logging(quiet)
    check_camera_has_image(image, camera)
    formats = [output_format(o) for o in outputs]
    if len({o.resolve() for o in outputs}) != len(outputs):
        raise InputError("the same -o file is given twice; give each output once")
    if formats.count("gpkg") > 1:
        raise InputError("more than one .gpkg output; give one GeoPackage (it holds every layer)")
    for o in outputs:
        check_output(o, overwrite)
    gpkg = next((o for o, f in zip(outputs, formats) if f == "gpkg"), None)
    model_files = [o for o, f in zip(outputs, formats) if f != "gpkg"]
    if classified is not None:
        if classified.suffix.lower() not in (".las", ".laz"):
            raise InputError(f"{classified}: --classified writes points; name it *.laz or *.las")
        check_output(classified, overwrite)
    if footprint_id is not None and footprints is None:
        raise InputError("--footprint-id names an attribute of --footprints; give --footprints FILE too")
    cfg = load_config(config)
    # the flags given win over the config's [run] and [tiling] tables
    run_options = RunOptions.from_config(cfg, alpha=alpha, planes=False if no_planes else None)
    tile_options = make_options(TileOptions, cfg, tile_size=tile_size, buffer=buffer,
                                workers=workers if workers > 1 else None, scheduler=scheduler, resume=resume or None)

    tiled = (tile_options.tile_size is not None or tile_options.workers > 1 or tile_options.scheduler is not None
             or tile_options.resume)
    announced = header_points(inputs)  # None: not all readable LAS/LAZ (the readers say why)
    if not tiled and announced and not fits_in_memory(announced):
        log.warning("%s: %d points need about %.1f GiB in one piece and %.1f GiB are available; running in tiles "
                    "(--tile-size sets their size)", ", ".join(map(str, inputs)), announced,
                    untiled_bytes(announced) / 2**30, available_bytes() / 2**30)
        tiled = True
    # an input whose headers announce no points fits in memory whatever the options: the untiled
    # path writes empty layers and a warning (an empty tile of a batch is data, not a mistake)
    where = ", ".join(map(str, inputs))
    if tiled and announced != 0:
        from rooftrace.io.points import parse_crs
        from rooftrace.tiling import run_tiled
        from rooftrace.tiling.split import scan_headers

        prints = None
        if footprints is not None:  # over the headers' box: the tiled run reads no point before the tiles
            head = scan_headers(inputs)
            b = head["bounds"]
            prints = _read_footprints(footprints, footprint_id, parse_crs(crs) if crs else head["crs"][0],
                                      np.array([[b[0], b[1], 0.0], [b[2], b[3], 0.0]]), where)

        first = gpkg if gpkg is not None else model_files[0]
        run_dir = Path(str(first) + ".parts")  # the tiles and their results, kept for --resume until written
        reporter = reporter_for(quiet)
        try:
            result = run_tiled(inputs, run_options, tile_options, run_dir=run_dir, crs=crs, image=image,
                               camera=camera, seed=seed, reporter=reporter, classified=classified is not None,
                               footprints=prints)
        finally:
            reporter.close()
        _write_outputs(result, gpkg, model_files, classified, result.crs, overwrite, inputs=inputs)
        shutil.rmtree(run_dir, ignore_errors=True)
        summary = {"output": str(first), **result.summary()}
        if not summary["buildings"]:
            log.warning("%s: no buildings found; %s %s empty", where, ", ".join(map(str, outputs)),
                        "is" if len(outputs) == 1 else "are")
        if json_:
            emit_json(summary)
        return

    cloud = read_points(inputs, crs, require_points=False)
    require_metric_crs(cloud.crs, where, cloud.xyz[:, :2])
    check_points(cloud.xyz, where)
    grey = cam = None
    if image is not None:
        from rooftrace.io.camera import image_camera
        from rooftrace.io.raster import read_image

        cam = image_camera(image, camera)
        check_same_crs(cloud.crs, cam.crs, where, str(camera or image))
        check_image_covers(cam, cloud.xyz, str(image))
        grey = read_image(image)
        check_image_size(grey.shape[::-1], cam, str(image), str(camera or image))

    prints = None
    if footprints is not None:
        prints = _read_footprints(footprints, footprint_id, cloud.crs, cloud.xyz, where)

    if len(cloud) == 0:
        _write_empty(gpkg, model_files, classified, cloud, overwrite, json_, where)
        return
    reporter = reporter_for(quiet)
    try:
        result = run_pipeline(cloud, run_options, image=grey, camera=cam, seed=seed, reporter=reporter,
                              footprints=prints)
    finally:
        reporter.close()
    _write_outputs(result, gpkg, model_files, classified, cloud.crs, overwrite, cloud=cloud)
    summary = {"output": str(outputs[0]), "outputs": [str(o) for o in outputs], **result.summary()}
    if not result.outlines:
        log.warning("%s: no buildings found; %s %s empty", where, ", ".join(map(str, outputs)),
                    "is" if len(outputs) == 1 else "are")
    else:
        warn_failed_outlines(result.outlines)
    if json_:
        emit_json(summary)
    else:
        log.info("%d buildings, %d ridges, %d roof faces, %d 3D models -> %s", summary["buildings"], summary["ridges"],
                 summary["roof_faces"], len(result.models), ", ".join(map(str, outputs)))


def _read_footprints(path: Path, id_field: str | None, crs, xyz: np.ndarray, where: str):
    """The footprints in the points' CRS, refused when none lies over the points' box."""
    from rooftrace.io.checks import check_footprints_overlap
    from rooftrace.io.footprints import read_footprints

    prints = read_footprints(path, crs, id_field=id_field)
    check_footprints_overlap(prints, xyz, str(path), where)
    return prints


def _write_outputs(result, gpkg: Path | None, model_files: list[Path], classified: Path | None, crs,
                   overwrite: bool, *, cloud=None, inputs: list[Path] | None = None) -> None:
    """Write a run's outputs, every one new or all as they were (:func:`rooftrace.io.atomic.commit_together`).

    The classified points come from ``cloud`` (an untiled run holds it) or
    are streamed again from the ``inputs`` (a tiled run does not).
    """
    from rooftrace.io.atomic import commit_together
    from rooftrace.io.las import write_las, write_las_labels
    from rooftrace.io.models import write_models
    from rooftrace.io.vector import write_layers

    with commit_together():
        if model_files:
            write_models(model_files, result.models, crs, overwrite=overwrite)
        if gpkg is not None:
            write_layers(gpkg, result.layers, crs, overwrite=overwrite)
        if classified is not None:
            classes, building_id = result.point_labels()
            if cloud is not None:
                write_las(classified, cloud, classification=classes, building_id=building_id, overwrite=overwrite)
            else:
                write_las_labels(inputs, classified, classes, building_id, crs=crs, overwrite=overwrite)


def _write_empty(gpkg, model_files, classified, cloud, overwrite: bool, json_: bool, where: str) -> None:
    """An empty input is data, not a mistake: empty layers (with their schema), empty model files and a warning."""
    import numpy as np

    from rooftrace.io.atomic import commit_together
    from rooftrace.io.models import write_models
    from rooftrace.io.vector import write_layers
    from rooftrace.pipeline import building_layers

    outputs = ([gpkg] if gpkg is not None else []) + list(model_files)
    log.warning("%s: no points; writing empty outputs to %s", where, ", ".join(map(str, outputs)))
    with commit_together():
        if gpkg is not None:
            write_layers(gpkg, building_layers([], [], models=[]), cloud.crs, overwrite=overwrite)
        write_models(model_files, [], cloud.crs, overwrite=overwrite)
        if classified is not None:
            from rooftrace.io.las import write_las

            write_las(classified, cloud, classification=np.zeros(0, np.uint8), building_id=np.zeros(0, np.int32),
                      overwrite=overwrite)
    if json_:
        emit_json({"output": str(outputs[0]), "outputs": [str(o) for o in outputs], "points": 0, "classes": {},
                   "buildings": 0, "outline_status": {}, "ridges": 0, "roof_faces": 0, "refined": False})

