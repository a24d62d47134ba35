"""Simulate a whole scene (terrain, buildings, trees, ALS cloud, aerial image, truth) and write it."""

from __future__ import annotations

import copy
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyproj
import shapely
from shapely.geometry import Polygon

from rooftrace.cloud import PointCloud
from rooftrace.errors import InputError, OutputExistsError
from rooftrace.io.vector import Layer
from rooftrace.synth.als import scan_scene
from rooftrace.synth.blocks import block_buildings
from rooftrace.synth.buildings import Building
from rooftrace.synth.mix import ROOF_PALETTE, WALL_PALETTE, default_buildings
from rooftrace.synth.raycast import SurfaceModel
from rooftrace.synth.scene import PowerLine, SceneOptions, Terrain, Trees, make_power_line, make_terrain, place_trees
from rooftrace.synth.truth import Ridge, RoofFace, plane_z, roof_faces, roof_outline_3d, roof_ridges

__all__ = ["Scene", "simulate_scene", "write_scene", "surface_model", "truth_layers", "SCENE_FILES"]

log = logging.getLogger(__name__)

#: files written by :func:`write_scene` (key -> name)
SCENE_FILES = {"points": "points.laz", "image": "image.tif", "camera": "camera.json", "truth": "truth.gpkg",
               "camera_perturbed": "camera_perturbed.json", "scene": "scene.json"}


@dataclass
class Scene:
    """A simulated scene and its exact truth.

    Attributes
    ----------
    options : SceneOptions
    cloud : PointCloud
        The ALS points: ``classification`` is 1 everywhere (raw); truth in
        ``truth_class`` (uint8 ASPRS: 2 ground, 6 building, 5 vegetation,
        7 noise, 14 wire) and ``truth_building_id`` (int32, 0 = none).
    crs : pyproj.CRS
    buildings : list of Building
        With ``base_height`` filled.
    truth : dict of str to Layer
        ``roof_outlines`` (PolygonZ at roof-edge height, overhang included),
        ``footprints`` (Polygon, walls), ``ridges`` (LineStringZ, ``kind`` in
        ridge | hip | valley | step), ``roof_faces`` (PolygonZ with
        ``slope_deg``, ``aspect_deg``).
    image : ndarray of shape (3, H, W), uint8, or None
        RGB frame image (or orthophoto in orthophoto mode).
    camera : FrameCamera or OrthoCamera or None
        The true camera of ``image``.
    ortho_transform : tuple or None
        Affine (a, b, c, d, e, f) of the orthophoto.
    terrain, trees, power_line, faces, ridges, model
        The geometry the cloud and image were made from.
    info : dict
        Counts, strip layout and timings.
    """

    options: SceneOptions
    cloud: PointCloud
    crs: Any
    buildings: list[Building]
    truth: dict[str, Layer]
    image: np.ndarray | None = None
    camera: Any = None
    ortho_transform: tuple | None = None
    terrain: Terrain | None = None
    trees: Trees | None = None
    power_line: PowerLine | None = None
    faces: list[RoofFace] = field(default_factory=list)
    ridges: list[Ridge] = field(default_factory=list)
    model: SurfaceModel | None = None
    info: dict = field(default_factory=dict)


def _check_buildings(buildings: list[Building], options: SceneOptions) -> None:
    ids = [b.building_id for b in buildings]
    if any((not isinstance(i, (int, np.integer))) or i <= 0 for i in ids):
        raise InputError("simulate: building ids must be positive integers")
    if len(set(ids)) != len(ids):
        raise InputError("simulate: building ids must be unique")
    scene = shapely.box(*options.bounds)
    for b in buildings:
        if not b.blocks:
            raise InputError(f"simulate: building {b.building_id} has no roof blocks")
        if not scene.contains(b.roof_outline):
            raise InputError(f"simulate: building {b.building_id} is not inside the scene {options.bounds}")
        if not b.eave_height > 0 or b.ridge_height < b.eave_height:
            raise InputError(f"simulate: building {b.building_id} needs 0 < eave_height <= ridge_height")


def surface_model(options: SceneOptions, faces: list[RoofFace], terrain: Terrain, pad: float = 100.0) -> SurfaceModel:
    """Rasterise the face indices at ``options.cell`` and build the coarse height bounds for the ray caster.

    The coarse grid (cells of about 0.5 m, aligned with the face raster, and
    ``pad`` metres beyond the scene, where there is only terrain) holds for
    each cell an upper bound of the surface height over its 3 x 3
    neighbourhood, so a ray above it can skip a whole coarse cell.
    """
    from affine import Affine
    from rasterio.features import rasterize
    from scipy.ndimage import maximum_filter

    x0, y0, x1, y1 = options.bounds
    cell = max(options.cell, (options.size + 2.0) / 6000.0)  # at most 6000 x 6000 cells
    k = max(1, int(round(0.5 / cell)))
    ccell = k * cell
    nx = int(np.ceil((x1 - x0 + 2) / ccell)) * k
    ny = int(np.ceil((y1 - y0 + 2) / ccell)) * k
    gx0, gy1 = x0 - 1.0, y1 + 1.0
    if faces:
        labels = rasterize([(f.polygon, i) for i, f in enumerate(faces)], out_shape=(ny, nx),
                           transform=Affine(cell, 0, gx0, 0, -cell, gy1), fill=-1, dtype="int32")
        planes = np.array([f.plane for f in faces])
    else:
        labels = np.full((ny, nx), -1, np.int32)
        planes = np.zeros((1, 3))
    # roof maxima per coarse cell: plane at the fine cell centre + (|a| + |b|) cell / 2 bounds it in the cell
    cols = gx0 + (np.arange(nx) + 0.5) * cell
    block = np.full((ny // k, nx // k), -np.inf)
    slack = (np.abs(planes[:, 0]) + np.abs(planes[:, 1])) * cell / 2 + 1e-4
    for r0 in range(0, ny, k):
        lab = labels[r0:r0 + k]
        roof = lab >= 0
        if not roof.any():
            continue
        yy = gy1 - (np.arange(r0, r0 + k) + 0.5) * cell
        gx, gy = np.meshgrid(cols, yy)
        z = np.full(lab.shape, -np.inf)
        pl = planes[lab[roof]]
        z[roof] = pl[:, 0] * gx[roof] + pl[:, 1] * gy[roof] + pl[:, 2] + slack[lab[roof]]
        block[r0 // k] = z.reshape(k, nx // k, k).max(axis=(0, 2))
    # terrain maxima per coarse cell: corners + curvature bound (max second derivative x half diagonal^2 / 2)
    npad = int(np.ceil(pad / ccell))
    my, mx = block.shape[0] + 2 * npad, block.shape[1] + 2 * npad
    cx0, cy1 = gx0 - npad * ccell, gy1 + npad * ccell
    gx, gy = np.meshgrid(cx0 + np.arange(mx + 1) * ccell, cy1 - np.arange(my + 1) * ccell)
    corner = terrain.height(gx, gy)
    curv = float(np.sum(terrain.amplitude * np.sum(terrain.wavevector**2, axis=1))) * ccell**2 / 4 + 1e-4
    coarse = np.maximum.reduce([corner[:-1, :-1], corner[1:, :-1], corner[:-1, 1:], corner[1:, 1:]]) + curv
    inner = coarse[npad:npad + block.shape[0], npad:npad + block.shape[1]]
    coarse[npad:npad + block.shape[0], npad:npad + block.shape[1]] = np.maximum(block, inner)
    coarse = maximum_filter(coarse, size=3, mode="nearest") + 1e-3
    z_top = float(coarse.max()) + 0.5
    z_bot = float(corner.min()) - 3.0
    k_max = max([len(f.support) for f in faces if f.support is not None] + [1])
    support = np.zeros((len(planes), k_max, 3))
    support[:, :, 2] = np.inf
    for i, f in enumerate(faces):
        rows = f.support if f.support is not None else f.plane[None]
        support[i, :len(rows)] = rows
    if not faces:
        support[0, 0] = planes[0]
    return SurfaceModel(labels, gx0, gy1, cell, planes, terrain.coefficients(), z_top, z_bot, coarse, cx0, cy1, ccell,
                        support)


def _z_polygon(poly: Polygon, plane: np.ndarray) -> Polygon:
    def ring(r):
        xy = np.asarray(r.coords)[:, :2]
        return np.column_stack([xy, plane_z(plane, xy[:, 0], xy[:, 1])])
    return Polygon(ring(poly.exterior), [ring(r) for r in poly.interiors])


def truth_layers(buildings: list[Building], faces: list[RoofFace], ridges: list[Ridge], crs) -> dict[str, Layer]:
    """The truth GeoPackage layers (see :class:`Scene`)."""
    by_b: dict[int, list[RoofFace]] = {}
    for f in faces:
        by_b.setdefault(f.building_id, []).append(f)
    outlines = [roof_outline_3d(b, by_b.get(b.building_id, [])) for b in buildings]
    bid = [int(b.building_id) for b in buildings]
    roof_outlines = Layer(outlines, {
        "building_id": bid, "kind": [b.kind for b in buildings],
        "eave_height": [float(b.eave_height) for b in buildings],
        "ridge_height": [float(b.ridge_height) for b in buildings],
        "base_height": [float(b.base_height or 0.0) for b in buildings],
        "overhang": [float(b.overhang) for b in buildings],
        "area": [float(o.area) for o in outlines],
        "n_faces": [len(by_b.get(b.building_id, [])) for b in buildings],
    }, "PolygonZ", crs)
    footprints = Layer([b.footprint for b in buildings], {
        "building_id": bid, "kind": [b.kind for b in buildings], "area": [float(b.footprint.area) for b in buildings],
    }, "Polygon", crs)
    ridge_layer = Layer([r.line for r in ridges], {
        "building_id": [int(r.building_id) for r in ridges], "kind": [r.kind for r in ridges],
        "length": [float(r.line.length) for r in ridges],
    }, "LineStringZ", crs)
    face_layer = Layer([_z_polygon(f.polygon, f.plane) for f in faces], {
        "building_id": [int(f.building_id) for f in faces], "face_id": list(range(1, len(faces) + 1)),
        "slope_deg": [f.slope_deg for f in faces], "aspect_deg": [f.aspect_deg for f in faces],
        "plane_a": [float(f.plane[0]) for f in faces], "plane_b": [float(f.plane[1]) for f in faces],
        "plane_c": [float(f.plane[2]) for f in faces],
    }, "PolygonZ", crs)
    return {"roof_outlines": roof_outlines, "ridges": ridge_layer, "footprints": footprints, "roof_faces": face_layer}


def simulate_scene(options: SceneOptions | None = None, *, buildings: list[Building] | None = None) -> Scene:
    """Simulate a scene: terrain, buildings, trees, the ALS cloud, the image and the truth.

    Parameters
    ----------
    options : SceneOptions, optional
        Defaults: a 160 m scene, 12 pts/m², 0.2 m GSD, seed 1.
    buildings : list of Building, optional
        Buildings to use instead of those of ``options.scene``; they must lie
        inside the scene.  Copies are made; the input is not changed.

    Returns
    -------
    Scene

    Notes
    -----
    Independent random streams (terrain, trees, scan, image) derive from
    ``options.seed``, so switching the image off leaves the cloud identical.

    Examples
    --------
    >>> scene = simulate_scene(SceneOptions(seed=1, size=40.0, density=8.0, image=False, trees=False))
    >>> scene.truth["roof_outlines"].attributes["kind"]
    ['l_shape']
    >>> len(scene.cloud) > 10_000
    True
    """
    options = options or SceneOptions()
    t0 = time.perf_counter()
    seed = int(options.seed)
    rngs = {k: np.random.default_rng([seed, i]) for i, k in enumerate(("terrain", "trees", "als", "image", "colour"))}
    crs = pyproj.CRS.from_user_input(options.crs)
    terrain = make_terrain(options, rngs["terrain"])
    if buildings is None and options.scene == "blocks":
        buildings = block_buildings(seed, options.size, options.origin)
    elif buildings is None:
        buildings = default_buildings(seed, options.size, options.origin)
    else:
        buildings = copy.deepcopy(list(buildings))
    _check_buildings(buildings, options)
    for b in buildings:
        c = b.footprint.centroid
        b.base_height = float(terrain.height(c.x, c.y))
        if b.roof_colour is None:
            b.roof_colour = tuple(ROOF_PALETTE[int(rngs["colour"].integers(len(ROOF_PALETTE)))])
        if b.wall_colour is None:
            b.wall_colour = tuple(WALL_PALETTE[int(rngs["colour"].integers(len(WALL_PALETTE)))])
    faces = [f for b in buildings for f in roof_faces(b)]
    ridges = roof_ridges(faces)
    trees = place_trees(options, buildings, terrain, rngs["trees"]) if options.trees else Trees(
        np.empty((0, 3)), np.empty(0), np.empty(0))
    power = make_power_line(options, terrain, rngs["trees"]) if options.power_line else None
    model = surface_model(options, faces, terrain)
    t1 = time.perf_counter()
    bindex = {b.building_id: b for b in buildings}
    face_building = np.array([f.building_id for f in faces] or [0], np.int32)
    face_refl = np.array([0.2 + 0.6 * float(np.mean(bindex[f.building_id].roof_colour)) for f in faces] or [0.3])
    z_ref = float(terrain.height(*options.center))
    cloud, info = scan_scene(options, model, trees.as_array(), power.as_array() if power else None, face_building,
                             face_refl, z_ref, rngs["als"])
    cloud.crs = crs
    cloud.sources = [f"rooftrace simulate seed={seed}"]
    t2 = time.perf_counter()
    scene = Scene(options, cloud, crs, buildings, truth_layers(buildings, faces, ridges, crs), terrain=terrain,
                  trees=trees, power_line=power, faces=faces, ridges=ridges, model=model)
    if options.image or options.orthophoto:
        from rooftrace.synth.render import render_scene

        render_scene(scene, rngs["image"])
    t3 = time.perf_counter()
    info.update(buildings=len(buildings), faces=len(faces), ridges=len(ridges), trees=len(trees),
                seconds={"geometry": t1 - t0, "als": t2 - t1, "image": t3 - t2, "total": t3 - t0})
    scene.info = info
    log.info("scene: %d buildings, %d points, %.1f s", len(buildings), len(cloud), t3 - t0)
    return scene


def _perturb(camera, pixels: float, points: np.ndarray, rng: np.random.Generator):
    """A copy of ``camera`` whose EO is off by a draw moving projections ~``pixels`` px on average.

    The covariance C = k · diag(σ_p², σ_p², σ_p², σ_a², σ_a², σ_a²) with
    σ_a = σ_p / H (so positions and angles contribute alike) is scaled so
    the expected displacement is ``pixels``; the draw from N(0, C) is then
    rescaled to make the mean displacement over the scene exactly ``pixels``.
    """
    eo = np.asarray(camera.exterior, float)
    h = max(float(eo[2] - np.mean(points[:, 2])), 1.0)
    c0 = np.diag([1.0, 1.0, 1.0, h**-2, h**-2, h**-2])
    j_eo, _ = camera.jacobians(points)
    expected = float(np.mean(np.einsum("nik,kl,nil->n", j_eo, c0, j_eo)))
    cov = c0 * (pixels**2 / expected)
    delta = np.linalg.cholesky(cov) @ rng.standard_normal(6)
    base = camera.project(points)
    for _ in range(3):
        disp = float(np.mean(np.hypot(*(camera.project(points, eo + delta) - base).T)))
        delta *= pixels / max(disp, 1e-12)
    return camera.with_exterior(eo + delta, cov)


def write_scene(out_dir, scene: Scene, *, overwrite: bool = False,
                perturbed_camera_px: float | None = None) -> dict[str, Path]:
    """Write a scene into a folder.

    Files: ``points.laz`` (truth as extra dimensions ``truth_class`` and
    ``truth_building_id``), ``image.tif`` and ``camera.json`` (when the scene
    has an image; an orthophoto is a GeoTIFF with ``"type": "orthophoto"``),
    ``truth.gpkg`` (``roof_outlines``, ``ridges``, ``footprints``,
    ``roof_faces``), ``scene.json`` (options and counts) and, with
    ``perturbed_camera_px``, ``camera_perturbed.json`` (frame cameras only).

    Raises
    ------
    OutputExistsError
        A file exists and ``overwrite`` is False (nothing is written).
    """
    from rooftrace.io.atomic import atomic_path
    from rooftrace.io.camera import write_camera
    from rooftrace.io.las import write_las
    from rooftrace.io.raster import write_geotiff
    from rooftrace.io.vector import write_layers

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a folder")
    frame = scene.image is not None and scene.ortho_transform is None
    if perturbed_camera_px is not None and (not frame or not perturbed_camera_px > 0):
        raise InputError("perturbed camera needs a frame image and a positive number of pixels")
    keys = ["points", "truth", "scene"] + (["image", "camera"] if scene.image is not None else [])
    keys += ["camera_perturbed"] if perturbed_camera_px else []
    paths = {k: out / SCENE_FILES[k] for k in keys}
    existing = [str(p) for p in paths.values() if p.exists()]
    if existing and not overwrite:
        raise OutputExistsError(f"{', '.join(existing)} exist(s); pass {{overwrite}} to replace", "overwrite")
    out.mkdir(parents=True, exist_ok=True)
    cloud = scene.cloud
    write_las(paths["points"], cloud, extra={"truth_class": cloud.fields["truth_class"],
                                             "truth_building_id": cloud.fields["truth_building_id"]},
              overwrite=overwrite)
    write_layers(paths["truth"], scene.truth, scene.crs, overwrite=overwrite)
    if scene.image is not None:
        if frame:
            write_geotiff(paths["image"], scene.image, overwrite=overwrite)
            write_camera(paths["camera"], scene.camera, overwrite=overwrite)
        else:
            write_geotiff(paths["image"], scene.image, transform=scene.ortho_transform, crs=scene.crs,
                          overwrite=overwrite)
            with atomic_path(paths["camera"], overwrite) as tmp:
                tmp.write_text(json.dumps({"type": "orthophoto", "crs": scene.crs.to_string(), "sigma_px": 0.0},
                                          indent=2) + "\n", encoding="utf-8")
    if perturbed_camera_px:
        pts = np.vstack([shapely.get_coordinates(g, include_z=True) for g in scene.truth["roof_outlines"].geometries])
        rng = np.random.default_rng([int(scene.options.seed), 99])
        write_camera(paths["camera_perturbed"], _perturb(scene.camera, float(perturbed_camera_px), pts, rng),
                     overwrite=overwrite)
    meta = {"options": {k: getattr(scene.options, k) for k in scene.options.__dataclass_fields__},
            "info": scene.info, "crs": scene.crs.to_string()}
    with atomic_path(paths["scene"], overwrite) as tmp:
        tmp.write_text(json.dumps(meta, indent=2, default=str) + "\n", encoding="utf-8")
    return paths
