"""``rooftrace refine``: sharpen existing 3D roof outlines and ridges with an aerial image (Marcato & Dal Poz)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, setup_logging

log = logging.getLogger("rooftrace.cli")


def _ids(layer, name: str, n: int) -> list[int] | None:
    values = layer.attributes.get(name) if layer is not None else None
    if values is None or len(values) != n:
        return None
    try:
        return [int(v) for v in values]
    except (TypeError, ValueError):
        return None


def _roof_planes(outlines, xyz: np.ndarray, cfg: dict) -> list:
    """Roof planes per outline from the LiDAR points inside it (None where none are found)."""
    import shapely
    from scipy.spatial import cKDTree

    from rooftrace.errors import GeometryError
    from rooftrace.options import make_options
    from rooftrace.roof import RoofOptions, roof_structure

    options = make_options(RoofOptions, cfg)
    tree = cKDTree(xyz[:, :2])
    planes = []
    for poly in outlines:
        if poly is None or poly.is_empty or poly.geom_type != "Polygon":
            planes.append(None)
            continue
        x0, y0, x1, y1 = poly.bounds
        near = np.sort(np.asarray(tree.query_ball_point([(x0 + x1) / 2, (y0 + y1) / 2],
                                                        np.hypot(x1 - x0, y1 - y0) / 2), int))
        pts = xyz[near]
        pts = pts[shapely.contains_xy(shapely.force_2d(poly), pts[:, 0], pts[:, 1])]
        try:
            roof = roof_structure(pts, poly, options)
            planes.append(roof.planes if len(roof.planes) else None)
        except (GeometryError, ValueError) as exc:
            log.debug("no roof planes (%s)", exc)
            planes.append(None)
    return planes


@app.command("refine")
def refine(
    outlines_path: Annotated[Path, typer.Argument(metavar="OUTLINES", help="GeoPackage with a roof_outlines layer "
                                                  "(PolygonZ) and optionally ridges (LineStringZ).")],
    output: opt.Output,
    image: Annotated[Path, typer.Option("--image", help=opt.IMAGE_HELP, show_default=False)],
    camera: opt.Camera = None,
    points: Annotated[Path | None, typer.Option("--points", help="LiDAR points (LAS/LAZ): roof planes and the "
                                                   "terrain-line filter.")] = None,
    crs: opt.Crs = None,
    config: opt.Config = None,
    seed: opt.Seed = 0,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Refine 3D roof outlines and ridges with an aerial image: candidate image lines, MRF grouping
    by a genetic algorithm, reconstruction, and rays back onto the roof planes."""
    import pyproj
    import shapely

    from rooftrace.config import load_config
    from rooftrace.errors import InputError
    from rooftrace.io.atomic import check_output
    from rooftrace.io.camera import image_camera
    from rooftrace.io.checks import check_image_covers, check_image_size, check_same_crs, require_metric_crs
    from rooftrace.io.raster import read_image
    from rooftrace.io.vector import Layer, read_layer, write_layers
    from rooftrace.refine import RefineOptions, refine_buildings

    setup_logging(quiet)
    if output.suffix.lower() != ".gpkg":
        raise InputError(f"{output}: the output of refine is a GeoPackage; name it *.gpkg")
    check_output(output, overwrite)
    cfg = load_config(config)
    try:
        options = RefineOptions.from_config(cfg)
    except InputError as exc:
        if config is None or str(config) in str(exc):
            raise
        raise InputError(f"{config}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"{config}: {exc}") from None

    outlines = read_layer(outlines_path, "roof_outlines")
    ridges = read_layer(outlines_path, "ridges", missing_ok=True) or Layer([], {}, "LineStringZ")
    target_crs = pyproj.CRS.from_user_input(crs) if crs else outlines.crs
    require_metric_crs(target_crs, str(outlines_path))
    cam = image_camera(image, camera)
    check_same_crs(target_crs, cam.crs, str(outlines_path), str(camera or image))
    geoms = [g if g is None or shapely.has_z(g) else shapely.force_3d(g) for g in outlines.geometries]
    vertices = [shapely.get_coordinates(g, include_z=True) for g in geoms if g is not None and not g.is_empty]
    vertices = np.concatenate(vertices) if vertices else np.empty((0, 3))
    vertices[np.isnan(vertices[:, 2]), 2] = 0.0
    check_image_covers(cam, vertices, str(image))
    grey = read_image(image)
    check_image_size(grey.shape[::-1], cam, str(image), str(camera or image))
    if not len(vertices):
        # no buildings upstream is a result, not a mistake: pass the empty layers on
        log.warning("%s: the roof_outlines layer has no outlines; writing empty layers to %s", outlines_path, output)
        write_layers(output, {"roof_outlines": outlines, "ridges": ridges}, target_crs, overwrite=overwrite)
        if json_:
            emit_json({"output": str(output), "buildings": len(outlines), "status": {}, "sides": 0,
                       "sides_refined": 0})
        return

    xyz = planes = None
    if points is not None:
        from rooftrace.io.points import read_points

        cloud = read_points([points], crs, require_points=False)
        check_same_crs(target_crs, cloud.crs, str(outlines_path), str(points))
        if len(cloud):
            xyz = cloud.xyz
            planes = _roof_planes(geoms, xyz, cfg)
        else:
            log.warning("%s: no points; refining without LiDAR roof planes and terrain-line filter", points)

    ridge_geoms = [g if g is None or shapely.has_z(g) else shapely.force_3d(g) for g in ridges.geometries]
    building_ids = _ids(outlines, "building_id", len(geoms))
    ridge_ids = _ids(ridges, "building_id", len(ridge_geoms)) if building_ids is not None else None
    result = refine_buildings(geoms, ridge_geoms, grey, cam, points_xyz=xyz, planes=planes,
                              building_ids=building_ids, ridge_building_ids=ridge_ids, options=options, seed=seed)

    out_attrs = {k: v for k, v in outlines.attributes.items() if k not in result.attributes}
    out_attrs.update(result.attributes)
    # input ridge attributes win (their own kind), except the new 'refined' flag
    ridge_attrs = dict(ridges.attributes)
    ridge_attrs.update({k: v for k, v in result.ridge_attributes.items() if k not in ridge_attrs or k == "refined"})
    layers = {"roof_outlines": Layer(result.outlines, out_attrs, "PolygonZ"),
              "ridges": Layer(result.ridges, ridge_attrs, "LineStringZ")}
    write_layers(output, layers, target_crs, overwrite=overwrite)
    summary = {"output": str(output), **result.summary()}
    if json_:
        emit_json(summary)
    else:
        log.info("%d of %d buildings refined (%d of %d sides replaced by image lines) -> %s",
                 summary["status"].get("refined", 0), summary["buildings"], summary["sides_refined"],
                 summary["sides"], output)
