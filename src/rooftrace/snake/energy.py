"""Energy terms of the object-space polygon snake, as arrays over candidate sets.

Why our own: snake libraries (``skimage.segmentation.active_contour``) move
image-space points by gradient descent on a smooth curve; the method of seed
004 (Fazan & Dal Poz) moves polygon *vertices in object space*, favours right
angles between adjacent sides and reads the image through the collinearity
equations, and is minimised exactly by dynamic programming.  The DP needs each
term tabulated over every candidate combination it couples, which is what the
functions here return:

* ``side_energy`` (external, pairs): minus the mean image gradient across a
  side, sampled at object-space points (X, Y, Z(X, Y)) projected into the
  image.  Mean, not sum, so a long side is not worth more than a short one
  (a sum would push the polygon outward along any strong edge).
* ``height_energy`` (external, pairs; beyond the paper): minus the mean
  LiDAR height step across a side, inside minus outside, saturating at
  ``step`` m.  Shadows, road markings and the hip and ridge lines of the
  roof itself are strong image edges with no height step; the paper's
  image-only energy locks onto them when the roof contrasts weakly with the
  ground (see docs/snake.md).  Weight 0 gives the paper's energy.
* ``spacing_energy`` (internal, pairs): Williams & Shah's evenness term
  ((|s| - L) / L)^2 with L the current mean side length; scale-free, and
  unlike Amini's |v_i - v_{i-1}|^2 it does not shrink the polygon.
* ``angle_energy`` (internal, triplets): cos^2 of the angle between the two
  sides meeting at a vertex, zero at a right angle (the paper's modification
  for rectilinear roofs).

All terms are dimensionless and of order one, so weights read as relative
importance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["EdgeField", "edge_field", "side_energy", "height_energy", "spacing_energy", "angle_energy"]


@dataclass(frozen=True)
class EdgeField:
    """Normalised image gradient of an image window at one Gaussian scale.

    ``gx``/``gy`` are d/dcolumn and d/drow of the smoothed grey image divided
    by the window's robust maximum gradient magnitude (99.5th percentile), so
    a clear roof edge reads about 1.  ``offset`` is the (column, row) of the
    window's first pixel in the full image.
    """

    gx: np.ndarray
    gy: np.ndarray
    offset: tuple[int, int]
    sigma: float

    def sample(self, cr: np.ndarray) -> np.ndarray:
        """Gradient at pixel positions (..., 2) (column, row), bilinear; 0 outside the window."""
        cr = np.asarray(cr, float)
        coords = np.stack([cr[..., 1].ravel() - self.offset[1], cr[..., 0].ravel() - self.offset[0]])
        coords = np.where(np.isfinite(coords), coords, -1e6)
        gx = ndimage.map_coordinates(self.gx, coords, order=1, mode="constant", cval=0.0)
        gy = ndimage.map_coordinates(self.gy, coords, order=1, mode="constant", cval=0.0)
        return np.stack([gx, gy], axis=-1).reshape(cr.shape)


def edge_field(image: np.ndarray, sigma: float = 1.0, window: tuple[int, int, int, int] | None = None) -> EdgeField:
    """Gaussian-derivative gradient of a grey image, restricted to a window.

    Parameters
    ----------
    image : ndarray of shape (H, W)
        Grey values (any range).
    sigma : float, default 1.0
        Gaussian scale in pixels (> 0).
    window : (col0, row0, col1, row1), optional
        Pixel bounds (inclusive start, exclusive end) of the region needed;
        the whole image when None.  A margin of 4 sigma is added so the
        window's border does not bias the smoothing.

    Returns
    -------
    EdgeField
    """
    image = np.asarray(image, float)
    if image.ndim != 2:
        raise ValueError(f"image must be a (H, W) grey image, got shape {image.shape}")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0, got {sigma}")
    h, w = image.shape
    c0, r0, c1, r1 = (0, 0, w, h) if window is None else window
    m = int(np.ceil(4 * sigma)) + 1
    c0, r0 = max(0, int(c0) - m), max(0, int(r0) - m)
    c1, r1 = min(w, int(c1) + m), min(h, int(r1) + m)
    if c1 - c0 < 2 or r1 - r0 < 2:
        z = np.zeros((2, 2))
        return EdgeField(z, z, (c0, r0), float(sigma))
    crop = image[r0:r1, c0:c1]
    gx = ndimage.gaussian_filter(crop, sigma, order=(0, 1), mode="nearest")
    gy = ndimage.gaussian_filter(crop, sigma, order=(1, 0), mode="nearest")
    scale = float(np.percentile(np.hypot(gx, gy), 99.5))
    scale = scale if scale > 1e-12 else 1.0
    return EdgeField(gx / scale, gy / scale, (c0, r0), float(sigma))


def side_energy(field: EdgeField, project, height, a: np.ndarray, b: np.ndarray, n_samples: int = 16) -> np.ndarray:
    """External energy of every side from a candidate in ``a`` to one in ``b``.

    Parameters
    ----------
    field : EdgeField
    project : callable
        Object (M, 3) -> pixel (M, 2) (column, row), e.g. ``camera.project``
        (the collinearity equations of a frame camera).
    height : callable
        (X, Y) (..., 2) -> Z (...,) in m, the roof surface.
    a, b : ndarray of shape (Ka, 2) and (Kb, 2)
        Candidate positions (X, Y) of the side's start and end vertex (m).
    n_samples : int, default 16
        Samples per side, at the centres of equal parts (ends excluded).

    Returns
    -------
    ndarray of shape (Ka, Kb)
        ``-mean_k |g(p_k) . n|`` with n the unit normal of the projected
        side: in [-1, 0] for edges up to the normalising strength (stronger
        ones count at most 1 per sample); 0 for a degenerate side.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    t = (np.arange(n_samples) + 0.5) / n_samples
    pts = a[:, None, None, :] * (1 - t)[None, None, :, None] + b[None, :, None, :] * t[None, None, :, None]
    xyz = np.concatenate([pts, height(pts)[..., None]], axis=-1)
    cr = project(xyz.reshape(-1, 3)).reshape(pts.shape)
    ends = np.concatenate([a, b])
    ends_cr = project(np.column_stack([ends, height(ends)]))
    d = ends_cr[len(a):][None, :, :] - ends_cr[: len(a)][:, None, :]  # (Ka, Kb, 2)
    length = np.hypot(d[..., 0], d[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = np.stack([-d[..., 1], d[..., 0]], axis=-1) / length[..., None]
    normal = np.where(length[..., None] > 1e-9, normal, 0.0)
    g = field.sample(cr)
    across = np.abs(np.einsum("abkc,abc->abk", g, normal))
    return -np.minimum(across, 1.0).mean(axis=-1)


def height_energy(height, a: np.ndarray, b: np.ndarray, offset: float, step: float = 2.0,
                  n_samples: int = 16, interior: int = 1) -> np.ndarray:
    """Height-step energy of every side from a candidate in ``a`` to one in ``b``.

    Parameters
    ----------
    height : callable
        (X, Y) (..., 2) -> Z (...,) in m: the plain (undilated) TIN.
    a, b : ndarray of shape (Ka, 2) and (Kb, 2)
        Candidate positions (X, Y) (m).
    offset : float
        Distance (m) on either side of the side where heights are compared;
        about 1.5 point spacings, past the TIN's blended band.
    step : float, default 2.0
        Height difference (m) that counts fully; larger ones count 1.
    n_samples : int, default 16
    interior : {1, -1}
        1 when the polygon runs counter-clockwise (interior on the left of
        each side), -1 when clockwise.

    Returns
    -------
    ndarray of shape (Ka, Kb)
        ``-mean_k clip((z_in - z_out) / step, 0, 1)``, in [-1, 0].
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    t = (np.arange(n_samples) + 0.5) / n_samples
    pts = a[:, None, None, :] * (1 - t)[None, None, :, None] + b[None, :, None, :] * t[None, None, :, None]
    d = b[None, :, :] - a[:, None, :]
    length = np.hypot(d[..., 0], d[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        left = interior * np.stack([-d[..., 1], d[..., 0]], axis=-1) / length[..., None]
    left = np.where(length[..., None] > 1e-9, left, 0.0)[:, :, None, :]
    dz = height(pts + offset * left) - height(pts - offset * left)
    return -np.clip(dz / step, 0.0, 1.0).mean(axis=-1)


def spacing_energy(a: np.ndarray, b: np.ndarray, mean_length: float) -> np.ndarray:
    """Evenness term ((|b - a| - L) / L)^2 for every candidate pair, (Ka, Kb).

    ``mean_length`` L (m, > 0) is the mean side length of the current polygon.
    """
    if not mean_length > 0:
        raise ValueError(f"mean_length must be > 0, got {mean_length}")
    d = np.asarray(b, float)[None, :, :] - np.asarray(a, float)[:, None, :]
    return ((np.hypot(d[..., 0], d[..., 1]) - mean_length) / mean_length) ** 2


def angle_energy(prev: np.ndarray, cur: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """Right-angle term cos^2(angle between adjacent sides) for every candidate triplet.

    Parameters
    ----------
    prev, cur, nxt : ndarray of shape (Kp, 2), (Kc, 2), (Kn, 2)
        Candidates of vertices i-1, i, i+1 (m).

    Returns
    -------
    ndarray of shape (Kp, Kc, Kn)
        0 when the sides prev->cur and cur->nxt are perpendicular, 1 when
        they are parallel (straight on or folding back) or degenerate.

    Examples
    --------
    >>> p = np.array([[0.0, 0.0]]); c = np.array([[1.0, 0.0]])
    >>> angle_energy(p, c, np.array([[1.0, 1.0], [2.0, 0.0], [2.0, 1.0]])).round(3)
    array([[[0. , 1. , 0.5]]])
    """
    prev, cur, nxt = (np.asarray(v, float) for v in (prev, cur, nxt))
    u = cur[None, :, None, :] - prev[:, None, None, :]
    w = nxt[None, None, :, :] - cur[None, :, None, :]
    dot = (u * w).sum(axis=-1)
    nn = (u * u).sum(axis=-1) * (w * w).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos2 = dot * dot / nn
    return np.where(nn > 1e-18, cos2, 1.0)
