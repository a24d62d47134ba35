"""Terrain-line filter (Marcato & Dal Poz §2.1): remove image lines that lie on the ground
away from the building.

Every LiDAR point projected into the image lends its height and its
registration error to the pixels around it (nearest-neighbour
interpolation, as in the seed).  A candidate line is sampled every pixel;
its mean height is compared with the building's, and its mean distance to
the building with the mean registration error where it lies.  A line is a
terrain line, and is removed, when

* its height is below the building's lowest roof edge by more than
  ``height_tolerance`` (the seed compares with the building's mean height;
  the lowest outline vertex keeps the eaves of steep roofs from being taken
  for ground), and
* its mean distance to the projected building exceeds its mean registration
  error (lines near the roof may be its displaced edge and are kept -- the
  seed's stated limitation).

A line's height is the larger of the median heights sampled on its two
sides, ``side_offset`` px off the line (ours).  The seed samples the line
itself; but a roof edge *is* the height discontinuity, so half of its
nearest points are ground, its mean height looks terrain-like, and the
distance test alone decides -- and removes true edges whenever the LiDAR
outline is off by more than one registration error.  A terrain line has
ground on both sides; a roof edge has the roof on one.

Pixel coordinates are ``(col, row)``, centres at integers.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["PixelHeights", "sample_segments", "terrain_lines"]

log = logging.getLogger(__name__)


class PixelHeights:
    """Height and registration error at any image position, from projected LiDAR points.

    Parameters
    ----------
    camera : FrameCamera or OrthoCamera
    points_xyz : ndarray of shape (P, 3)
        LiDAR points (all classes: ground points are what identifies terrain lines).
    bounds : (col0, row0, col1, row1), optional
        Keep only points projecting inside this pixel box (saves the error
        propagation for points far from any window).
    sigma_xy, sigma_z : float, default 0.48 and 0.15
        LiDAR precision (m, Marcato & Dal Poz).
    """

    def __init__(self, camera, points_xyz, bounds=None, *, sigma_xy: float = 0.48, sigma_z: float = 0.15):
        xyz = np.asarray(points_xyz, float).reshape(-1, 3)
        xyz = xyz[np.isfinite(xyz).all(axis=1)]
        cr = camera.project(xyz) if len(xyz) else np.zeros((0, 2))
        keep = np.isfinite(cr).all(axis=1)
        if bounds is not None:
            c0, r0, c1, r1 = bounds
            keep &= (cr[:, 0] >= c0) & (cr[:, 0] <= c1) & (cr[:, 1] >= r0) & (cr[:, 1] <= r1)
        self.cr = cr[keep]
        self.z = xyz[keep, 2]
        self.e = (
            np.asarray(camera.registration_error(xyz[keep], sigma_xy, sigma_z), float)
            if keep.any()
            else np.zeros(0)
        )
        self.tree = cKDTree(self.cr) if len(self.cr) else None
        #: median distance (px) between neighbouring projected points
        self.spacing = float(np.median(self.tree.query(self.cr, k=2)[0][:, 1])) if len(self.cr) > 1 else 0.0

    def __len__(self) -> int:
        return len(self.cr)

    def sample(self, cr) -> tuple[np.ndarray, np.ndarray]:
        """Nearest-neighbour height (N,) and registration error (N,) at pixels (N, 2); NaN without points."""
        cr = np.atleast_2d(np.asarray(cr, float))
        if self.tree is None:
            nan = np.full(len(cr), np.nan)
            return nan, nan.copy()
        _, idx = self.tree.query(cr)
        return self.z[idx], self.e[idx]


def sample_segments(segments, step: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` px along segments (K, 2, 2): samples (S, 2) and owner index (S,)."""
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    if not len(seg):
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    length = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
    n = np.maximum(np.ceil(length / step).astype(np.int64) + 1, 2)
    owner = np.repeat(np.arange(len(seg)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    t = (np.arange(owner.size) - first) / (n[owner] - 1)
    pts = seg[owner, 0] + t[:, None] * (seg[owner, 1] - seg[owner, 0])
    return pts, owner


def terrain_lines(
    segments,
    heights: PixelHeights,
    building_cr,
    building_z: float,
    height_tolerance: float = 1.0,
    *,
    step: float = 1.0,
    side_offset: float | None = None,
) -> np.ndarray:
    """Mask (K,) of terrain lines among segments (K, 2, 2).

    Parameters
    ----------
    segments : ndarray of shape (K, 2, 2)
        Candidate lines (col, row).
    heights : PixelHeights
        Projected LiDAR points.
    building_cr : ndarray of shape (B, 2)
        The building in the image: its projected points, or samples along its
        projected outline and ridges.
    building_z : float
        Height of the building's lowest roof edge (CRS units).
    height_tolerance : float, default 1.0
        Metres below ``building_z`` a line must lie to be terrain-compatible.
    step : float, default 1.0
        Sampling step along the lines (px).
    side_offset : float or None
        Distance (px) of the height samples on each side of a line; ``None``:
        ``max(2, s)`` with ``s`` the median spacing of the projected points,
        so the two sides see different points.

    Returns
    -------
    ndarray of shape (K,) of bool
        True for lines to remove.  With no LiDAR points nothing is removed.
    """
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    out = np.zeros(len(seg), bool)
    bld = np.atleast_2d(np.asarray(building_cr, float))
    if not len(seg) or not len(heights) or not len(bld):
        return out
    if side_offset is None:
        side_offset = max(2.0, heights.spacing)
    pts, owner = sample_segments(seg, step)
    d = seg[:, 1] - seg[:, 0]
    n = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    side = side_offset * n[owner]
    z_a, e = heights.sample(pts + side)
    z_b, _ = heights.sample(pts - side)
    dist, _ = cKDTree(bld).query(pts)
    count = np.bincount(owner, minlength=len(seg))
    mean = lambda v: np.bincount(owner, weights=v, minlength=len(seg)) / count  # noqa: E731
    # medians: near a roof edge some nearest points of the roof side are ground
    # points across the edge (sparse clouds), which pull a mean below the eaves
    order = np.argsort(owner, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(count)])
    med = lambda v: np.array([np.median(v[order[a:b]]) for a, b in zip(bounds[:-1], bounds[1:])])  # noqa: E731
    low = np.maximum(med(z_a), med(z_b)) < building_z - height_tolerance
    far = mean(dist) > mean(e)
    out = low & far
    if out.any():
        log.debug("terrain filter removed %d of %d lines", int(out.sum()), len(seg))
    return out
