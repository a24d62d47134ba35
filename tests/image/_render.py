"""Synthetic images with known geometry for the image-stage tests.

Polygons are rendered by 8x supersampling and area averaging, so a pixel's
value is its covered fraction (pixel (c, r) covers [c - 0.5, c + 0.5]).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage as ndi

from rooftrace.image.camera import FrameCamera

SS = 8  # supersampling factor


def render(shape, layers, *, blur=1.0, noise=0.0, seed=0, background=0.3):
    """Paint polygons (list of ((n, 2) col,row vertices, grey)) in order; blur; add noise."""
    h, w = shape
    hi = np.full((h * SS, w * SS), background, np.float32)
    for poly, grey in layers:
        p = (np.asarray(poly, float) + 0.5) * SS - 0.5
        cv2.fillPoly(hi, [np.round(p * 16).astype(np.int32)], float(grey), lineType=cv2.LINE_8, shift=4)
    img = cv2.resize(hi, (w, h), interpolation=cv2.INTER_AREA).astype(float)
    if blur:
        img = ndi.gaussian_filter(img, blur, mode="nearest")
    if noise:
        img = img + np.random.default_rng(seed).normal(0, noise, img.shape)
    return img


def bar_polygon(p0, p1, width):
    """Rectangle (4, 2) of full ``width`` around the segment p0-p1 (col, row)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    u = (p1 - p0) / np.hypot(*(p1 - p0))
    n = np.array([-u[1], u[0]]) * width / 2
    return np.array([p0 + n, p1 + n, p1 - n, p0 - n])


@dataclass
class GableScene:
    camera: FrameCamera
    image: np.ndarray
    lines3d: np.ndarray  # (5, 2, 3): 4 outline sides then the ridge
    kinds: list
    truth: np.ndarray  # (5, 2, 2) projected truth
    building_xyz: np.ndarray
    points_xyz: np.ndarray


def gable_scene(*, shift=(0.25, -0.2), angle=20.0, noise=0.01, seed=3, ridge_cap=True, extra=(), background=0.3,
                roof=(0.62, 0.78, 0.95)):
    """A gable-roofed house seen by a nadir camera at 0.1 m GSD (roof at z = 8..10 m).

    The 3D lines handed to the extractor are the truth shifted by ``shift``
    metres (a LiDAR outline error), so the candidates must correct them.
    """
    cam = FrameCamera((320, 320), 0.01, 100.0, np.array([500.0, 300.0, 1009.0, 0, 0, 0]))
    a = np.radians(angle)
    u, v = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    c = np.array([500.0, 300.0])
    L, W = 8.0, 5.0  # half-length / half-width, m
    corners = np.array([c - L * u - W * v, c + L * u - W * v, c + L * u + W * v, c - L * u + W * v])
    outline = np.column_stack([corners, np.full(4, 8.0)])
    ridge = np.array([[*(c - L * u), 10.0], [*(c + L * u), 10.0]])
    sides = np.array([[outline[i], outline[(i + 1) % 4]] for i in range(4)])
    truth3d = np.concatenate([sides, ridge[None]])
    pr = lambda xyz: cam.project(np.asarray(xyz, float))  # noqa: E731
    half_a = pr([outline[0], outline[1], ridge[1], ridge[0]])
    half_b = pr([ridge[0], ridge[1], outline[2], outline[3]])
    layers = [*extra, (half_a, roof[0]), (half_b, roof[1])]
    if ridge_cap:
        r2 = pr(ridge)
        layers.append((bar_polygon(r2[0], r2[1], 3.0), roof[2]))
    img = render((320, 320), layers, noise=noise, seed=seed, background=background)
    truth = cam.project(truth3d.reshape(-1, 3)).reshape(-1, 2, 2)
    lines3d = truth3d + np.array([shift[0], shift[1], 0.0])
    rng = np.random.default_rng(seed)
    # LiDAR: 0.3 m grid; roof points inside the outline, ground (z = 0) elsewhere
    g = np.mgrid[480:520:0.3, 280:320:0.3].reshape(2, -1).T + rng.normal(0, 0.02, (1, 2))
    loc = (g - c) @ np.column_stack([u, v])
    on_roof = (np.abs(loc[:, 0]) <= L) & (np.abs(loc[:, 1]) <= W)
    z = np.where(on_roof, 10.0 - 2.0 * np.abs(loc[:, 1]) / W, 0.0)
    pts = np.column_stack([g, z])
    return GableScene(cam, img, lines3d, ["outline"] * 4 + ["ridge"], truth, pts[on_roof], pts)


def close_to(segments, truth, px=1.0, deg=1.0):
    """True if some segment lies within ``px`` (both truth endpoints' distance to its line,
    within the segment's span allowance) and ``deg`` of the truth segment (2, 2)."""
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    t = np.asarray(truth, float)
    dt = t[1] - t[0]
    at = np.arctan2(dt[1], dt[0])
    for s in seg:
        d = s[1] - s[0]
        ang = np.mod(np.arctan2(d[1], d[0]) - at, np.pi)
        ang = min(ang, np.pi - ang)
        n = np.array([-d[1], d[0]]) / np.hypot(*d)
        # distance of the segment's endpoints to the truth line
        off = np.abs((s - t[0]) @ (np.array([-dt[1], dt[0]]) / np.hypot(*dt)))
        if np.degrees(ang) <= deg and off.max() <= px and np.isfinite(n).all():
            return True
    return False
