"""Projection of 3D roof lines into the image, their registration error, and
the search window around each projected line.

Pixel coordinates are ``(col, row)`` with pixel centres at integers.  A
window is a rectangle whose symmetry axis is the projected line (Marcato & Dal Poz
§2.1, Marcato & Dal Poz 2011 §3)::

    half_width = k * e + margin          (across the line)
    extension  = k * e                   (beyond each end, along the line)

with ``e`` the registration error of the line (px) -- the larger of its two
endpoints' ``sqrt(sigma_C^2 + sigma_L^2)`` -- ``k`` a coverage factor (3:
the true line lies inside with ~99 % probability for Gaussian errors) and
``margin`` a few pixels for the detectors' own support.  The seeds size the
window "from the length and the registration error" without a formula; this
one is ours.
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = ["project_lines", "line_windows", "window_frame", "in_window", "window_slices", "clip_to_window"]

log = logging.getLogger(__name__)


def project_lines(
    camera, lines3d, *, sigma_xy: float = 0.48, sigma_z: float = 0.15
) -> tuple[np.ndarray, np.ndarray]:
    """Project 3D segments and propagate their registration error.

    Parameters
    ----------
    camera : FrameCamera or OrthoCamera
    lines3d : ndarray of shape (M, 2, 3)
        Object-space segments (CRS units, metres).
    sigma_xy, sigma_z : float, default 0.48 and 0.15
        Planimetric and altimetric precision of the LiDAR-derived vertices
        (m, Marcato & Dal Poz).

    Returns
    -------
    reference : ndarray of shape (M, 2, 2)
        Projected endpoints (col, row).
    error : ndarray of shape (M,)
        Registration error per line (px): the larger of its two endpoints'
        ``sqrt(sigma_C^2 + sigma_L^2)``, propagated from the exterior
        orientation covariance and the point precision (Marcato & Dal Poz eq. 1).

    Examples
    --------
    >>> from rooftrace.image.camera import FrameCamera
    >>> cam = FrameCamera((401, 401), 0.01, 100.0, np.array([0, 0, 1000.0, 0, 0, 0]))
    >>> ref, err = project_lines(cam, np.array([[[0, 0, 0], [10, 0, 0]]]))
    >>> ref.tolist()
    [[[200.0, 200.0], [300.0, 200.0]]]
    """
    lines = np.asarray(lines3d, float)
    if lines.ndim != 3 or lines.shape[1:] != (2, 3):
        raise ValueError(f"lines3d must have shape (M, 2, 3), got {lines.shape}")
    if not np.isfinite(lines).all():
        raise ValueError("lines3d holds NaN or infinite coordinates")
    flat = lines.reshape(-1, 3)
    reference = camera.project(flat).reshape(-1, 2, 2)
    err = np.asarray(camera.registration_error(flat, sigma_xy, sigma_z), float).reshape(-1, 2)
    return reference, err.max(axis=1) if len(err) else np.zeros(0)


def window_frame(reference: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Start point, unit direction, unit normal and length of one projected line (2, 2)."""
    p0, p1 = np.asarray(reference, float)
    d = p1 - p0
    length = float(np.hypot(*d))
    u = d / length if length > 1e-12 else np.array([1.0, 0.0])
    return p0, u, np.array([-u[1], u[0]]), length


def line_windows(reference, error, k: float = 3.0, margin: float = 3.0) -> np.ndarray:
    """Corner pixels (M, 4, 2) of the window rectangle around each projected line.

    Corners run ``start - ext + hw n``, ``end + ext + hw n``, ``end + ext - hw n``,
    ``start - ext - hw n`` (see the module notes for ``hw`` and ``ext``).

    Parameters
    ----------
    reference : ndarray of shape (M, 2, 2)
    error : ndarray of shape (M,)
        Registration error (px).
    k : float, default 3.0
        Coverage factor on the registration error.
    margin : float, default 3.0
        Extra half-width (px).
    """
    ref = np.asarray(reference, float).reshape(-1, 2, 2)
    err = np.broadcast_to(np.asarray(error, float), (len(ref),))
    if k < 0 or margin < 0:
        raise ValueError(f"k and margin must be non-negative, got {k} and {margin}")
    out = np.empty((len(ref), 4, 2))
    for i, (r, e) in enumerate(zip(ref, err)):
        p0, u, n, length = window_frame(r)
        hw, ext = k * e + margin, k * e
        a, b = p0 - ext * u, p0 + (length + ext) * u
        out[i] = [a + hw * n, b + hw * n, b - hw * n, a - hw * n]
    return out


def in_window(points, window) -> np.ndarray:
    """Mask (N,) of points (N, 2) (col, row) inside a window rectangle (4, 2)."""
    pts = np.atleast_2d(np.asarray(points, float))
    w = np.asarray(window, float)
    e1, e2 = w[1] - w[0], w[3] - w[0]
    q = pts - w[0]
    s = q @ e1 / max(e1 @ e1, 1e-12)
    t = q @ e2 / max(e2 @ e2, 1e-12)
    return (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)


def window_slices(window, shape: tuple[int, int], pad: int = 0) -> tuple[slice, slice] | None:
    """Row and column slices of the window's bounding box grown by ``pad`` px, clipped to ``shape`` (H, W).

    ``None`` when the window does not meet the image.
    """
    w = np.asarray(window, float)
    h_img, w_img = shape
    c0 = max(int(np.floor(w[:, 0].min())) - pad, 0)
    c1 = min(int(np.ceil(w[:, 0].max())) + pad + 1, w_img)
    r0 = max(int(np.floor(w[:, 1].min())) - pad, 0)
    r1 = min(int(np.ceil(w[:, 1].max())) + pad + 1, h_img)
    if c0 >= c1 or r0 >= r1:
        return None
    return slice(r0, r1), slice(c0, c1)


def clip_to_window(segments, window) -> tuple[np.ndarray, np.ndarray]:
    """Clip segments (K, 2, 2) to a window rectangle (4, 2) (Liang-Barsky in the window's frame).

    Returns the clipped segments (K', 2, 2) and the mask (K,) of those that
    keep a part inside.
    """
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    w = np.asarray(window, float)
    e1, e2 = w[1] - w[0], w[3] - w[0]
    m = np.linalg.inv(np.column_stack([e1, e2]))  # pixel offset -> unit square coordinates
    a = (seg[:, 0] - w[0]) @ m.T
    d = (seg[:, 1] - seg[:, 0]) @ m.T
    t0, t1 = np.zeros(len(seg)), np.ones(len(seg))
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(2):
            for p, q in ((-d[:, k], a[:, k]), (d[:, k], 1.0 - a[:, k])):
                r = q / p
                t0 = np.where(p < 0, np.maximum(t0, r), t0)
                t1 = np.where(p > 0, np.minimum(t1, r), t1)
                t1 = np.where((p == 0) & (q < 0), -1.0, t1)  # parallel and outside
    keep = t1 > t0
    out = seg[:, :1] + np.stack([t0, t1], axis=1)[..., None] * (seg[:, 1:] - seg[:, :1])
    return out[keep], keep
