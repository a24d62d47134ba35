"""``rooftrace outline``: roof outlines of points that are already buildings."""

from __future__ import annotations

import logging
import time
from typing import Annotated, Optional

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, reporter_for, setup_logging

log = logging.getLogger("rooftrace.cli")

BUILDING = 6


@app.command("outline")
def outline(
    inputs: opt.Inputs,
    output: opt.Output,
    single_building: Annotated[bool, typer.Option(
        "--single-building", help="Every input file (PLY, LAS/LAZ or text x y z) is one building.")] = False,
    alpha: Annotated[Optional[str], typer.Option(
        "--alpha", help="Alpha-shape strategy: global (S1), building (S2) or point (S3).")] = None,
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
    from rooftrace.contour.alpha_shape import mean_spacing
    from rooftrace.contour.outline import OutlineOptions, connected_buildings, outline_buildings, outlines_layer
    from rooftrace.errors import GeometryError, InputError
    from rooftrace.io.atomic import check_output
    from rooftrace.io.checks import check_points, require_metric_crs
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import vector_driver, write_layers

    setup_logging(quiet)
    if alpha is not None and alpha not in ("global", "building", "point"):
        raise InputError(f"--alpha must be global, building or point, not {alpha!r}")
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
        source = cloud.fields["source_index"].astype(np.int64)
        ids = source + 1
        xyz = cloud.xyz
        extra = {"source": [inputs[i].name for i in range(len(inputs))]}
    else:
        if "classification" not in cloud.fields:
            raise InputError(f"{inputs[0]}: no classification; use --single-building for a cloud that is one "
                             "building, or classify it first with 'rooftrace detect'")
        cls = cloud.fields["classification"]
        building = cls == BUILDING
        if len(cloud) and not building.any():
            if np.isin(cls, (0, 1)).all():  # LAS "never classified" / "unclassified" only
                raise InputError(f"{where}: not classified (no class-6 building points); classify it with "
                                 "'rooftrace detect', or use --single-building for a cloud that is one building")
            log.warning("%s: no class-6 (building) points; writing an empty roof_outlines layer", where)
        xyz = cloud.xyz[building]
        # ASPRS 7 and 18 are noise: every other point is not roof, and the roof edge lies before it
        context = cloud.xyz[~building & ~np.isin(cls, (7, 18)), :2]
        if "building_id" in cloud.fields:
            ids = cloud.fields["building_id"][building].astype(np.int64)
        else:
            try:
                spacing = mean_spacing(xyz[:, :2])
                ids = connected_buildings(xyz[:, :2], 2.0 * spacing)
            except GeometryError:
                # too few or collinear building points for a spacing: one building, which
                # then gets the status saying why it has no outline
                ids = np.ones(len(xyz), np.int64)
    spacing = None
    if options.alpha.strategy == "global" and options.alpha.alpha is None:
        try:
            per = [mean_spacing(xyz[ids == i, :2]) for i in np.unique(ids[ids > 0])]
            spacing = float(np.median(per)) if per else None
        except GeometryError:
            spacing = None
    reporter = reporter_for(quiet)
    try:
        outlines = outline_buildings(xyz, ids, options, mean_spacing=spacing, reporter=reporter, context_xy=context)
    finally:
        reporter.close()
    if extra is not None:
        extra = {"source": [extra["source"][o.building_id - 1] for o in outlines]}
    layer = outlines_layer(outlines, extra)
    write_layers(output, {"roof_outlines": layer}, cloud.crs, overwrite=overwrite)
    statuses: dict[str, int] = {}
    for o in outlines:
        statuses[o.status] = statuses.get(o.status, 0) + 1
    failed = [o.building_id for o in outlines if o.polygon is None]
    if failed:
        log.warning("%d of %d buildings have no outline (see their 'status' attribute): ids %s",
                    len(failed), len(outlines), ", ".join(map(str, failed[:20])) + (" ..." if len(failed) > 20 else ""))
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
