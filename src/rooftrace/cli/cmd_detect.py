"""``rooftrace detect``: ground, buildings, vegetation and noise classes of a LiDAR cloud."""

from __future__ import annotations

import logging
import time
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, reporter_for, setup_logging

log = logging.getLogger("rooftrace.cli")

_NAMES = {1: "other", 2: "ground", 5: "high_vegetation", 6: "building", 7: "noise"}


def _check_memory(inputs, where: str, output) -> None:
    """Refuse, before reading, a cloud that cannot fit in memory in one piece (run classifies in tiles)."""
    from rooftrace.errors import InputError
    from rooftrace.tiling.memory import available_bytes, header_points, untiled_bytes

    announced = header_points(inputs)
    if announced and untiled_bytes(announced) > available_bytes():
        raise InputError(f"{where}: {announced} points need about {untiled_bytes(announced) / 2**30:.1f} GiB in one "
                         f"piece and {available_bytes() / 2**30:.1f} GiB are available; classify them in tiles with "
                         f"'rooftrace run {' '.join(map(str, inputs))} -o OUT.gpkg --classified {output}'")


@app.command("detect")
def detect(
    inputs: opt.Inputs,
    output: opt.Output,
    crs: opt.Crs = None,
    config: opt.Config = None,
    min_area: Annotated[float | None, typer.Option(
        "--min-area", min=0.01, help="Smallest building kept, Ar_min (m²); default 4.")] = None,
    min_height: Annotated[float | None, typer.Option(
        "--min-height", min=0.0, help="Lowest height above ground of roof points (m); default 2.")] = None,
    seed_cell: Annotated[float | None, typer.Option(
        "--seed-cell", min=1.0, help="Ground seed grid cell (m), larger than the largest building; default 30.")] = None,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Classify LiDAR points (ASPRS 2 ground, 6 building, 5 high vegetation, 7 noise, 1 other) into a LAZ/LAS file.

    The output keeps every input dimension and adds the int32 dimension
    building_id (0 = none).  The input's own classification is ignored.
    """
    from rooftrace.config import load_config
    from rooftrace.errors import InputError
    from rooftrace.io.atomic import check_output
    from rooftrace.io.checks import check_points, require_metric_crs
    from rooftrace.io.las import write_las
    from rooftrace.io.points import read_points
    from rooftrace.lidar.detect import DetectOptions, detect_buildings

    setup_logging(quiet)
    check_output(output, overwrite)
    if output.suffix.lower() not in (".las", ".laz"):
        raise InputError(f"{output}: output must end in .las or .laz")
    options = DetectOptions.from_config(
        load_config(config),
        segment={"min_area": min_area, "min_height": min_height},
        ground={"seed_cell": seed_cell},
    )
    where = ", ".join(map(str, inputs))
    _check_memory(inputs, where, output)
    t0 = time.perf_counter()
    cloud = read_points(inputs, crs, require_points=False)
    require_metric_crs(cloud.crs, where, cloud.xyz[:, :2])
    check_points(cloud.xyz, where)
    t_read = time.perf_counter() - t0
    if len(cloud) == 0:
        # an empty tile is data, not a mistake: an empty classified file keeps a batch going
        log.warning("%s: no points; writing an empty classified file", where)
        write_las(output, cloud, classification=np.zeros(0, np.uint8), building_id=np.zeros(0, np.int32),
                  overwrite=overwrite)
        if json_:
            emit_json({"output": str(output), "points": 0, "crs": cloud.crs.to_string() if cloud.crs else None,
                       "classes": {}, "buildings": 0})
        return
    reporter = reporter_for(quiet or json_)
    try:
        det = detect_buildings(cloud, options, reporter=reporter)
    finally:
        reporter.close()
    if det.n_buildings == 0:
        log.warning("%s: no buildings found; the output has no class-6 points", where)
    t0 = time.perf_counter()
    write_las(output, cloud, classification=det.classification, building_id=det.building_id, overwrite=overwrite)
    t_write = time.perf_counter() - t0

    values, counts = np.unique(det.classification, return_counts=True)
    classes = {_NAMES.get(int(v), str(int(v))): int(c) for v, c in zip(values, counts)}
    log.info("%d points: %s; %d buildings -> %s", len(cloud), classes, det.n_buildings, output)
    if json_:
        emit_json({
            "output": str(output),
            "points": len(cloud),
            "crs": cloud.crs.to_string() if cloud.crs is not None else None,
            "classes": classes,
            "buildings": det.n_buildings,
            "mean_spacing": det.mean_spacing,
            "density": det.density,
            "sigma_h": det.sigma_h,
            "params": det.params,
            "timings": {"read": t_read, **det.timings, "write": t_write},
        })
