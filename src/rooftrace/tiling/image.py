"""Image refinement of a tiled run: checked before the tiles, run once after the merge.

The tiles run the LiDAR method only; the image never goes to a worker.
After the merge the parent refines every building in one pass with
:func:`rooftrace.refine.refine_roofs`, the function the untiled run
uses, because the refinement is not per building: the exterior-orientation
correction (``[refine] orientation``) fits one camera to the line matches of
all buildings, and the genetic algorithm of building ``i`` is seeded with
``seed + i`` in the merged numbering.  Refining per tile would give each
tile its own camera and seeds.

What the refinement needs from the LiDAR besides the layers:

- the roof planes of each building (``RoofStructure.planes``), carried in
  the tile results;
- the points (any class) around each building, within ``[refine] context``
  of it: :func:`rooftrace.refine.refine_buildings` takes the ground height
  under the walls and the LiDAR precision from them, and the terrain-line
  filter (off by default) the points themselves.  Each tile keeps the
  points of that neighbourhood of the buildings it owns (a superset of what
  the refinement queries, with a margin), the parent joins them by their
  index in the input files and orders them as the input is; a query of
  the refinement on this union returns exactly the points it returns on the
  whole cloud, so nothing is re-read and memory stays at the buildings'
  neighbourhoods, not the cloud.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rooftrace.tiling.split import near_open_side

__all__ = ["check_image_inputs", "image_fingerprint", "neighbourhood_points", "cut_neighbourhoods",
           "join_neighbourhoods", "merged_planes", "roofs_of_layers"]

log = logging.getLogger(__name__)

# metres added to the refinement's neighbourhood radius: the tiles keep a
# superset, so rounding in the radius can never drop a point the parent needs
_MARGIN = 1.0


def _header_grid(boxes: Sequence[Sequence[float]], counts: Sequence[int], n: int = 40) -> np.ndarray:
    """Points on an ``n`` x ``n`` grid over each input's header box, at its lowest and highest z.

    The tiled run reads no points before the tiles; the headers' boxes
    stand for the cloud in :func:`rooftrace.io.checks.check_image_covers`.
    """
    out = []
    for (x0, y0, z0, x1, y1, z1), c in zip(boxes, counts):
        if c == 0:
            continue
        gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
        z = np.where((np.arange(gx.size) % 2) == 0, z0, z1)
        out.append(np.column_stack([gx.ravel(), gy.ravel(), z]))
    return np.concatenate(out) if out else np.zeros((0, 3))


def check_image_inputs(image: Path, camera: Path | None, crs, head: dict[str, Any], where: str):
    """The untiled run's checks of the image and its camera, on the inputs' headers.

    Parameters
    ----------
    image : Path
        The image.
    camera : Path or None
        Its ``camera.json``; None for a georeferenced orthophoto.
    crs : pyproj.CRS or None
        CRS of the point clouds.
    head : dict
        :func:`rooftrace.tiling.split._scan_headers` of the inputs
        (``boxes`` and ``counts`` per file).
    where : str
        The inputs, for the messages.

    Returns
    -------
    FrameCamera or OrthoCamera

    Raises
    ------
    InputError
        Unreadable camera or image, a camera in another CRS, an image that
        does not cover the inputs' header boxes, or an image whose size is
        not the camera's.  The image's pixels are read after the tiles; its
        header is read here.
    """
    from rooftrace.io.camera import image_camera
    from rooftrace.io.checks import check_image_covers, check_image_size, check_same_crs
    from rooftrace.io.raster import read_raster_meta

    cam = image_camera(image, camera)
    check_same_crs(crs, cam.crs, where, str(camera or image))
    check_image_covers(cam, _header_grid(head["boxes"], head["counts"]), str(image))
    check_image_size(read_raster_meta(image).size, cam, str(image), str(camera or image))
    return cam


def image_fingerprint(image: Path, camera: Path | None) -> dict[str, Any]:
    """What ``--resume`` compares of the image and camera: paths, the image's size and mtime, the camera's hash.

    The image can be large, so its bytes and modification time stand for
    its content; the camera file is small and hashed.
    """
    st = Path(image).stat()
    return {"image": {"path": str(Path(image).resolve()), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns},
            "camera": None if camera is None else {
                "path": str(Path(camera).resolve()), "sha256": hashlib.sha256(Path(camera).read_bytes()).hexdigest()}}


def neighbourhood_points(xyz: np.ndarray, gidx: np.ndarray, polygons: Sequence, context: float
                         ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The points of a tile the refinement of its buildings may use.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        The tile's points, any class (m).
    gidx : ndarray of shape (N,), int64
        Their indices in the input files.
    polygons : sequence of Polygon
        Outlines of the buildings the tile owns (``None`` or empty skipped).
    context : float
        ``[refine] context`` (m).

    Returns
    -------
    points : dict
        ``xyz`` (M, 3) float64 and ``gidx`` (M,) int64 of the points within
        the refinement's disc of any building (the disc around the centre
        of the outline's box, of radius half its diagonal plus ``context``;
        see :func:`rooftrace.refine.refine_buildings`) plus a margin, in
        ``gidx`` order.
    discs : ndarray of shape (B, 3), float64
        Centre x, y and radius (m, without the margin) of each disc, for
        :func:`cut_neighbourhoods`.
    """
    from scipy.spatial import cKDTree

    discs = []
    for poly in polygons:
        if poly is None or poly.is_empty:
            continue
        x0, y0, x1, y1 = poly.bounds
        discs.append(((x0 + x1) / 2, (y0 + y1) / 2, np.hypot(x1 - x0, y1 - y0) / 2 + context))
    discs = np.asarray(discs, float).reshape(-1, 3)
    keep = np.zeros(len(xyz), bool)
    if len(discs) and len(xyz):
        near = cKDTree(xyz[:, :2]).query_ball_point(discs[:, :2], discs[:, 2] + _MARGIN)
        for idx in near:
            keep[np.asarray(idx, np.int64)] = True
    sel = np.flatnonzero(keep)
    sel = sel[np.argsort(np.asarray(gidx)[sel], kind="stable")]
    return {"xyz": np.ascontiguousarray(xyz[sel], np.float64), "gidx": np.asarray(gidx)[sel].astype(np.int64)}, discs


def cut_neighbourhoods(discs: np.ndarray, extent: Sequence[float], bounds: Sequence[float]) -> np.ndarray:
    """Which discs of :func:`neighbourhood_points` reach past their tile where the data goes on.

    Parameters
    ----------
    discs : ndarray of shape (B, 3)
        Centre x, y and radius (m).
    extent : (xmin, ymin, xmax, ymax)
        The buffered tile clipped to the inputs' bounds (m).
    bounds : (xmin, ymin, xmax, ymax)
        The inputs' bounds (m): past them there are no points to miss.

    Returns
    -------
    ndarray of shape (B,), bool
        True where the tile may lack points the refinement of the whole
        cloud would use (a larger ``--buffer`` helps).
    """
    x, y, r = np.asarray(discs, float).reshape(-1, 3).T
    return near_open_side(np.column_stack([x - r, y - r, x + r, y + r]), extent, bounds)


def join_neighbourhoods(results: Sequence) -> np.ndarray | None:
    """The points of every tile's building neighbourhoods, each once, in the order of the input files.

    ``results`` are the tiles' :class:`rooftrace.tiling.tile.TileResult`.

    Returns
    -------
    ndarray of shape (M, 3), float64, or None
        ``None`` when no tile kept any point.
    """
    parts = [r.refine_points for r in results if len(r.refine_points.get("gidx", ()))]
    if not parts:
        return None
    gidx = np.concatenate([p["gidx"] for p in parts])
    xyz = np.concatenate([p["xyz"] for p in parts])
    # a point in the buffers of two tiles comes twice; np.unique sorts by gidx, the input order
    _, first = np.unique(gidx, return_index=True)
    return xyz[first]


def merged_planes(results: Sequence, numbers: Sequence[tuple]) -> dict[int, np.ndarray]:
    """Roof planes of every building by its merged id.

    ``results`` are the tiles' :class:`rooftrace.tiling.tile.TileResult`,
    ``numbers`` from :func:`rooftrace.tiling.tile.building_numbers`.
    """
    out = {}
    for _, t, old, new in numbers:
        planes = results[t].planes.get(old)
        if planes is not None:
            out[int(new)] = planes
    return out


def roofs_of_layers(layers: dict, planes: dict[int, np.ndarray]):
    """The merged layers of a tiled run as the refinement takes them (:class:`rooftrace.refine.LidarRoofs`).

    The tiles hand their buildings to the merge as layers; this reads the
    outlines, ridges and their buildings back from ``roof_outlines`` and
    ``ridges``, in the layers' (building-id) order, as
    :func:`rooftrace.pipeline.lidar_roofs` takes them from the stages.
    """
    from rooftrace.refine import LidarRoofs

    outlines, ridges = layers["roof_outlines"], layers["ridges"]
    return LidarRoofs(building_ids=[int(b) for b in outlines.attributes["building_id"]],
                      outlines=list(outlines.geometries), ridges=list(ridges.geometries),
                      ridge_building_ids=[int(b) for b in ridges.attributes["building_id"]],
                      ridge_kinds=list(ridges.attributes["kind"]), planes=planes)
