"""A small rendered scene with exact truth for checking the snake.

Why here: the snake's tests and benchmark need an aerial image, its frame
camera and a LiDAR sample of the *same* roofs, with known corners.  The full
simulator (``rooftrace.synth``) is the benchmark's first choice; this module
is the self-contained fallback the unit tests use (seconds, no files):
flat and gable roofs on a sloping textured ground, optional round trees,
rendered by ray casting through a tilted frame camera (so relief
displacement is real and the collinearity handling is exercised), and a
uniform random LiDAR sample of the top surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy import ndimage

from rooftrace.image.camera import FrameCamera

__all__ = ["Roof", "SnakeScene", "render_scene", "rectangle", "l_shape"]


@dataclass(frozen=True)
class Roof:
    """A building: footprint ring (n, 2) (m), eave height above ground (m), roof shape and grey level.

    ``kind`` is ``"flat"`` or ``"gable"`` (rectangles only: the ridge runs
    along the longer side, ``rise`` m above the eaves).
    """

    ring: np.ndarray
    height: float
    kind: str = "flat"
    rise: float = 2.0
    grey: float = 0.75


@dataclass
class SnakeScene:
    """Grey image (H, W) in [0, 1], its camera, LiDAR points (N, 3) and true outlines [(n, 3)]."""

    image: np.ndarray
    camera: FrameCamera
    xyz: np.ndarray
    truth: list[np.ndarray]
    roofs: list[Roof]


def rectangle(cx: float, cy: float, length: float, width: float, angle_deg: float = 0.0) -> np.ndarray:
    """Counter-clockwise corners (4, 2) of a rotated rectangle."""
    h = np.array([[-length, -width], [length, -width], [length, width], [-length, width]]) / 2
    a = np.radians(angle_deg)
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return h @ r.T + [cx, cy]


def l_shape(cx: float, cy: float, size: float, arm: float, angle_deg: float = 0.0) -> np.ndarray:
    """Counter-clockwise corners (6, 2) of an L of outer side ``size`` and arm width ``arm``."""
    h = np.array([[0, 0], [size, 0], [size, arm], [arm, arm], [arm, size], [0, size]], float) - size / 2
    a = np.radians(angle_deg)
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return h @ r.T + [cx, cy]


def _ground(xy: np.ndarray) -> np.ndarray:
    return 10.0 + 0.02 * xy[..., 0] + 0.01 * xy[..., 1]


def _faces(roof: Roof) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Planar roof faces: (ring (m, 2), plane (a, b, c, d), grey) with a X + b Y + c Z + d = 0."""
    ring = np.asarray(roof.ring, float)
    z0 = float(_ground(ring.mean(axis=0))) + roof.height
    if roof.kind == "flat":
        return [(ring, np.array([0.0, 0.0, 1.0, -z0]), roof.grey)]
    if roof.kind != "gable" or len(ring) != 4:
        raise ValueError("gable roofs need a rectangle")
    p0, p1, p2, p3 = ring
    if np.linalg.norm(p1 - p0) < np.linalg.norm(p2 - p1):  # ridge along the longer side
        p0, p1, p2, p3 = p1, p2, p3, p0
    m0, m1 = (p0 + p3) / 2, (p1 + p2) / 2
    out = []
    for (a, b), grey in (((p0, p1), roof.grey), ((p2, p3), roof.grey - 0.15)):
        pts = np.array([[*a, z0], [*b, z0], [*(m1 if grey == roof.grey else m0), z0 + roof.rise]])
        n = np.cross(pts[1] - pts[0], pts[2] - pts[0])
        face = np.array([a, b, m1, m0]) if grey == roof.grey else np.array([a, b, m0, m1])
        out.append((face, np.array([*n, -n @ pts[0]]), grey))
    return out


def _camera(center: np.ndarray, size: tuple[int, int], gsd: float, offset: float) -> FrameCamera:
    f, ps = 60.0, 0.012
    height = gsd * f / ps
    phi = np.arctan2(offset, height)  # looks back at the scene from ``offset`` m west
    eo = np.array([center[0] - offset, center[1], height + 10.0, 0.0, phi, 0.0])
    cam = FrameCamera(size, ps, f, eo)
    c = cam.project(np.array([[center[0], center[1], 10.0]]))[0]
    if abs(c[0] - (size[0] - 1) / 2) > size[0] / 4:  # wrong sign convention: tilt the other way
        cam = cam.with_exterior(np.array([*eo[:4], -phi, 0.0]))
    return cam


def render_scene(roofs: list[Roof], *, trees: list[tuple[float, float, float, float]] = (), extent: float = 60.0,
                 gsd: float = 0.2, offset: float = 150.0, density: float = 8.0, seed: int = 0) -> SnakeScene:
    """Render a nadir-ish frame image and a LiDAR sample of roofs on textured ground.

    Parameters
    ----------
    roofs : list of Roof
        Footprints inside ``[-extent/2, extent/2]^2`` (m).
    trees : list of (x, y, radius, height)
        Round crowns (m), dark and textured in the image, domes in the LiDAR.
    extent : float, default 60
        Side of the square scene (m).
    gsd : float, default 0.2
        Ground sample distance (m/px); the image covers the scene plus 10 %.
    offset : float, default 150
        Horizontal distance (m) of the projection centre from the scene
        centre: a tall roof leans by height * offset / flying height.
    density : float, default 8
        LiDAR points per m^2.
    seed : int, default 0
    """
    rng = np.random.default_rng(seed)
    npx = int(np.ceil(1.1 * extent / gsd))
    cam = _camera(np.zeros(2), (npx, npx), gsd, offset)
    cols, rows = np.meshgrid(np.arange(npx), np.arange(npx))
    origin, d = cam.ray(np.column_stack([cols.ravel(), rows.ravel()]))
    # ground: plane z = 10 + 0.02 x + 0.01 y
    gplane = np.array([0.02, 0.01, -1.0, 10.0])
    t_best = -(origin @ gplane[:3] + gplane[3]) / (d @ gplane[:3])
    tex = ndimage.gaussian_filter(rng.normal(size=(npx, npx)), 3.0)
    grey = 0.35 + 0.06 * tex.ravel() / tex.std()
    for roof in roofs:
        ring = np.asarray(roof.ring, float)
        zg = float(_ground(ring.mean(axis=0)))
        faces = _faces(roof)
        for face, plane, g in faces:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -(origin @ plane[:3] + plane[3]) / (d @ plane[:3])
            p = origin + t[:, None] * d
            inside = shapely.contains_xy(shapely.Polygon(face).buffer(1e-9), p[:, 0], p[:, 1]) & (t < t_best)
            t_best = np.where(inside, t, t_best)
            grey = np.where(inside, g, grey)
        # walls: the ray crosses the footprint between eave and ground without meeting the roof first
        top = zg + roof.height
        a = origin + ((top - origin[:, 2]) / d[:, 2])[:, None] * d
        b = origin + ((zg - origin[:, 2]) / d[:, 2])[:, None] * d
        ta = (top - origin[:, 2]) / d[:, 2]
        segs = shapely.linestrings(np.stack([a[:, :2], b[:, :2]], axis=1))
        wall = shapely.intersects(segs, shapely.Polygon(ring)) & (ta < t_best)
        t_best = np.where(wall, ta, t_best)
        grey = np.where(wall, 0.2, grey)
    for x, y, r, h in trees:
        zt = float(_ground(np.array([x, y]))) + h
        t = (zt - origin[:, 2]) / d[:, 2]
        p = origin + t[:, None] * d
        inside = ((p[:, 0] - x) ** 2 + (p[:, 1] - y) ** 2 < r * r) & (t < t_best)
        t_best = np.where(inside, t, t_best)
        grey = np.where(inside, 0.18 + 0.08 * np.abs(tex.ravel()) / tex.std(), grey)
    image = grey.reshape(npx, npx) + rng.normal(0, 0.02, (npx, npx))
    image = np.clip(ndimage.gaussian_filter(image, 0.7), 0, 1)

    n = rng.poisson(density * extent * extent)
    xy = rng.uniform(-extent / 2, extent / 2, (n, 2))
    z = _ground(xy)
    truth = []
    for roof in roofs:
        for face, plane, _ in _faces(roof):
            inside = shapely.contains_xy(shapely.Polygon(face), xy[:, 0], xy[:, 1])
            z = np.where(inside, -(plane[0] * xy[:, 0] + plane[1] * xy[:, 1] + plane[3]) / plane[2], z)
        ring = np.asarray(roof.ring, float)
        truth.append(np.column_stack([ring, np.full(len(ring), _ground(ring.mean(axis=0)) + roof.height)]))
    for x, y, r, h in trees:
        rr = (xy[:, 0] - x) ** 2 + (xy[:, 1] - y) ** 2
        dome = _ground(np.array([x, y])) + h - 0.5 * h * rr / (r * r)
        z = np.where(rr < r * r, np.maximum(z, dome + rng.normal(0, 0.3, n)), z)
    xyz = np.column_stack([xy, z + rng.normal(0, 0.03, n)])
    return SnakeScene(image, cam, xyz, truth, list(roofs))
