"""``rooftrace snake``: semi-automatic 3D roof outline from seed points (Dal Poz & Fazan)."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, setup_logging

log = logging.getLogger("rooftrace.cli")


def seed_groups(layer, where: str) -> list[tuple[object, np.ndarray]]:
    """Seed rings (n, 2) per ``building`` value, in order of first appearance.

    Point features contribute one seed each in feature order; a MultiPoint
    contributes its points in order.  Raises InputError for a missing
    ``building`` attribute, other geometry types, or groups of fewer than 3.
    """
    import shapely

    from rooftrace.errors import InputError

    if "building" not in layer.attributes:
        names = ", ".join(layer.attributes) or "none"
        raise InputError(f"{where}: the seeds need a 'building' attribute telling which roof each belongs to "
                         f"(attributes: {names})")
    groups: dict[object, list] = {}
    for i, (geom, key) in enumerate(zip(layer.geometries, layer.attributes["building"])):
        if geom is None or geom.is_empty:
            raise InputError(f"{where}: feature {i} has no geometry")
        kind = shapely.get_type_id(geom)
        if kind not in (0, 4):  # Point, MultiPoint
            raise InputError(f"{where}: feature {i} is a {geom.geom_type}; seeds are Point or MultiPoint features")
        if key is None:
            raise InputError(f"{where}: feature {i} has an empty 'building' value")
        key = key.item() if isinstance(key, np.generic) else key
        groups.setdefault(key, []).append(shapely.get_coordinates(geom))
    out = []
    for key, parts in groups.items():
        ring = np.concatenate(parts)
        if len(ring) < 3:
            raise InputError(f"{where}: building {key!r} has {len(ring)} seed point(s); give at least 3, "
                             "one near each roof corner, in order around the roof")
        out.append((key, ring))
    if not out:
        raise InputError(f"{where}: no seed points")
    return out


@app.command("snake")
def snake(
    output: opt.Output,
    image: Annotated[Path, typer.Option("--image", help=opt.IMAGE_HELP, show_default=False)],
    points: Annotated[list[Path], typer.Option("--points", help="LiDAR point cloud(s) (LAS/LAZ); repeat for several.",
                                               show_default=False)],
    seeds: Annotated[Path, typer.Option("--seeds", help="Seed points near the roof corners (GeoJSON/GPKG): Point "
                                        "features in order around each roof, or one MultiPoint per roof, with a "
                                        "'building' attribute.", show_default=False)],
    seeds_in_pixels: Annotated[bool, typer.Option("--seeds-in-pixels", help="Seed coordinates are image pixels "
                                                  "(column, row; centres at integers), not map coordinates.")] = False,
    camera: opt.Camera = None,
    crs: opt.Crs = None,
    config: opt.Config = None,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Trace one 3D roof outline per group of seed points: a polygon snake in object space whose
    vertices follow the image edges (collinearity), keep right angles, and take Z from a LiDAR TIN."""
    import shapely

    from rooftrace.config import load_config
    from rooftrace.errors import GeometryError, InputError
    from rooftrace.io.atomic import check_output
    from rooftrace.io.camera import image_camera
    from rooftrace.io.checks import check_points, check_same_crs, require_metric_crs
    from rooftrace.io.points import read_points
    from rooftrace.io.raster import read_image
    from rooftrace.io.vector import Layer, read_layer, vector_driver, write_layers
    from rooftrace.options import make_options
    from rooftrace.snake import SnakeOptions, pixel_seeds_to_object, snake_outline

    setup_logging(quiet)
    t0 = time.perf_counter()
    check_output(output, overwrite)
    vector_driver(output)
    options = make_options(SnakeOptions, load_config(config))
    cloud = read_points(points, crs, require_points=False)
    where = ", ".join(map(str, points))
    if len(cloud) == 0:
        raise InputError(f"{where}: no points; the snake takes its heights from the LiDAR points, "
                         "give a cloud that covers the seeds")
    require_metric_crs(cloud.crs, where, cloud.xyz[:, :2])
    check_points(cloud.xyz, where)
    cam = image_camera(image, camera)
    check_same_crs(cloud.crs, getattr(cam, "crs", None), where, str(camera or image))
    grey = read_image(image)
    if tuple(grey.shape[::-1]) != tuple(cam.image_size):
        raise InputError(f"{image}: {grey.shape[1]} x {grey.shape[0]} px, but {camera or image} describes "
                         f"{cam.image_size[0]} x {cam.image_size[1]} px; give the camera file of this image")
    layer = read_layer(seeds)
    groups = seed_groups(layer, str(seeds))
    if not seeds_in_pixels:
        allxy = np.concatenate([r[:, :2] for _, r in groups])
        if layer.crs is not None and layer.crs.is_geographic and (np.abs(allxy).max(axis=0) > [180.0, 90.0]).any():
            # a GeoJSON without a "crs" member reads as WGS 84 (RFC 7946), but
            # hand-written seeds are usually in the map CRS: metres, not degrees
            log.warning("%s: coordinates are not degrees although the file says %s; taking them in the cloud's CRS",
                        seeds, layer.crs.name)
        else:
            check_same_crs(cloud.crs, layer.crs, where, str(seeds))
    w, h = cam.image_size

    geoms, attrs = [], {k: [] for k in ("building", "energy", "e_image", "e_angle", "e_spacing", "iterations",
                                        "converged", "area", "z_mean")}
    for key, ring in groups:
        xy = ring[:, :2]
        if seeds_in_pixels:
            out = (xy[:, 0] < -0.5) | (xy[:, 0] > w - 0.5) | (xy[:, 1] < -0.5) | (xy[:, 1] > h - 0.5)
            if out.any():
                raise InputError(f"{seeds}: building {key!r}: seed(s) {np.flatnonzero(out).tolist()} lie outside the "
                                 f"image ({w} x {h} px); pixel seeds are (column, row)")
        try:
            if seeds_in_pixels:
                xy = pixel_seeds_to_object(xy, cam, cloud.xyz)
            res = snake_outline(xy, grey, cam, cloud.xyz, options)
        except InputError as exc:
            raise InputError(f"{seeds}: building {key!r}: {exc}") from None
        except GeometryError as exc:
            # the seeds are the user's: a roof the snake cannot build is theirs to move
            raise InputError(f"{seeds}: building {key!r}: {exc}; check the seeds and that the cloud covers "
                             "them") from None
        poly = shapely.Polygon(res.xyz)
        geoms.append(poly)
        attrs["building"].append(key)
        attrs["energy"].append(res.energy)
        attrs["e_image"].append(res.terms["image"])
        attrs["e_angle"].append(res.terms["angle"])
        attrs["e_spacing"].append(res.terms["spacing"])
        attrs["iterations"].append(res.iterations)
        attrs["converged"].append(bool(res.converged))
        attrs["area"].append(float(poly.area))
        attrs["z_mean"].append(float(res.xyz[:, 2].mean()))
        log.info("building %s: %d vertices, E = %.3f, %d iterations", key, len(res.xyz), res.energy, res.iterations)
    write_layers(output, {"roof_outlines": Layer(geoms, attrs, "PolygonZ", cloud.crs)}, cloud.crs, overwrite=overwrite)
    summary = {
        "output": str(output),
        "buildings": len(geoms),
        "seconds": round(time.perf_counter() - t0, 3),
        "outlines": [{"building": k, "vertices": len(g.exterior.coords) - 1, "energy": e, "area": a, "converged": c}
                     for k, g, e, a, c in zip(attrs["building"], geoms, attrs["energy"], attrs["area"],
                                              attrs["converged"])],
    }
    if json_:
        emit_json(summary)
    elif not quiet:
        typer.echo(f"{len(geoms)} roof outline(s) -> {output}")
