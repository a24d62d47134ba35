"""Render the aerial frame image (or a true orthophoto) of a simulated scene.

One ray per pixel from :meth:`FrameCamera.ray` is cast against the same
surface model as the laser, so the image projects exactly with
:meth:`FrameCamera.project` (relief displacement included: roofs lean away
from the nadir point, walls facing the camera show).  Shading is Lambertian
under a sun direction plus sky light, with cast shadows found by marching
towards the sun; roofs have per-building albedo and some have bright ridge
caps; ground is textured grass and soil with an asphalt road; crowns are
ellipsoids with a clumpy normal.  A Gaussian blur and noise finish it.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import shapely
from scipy.ndimage import gaussian_filter, map_coordinates

from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.synth.raycast import cast_rays, crown_chords, shadow_rays

__all__ = ["make_camera", "render_scene", "sun_vector"]

log = logging.getLogger(__name__)

_GRASS = np.array([0.27, 0.38, 0.17])
_SOIL = np.array([0.46, 0.41, 0.31])
_ASPHALT = np.array([0.20, 0.20, 0.21])
_CROWN = np.array([0.14, 0.27, 0.10])


def sun_vector(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector towards the sun (x east, y north, z up)."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(a) * math.cos(e), math.cos(a) * math.cos(e), math.sin(e)])


def make_camera(options, ground_z: float, rng: np.random.Generator, crs=None) -> FrameCamera:
    """The frame camera: GSD ``options.gsd`` at the scene centre, looking at it from off nadir.

    The slant distance D = gsd · f / pixel size; the projection centre
    stands ``camera_offnadir_deg`` off the vertical of the scene centre
    towards ``camera_azimuth_deg``; ω and φ aim the principal axis at the
    scene centre (plus a 0.05° jitter), κ = ``camera_kappa_deg``.  The
    square image covers 1.1 × the scene.
    """
    dist = options.gsd * options.focal_length_mm / options.pixel_size_mm
    nu, az = math.radians(options.camera_offnadir_deg), math.radians(options.camera_azimuth_deg)
    c = np.asarray(options.center)
    target = np.array([c[0], c[1], ground_z + 4.0])
    centre = target + dist * np.array([math.sin(nu) * math.sin(az), math.sin(nu) * math.cos(az), math.cos(nu)])
    axis = (target - centre) / dist
    phi = math.asin(-axis[0])
    omega = math.atan2(axis[1], -axis[2])
    jitter = np.radians(rng.normal(0.0, 0.05, 2))
    size = int(math.ceil(options.size * 1.1 / options.gsd / 2.0)) * 2
    eo = np.array([*centre, omega + jitter[0], phi + jitter[1], math.radians(options.camera_kappa_deg)])
    return FrameCamera((size, size), options.pixel_size_mm, options.focal_length_mm, eo, crs=crs)


def _value_noise(rng: np.random.Generator, n: int = 64):
    """A smooth periodic noise field: returns f(u, v) in about [-1, 1] (grid units)."""
    grid = rng.uniform(-1.0, 1.0, (n, n))

    def f(u, v):
        return map_coordinates(grid, [np.mod(v, n), np.mod(u, n)], order=3, mode="grid-wrap")
    return f


def _ground_albedo(x, y, road, rng):
    lo, mid, hi = _value_noise(rng), _value_noise(rng), _value_noise(rng)
    mask = np.clip(0.5 + 0.9 * lo(x / 9.0, y / 9.0), 0, 1) ** 2
    col = _GRASS[None] * (1 - 0.45 * mask[:, None]) + _SOIL[None] * (0.45 * mask[:, None])
    col *= (1 + 0.12 * mid(x / 1.3, y / 1.3) + 0.08 * hi(x / 0.35, y / 0.35))[:, None]
    if road is not None:
        on = shapely.contains_xy(road, x, y)
        col[on] = _ASPHALT * (1 + 0.06 * hi(x[on] / 0.5, y[on] / 0.5))[:, None]
    return col


def _road(scene):
    """A 5 m road along the gap between the middle rows of building slots, if no roof touches it."""
    o = scene.options
    n = int(o.size // 30.0)
    if n < 2:
        return None
    y = o.origin[1] + (o.size - n * 30.0) / 2 + (n // 2) * 30.0
    road = shapely.box(o.origin[0] - 200, y - 2.5, o.origin[0] + o.size + 200, y + 2.5)
    if any(road.intersects(b.roof_outline) for b in scene.buildings):
        return None
    return road


def _wall_normals(faces, pts_xy, view):
    """Outward normals of the face-boundary segment nearest each wall hit, turned towards the viewer."""
    segs = []
    for f in faces:
        for ring in [f.polygon.exterior, *f.polygon.interiors]:
            c = np.asarray(ring.coords)[:, :2]
            segs.append(np.stack([c[:-1], c[1:]], axis=1))
    segs = np.concatenate(segs)
    tree = shapely.STRtree(shapely.linestrings(segs))
    idx = tree.query_nearest(shapely.points(pts_xy), return_distance=False, all_matches=False)[1]
    d = segs[idx, 1] - segs[idx, 0]
    n = np.column_stack([d[:, 1], -d[:, 0], np.zeros(len(d))])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    flip = np.einsum("ij,ij->i", n, view) < 0
    n[flip] *= -1
    return n


def shade(scene, origins: np.ndarray, dirs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Linear RGB radiance (N, 3) seen along rays (origins, unit dirs)."""
    o = scene.options
    model = scene.model
    t, face, wall = cast_rays(origins, dirs, *model.args(), model.z_top, model.z_bot)
    trees = scene.trees.as_array()
    tin, _, tid = crown_chords(origins, dirs, trees, np.where(np.isfinite(t), t, np.inf), 1)
    is_tree = np.isfinite(tin[:, 0])
    t = np.where(is_tree, tin[:, 0], t)
    p = origins + t[:, None] * dirs
    n = len(p)
    normal = np.zeros((n, 3))
    albedo = np.zeros((n, 3))
    roof = (face >= 0) & ~wall & ~is_tree
    walls = (face >= 0) & wall & ~is_tree
    ground = (face < 0) & ~is_tree
    planes = model.planes[np.maximum(face, 0)]
    normal[roof] = np.column_stack([-planes[roof, 0], -planes[roof, 1], np.ones(roof.sum())])
    eps = 0.05
    terr = scene.terrain
    gx = (terr.height(p[ground, 0] + eps, p[ground, 1]) - terr.height(p[ground, 0] - eps, p[ground, 1])) / (2 * eps)
    gy = (terr.height(p[ground, 0], p[ground, 1] + eps) - terr.height(p[ground, 0], p[ground, 1] - eps)) / (2 * eps)
    normal[ground] = np.column_stack([-gx, -gy, np.ones(ground.sum())])
    if walls.any():
        normal[walls] = _wall_normals(scene.faces, p[walls, :2], -dirs[walls])
    if is_tree.any():
        tr = trees[tid[is_tree, 0]]
        q = p[is_tree] - tr[:, :3]
        g = np.column_stack([q[:, 0] / tr[:, 3] ** 2, q[:, 1] / tr[:, 3] ** 2, q[:, 2] / tr[:, 4] ** 2])
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        normal[is_tree] = g + 0.45 * rng.normal(size=g.shape)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    # albedo
    albedo[ground] = _ground_albedo(p[ground, 0], p[ground, 1], _road(scene), rng)
    bidx = {b.building_id: b for b in scene.buildings}
    fb = np.array([f.building_id for f in scene.faces] or [0])
    roof_col = np.array([bidx[b].roof_colour for b in fb] if len(scene.faces) else [[0, 0, 0]], float)
    wall_col = np.array([bidx[b].wall_colour for b in fb] if len(scene.faces) else [[0, 0, 0]], float)
    fine = _value_noise(rng)
    if roof.any():
        albedo[roof] = roof_col[face[roof]] * (1 + 0.05 * fine(p[roof, 0] / 0.4, p[roof, 1] / 0.4))[:, None]
        _ridge_caps(scene, p, face, roof, albedo)
    albedo[walls] = wall_col[face[walls]] * (1 + 0.04 * fine(p[walls, 0] / 0.3, p[walls, 2] / 0.3))[:, None]
    if is_tree.any():
        albedo[is_tree] = _CROWN * (0.75 + 0.5 * rng.random(is_tree.sum()))[:, None]
    # light
    sun = sun_vector(o.sun_azimuth_deg, o.sun_elevation_deg)
    lift = np.where(walls, 0.06, 0.02)[:, None] * normal
    light = shadow_rays(p + lift, sun, *model.args(), model.z_top, trees, 0.3)
    direct = np.clip(normal @ sun, 0.0, None) * light
    sky = 0.32 * (0.55 + 0.45 * normal[:, 2])
    radiance = albedo * (sky + 1.0 * direct)[:, None]
    if scene.power_line is not None:
        near = _near_wire(origins, dirs, scene.power_line.as_array(), t, 0.5 * o.gsd)
        radiance[near] *= 0.5
    return radiance


def _near_wire(origins, dirs, wires, t_max, radius):
    """Rays passing within ``radius`` (m) of a conductor before their hit: a thin dark line in the image.

    A conductor lies in the vertical plane through its pylons; a slanted ray
    crosses that plane once, and its distance to the (locally horizontal)
    wire is the height miss there times the ray's horizontal component
    across the plane.  A vertical ray (orthophoto) uses the plan distance.
    """
    near = np.zeros(len(origins), bool)
    for x0, y0, x1, y1, z0, z1, sag in wires:
        a = np.array([x0, y0])
        u = np.array([x1 - x0, y1 - y0])
        length = np.hypot(*u)
        u /= length
        nrm = np.array([-u[1], u[0]])
        den = dirs[:, :2] @ nrm
        vertical = np.abs(den) < 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            tw = np.where(vertical, 0.0, ((a - origins[:, :2]) @ nrm) / np.where(vertical, 1.0, den))
        p = origins + tw[:, None] * dirs
        s = ((p[:, :2] - a) @ u) / length
        zw = z0 + (z1 - z0) * s - 4 * sag * s * (1 - s)
        miss = np.where(vertical, np.abs((origins[:, :2] - a) @ nrm), np.abs(p[:, 2] - zw) * np.abs(den))
        t_wire = (zw - origins[:, 2]) / dirs[:, 2]  # where the ray passes the wire's height
        before = vertical | ((t_wire > 0) & (t_wire < t_max))
        near |= (miss < radius) & (s >= 0) & (s <= 1) & before
    return near


def _ridge_caps(scene, p, face, roof, albedo, half_width: float = 0.18):
    """Paint bright caps (``half_width`` m either side) on ridges and hips of buildings with ``ridge_cap``."""
    capped = {b.building_id for b in scene.buildings if b.ridge_cap}
    if not capped:
        return
    fb = np.array([f.building_id for f in scene.faces])
    for bid in capped:
        lines = [r.line for r in scene.ridges if r.building_id == bid and r.kind in ("ridge", "hip")]
        if not lines:
            continue
        sel = roof & (fb[np.maximum(face, 0)] == bid)
        if not sel.any():
            continue
        geom = shapely.force_2d(shapely.multilinestrings(lines))
        near = shapely.distance(geom, shapely.points(p[sel, :2])) < half_width
        idx = np.flatnonzero(sel)[near]
        albedo[idx] = np.clip(albedo[idx] * 0.4 + 0.55, 0, 1)


def _finish(radiance: np.ndarray, h: int, w: int, options, rng) -> np.ndarray:
    img = radiance.reshape(h, w, 3)
    img = np.clip(img * 1.05, 0.0, 1.0) ** (1 / 1.5)
    img = np.stack([gaussian_filter(img[..., k], options.blur_sigma_px) for k in range(3)]) if options.blur_sigma_px > 0 \
        else img.transpose(2, 0, 1)
    img = img + rng.normal(0.0, options.image_noise, img.shape)
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


def render_scene(scene, rng: np.random.Generator) -> None:
    """Render ``scene.image`` (uint8 (3, H, W)) and set ``scene.camera`` (and ``ortho_transform``)."""
    o = scene.options
    if o.orthophoto:
        x0, y0, x1, y1 = o.bounds
        w = h = int(round(o.size / o.gsd))
        transform = (o.gsd, 0.0, x0, 0.0, -o.gsd, y1)
        cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        origins = np.column_stack([x0 + cols.ravel() * o.gsd, y1 - rows.ravel() * o.gsd,
                                   np.full(w * h, scene.model.z_top + 1.0)])
        dirs = np.tile([0.0, 0.0, -1.0], (w * h, 1))
        camera = OrthoCamera((w, h), transform, scene.crs)
        scene.ortho_transform = transform
    else:
        camera = make_camera(o, float(scene.terrain.height(*o.center)), rng, scene.crs)
        w, h = camera.image_size
        cols, rows = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        origins, dirs = camera.ray(np.column_stack([cols.ravel(), rows.ravel()]))
    radiance = shade(scene, np.ascontiguousarray(origins), np.ascontiguousarray(dirs), rng)
    scene.image = _finish(radiance, h, w, o, rng)
    scene.camera = camera
    log.info("image: %d x %d px, GSD %.2f m", w, h, o.gsd)
