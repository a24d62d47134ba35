"""``rooftrace outline``: roof outlines of points that are already buildings."""

from __future__ import annotations

import logging
import time
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, reporter_for, setup_logging

log = logging.getLogger("rooftrace.cli")


@app.command("outline")
def outline(
    inputs: opt.Inputs,
    output: opt.Output,
    single_building: Annotated[bool, typer.Option(
        "--single-building", help="Every input file (PLY, LAS/LAZ or text x y z) is one building.")] = False,
    alpha: opt.Alpha = None,
    crs: opt.Crs = None,
    config: opt.Config = None,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Trace and regularise 3D roof outlines (alpha shape + CD-spline) into a GeoPackage layer roof_outlines.

    Without --single-building the class-6 (building) points of LAS/LAZ input
    are used, split into buildings by their building_id dimension (as written
    by 'rooftrace detect') or else by connected components in plan view.
    """
    from rooftrace.config import load_config
    from rooftrace.contour.buildings import (
        BUILDING,
        classified_buildings,
        median_building_spacing,
        outline_statuses,
        warn_failed_outlines,
    )
    from rooftrace.contour.outline import OutlineOptions, outline_buildings, outlines_layer
    from rooftrace.errors import InputError
    from rooftrace.io.atomic import check_output
    from rooftrace.io.checks import check_points, require_metric_crs
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import vector_driver, write_layers

    setup_logging(quiet)
    check_output(output, overwrite)
    vector_driver(output)
    options = OutlineOptions.from_config(load_config(config), strategy=alpha)
    t0 = time.perf_counter()
    cloud = read_points(inputs, crs, require_points=False)
    where = ", ".join(map(str, inputs))
    require_metric_crs(cloud.crs, where, cloud.xyz[:, :2])
    check_points(cloud.xyz, where)
    if len(cloud) == 0:
        log.warning("%s: no points; writing an empty roof_outlines layer", where)
    extra = None
    context = None
    if single_building:
        ids = cloud.fields["source_index"].astype(np.int64) + 1
        xyz = cloud.xyz
        extra = {"source": [inputs[i].name for i in range(len(inputs))]}
    else:
        if "classification" not in cloud.fields:
            raise InputError(f"{inputs[0]}: no classification; use --single-building for a cloud that is one "
                             "building, or classify it first with 'rooftrace detect'")
        cls = cloud.fields["classification"]
        if len(cloud) and not (cls == BUILDING).any():
            if np.isin(cls, (0, 1)).all():  # LAS "never classified" / "unclassified" only
                raise InputError(f"{where}: not classified (no class-6 building points); classify it with "
                                 "'rooftrace detect', or use --single-building for a cloud that is one building")
            log.warning("%s: no class-6 (building) points; writing an empty roof_outlines layer", where)
        xyz, ids = classified_buildings(cloud.xyz, cls, cloud.fields.get("building_id"))
        # ASPRS 7 and 18 are noise: every other point is not roof, and the roof edge lies before it
        context = cloud.xyz[(cls != BUILDING) & ~np.isin(cls, (7, 18))]
    spacing = None
    if options.alpha.strategy == "global" and options.alpha.alpha is None:
        spacing = median_building_spacing(xyz, ids)
    reporter = reporter_for(quiet)
    try:
        outlines = outline_buildings(xyz, ids, options, mean_spacing=spacing, reporter=reporter, context_xy=context)
    finally:
        reporter.close()
    if extra is not None:
        extra = {"source": [extra["source"][o.building_id - 1] for o in outlines]}
    layer = outlines_layer(outlines, extra)
    write_layers(output, {"roof_outlines": layer}, cloud.crs, overwrite=overwrite)
    statuses = outline_statuses(outlines)
    warn_failed_outlines(outlines)
    summary = {
        "output": str(output),
        "layer": "roof_outlines",
        "buildings": len(outlines),
        "status": statuses,
        "alpha_strategy": options.alpha.strategy,
        "points": int((ids > 0).sum()),
        "seconds": round(time.perf_counter() - t0, 3),
    }
    if json_:
        emit_json(summary)
    else:
        log.info("%d roof outlines written to %s (%s)", len(outlines), output,
                 ", ".join(f"{k}: {v}" for k, v in statuses.items()))
