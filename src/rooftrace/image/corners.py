"""Harris corners with sub-pixel positions (the corner term U5 of Marcato & Dal Poz's MRF energy).

Response ``R = det(A) - k trace(A)^2`` of the structure tensor ``A`` (Gaussian
derivatives at ``sigma_d``, products smoothed at ``sigma_i``).  Corners are
local maxima of ``R`` at least ``min_distance`` px apart above
``max(threshold_abs, threshold_rel * max R)``.  The maximum of ``R`` sits
1.5-2 px inside a blurred right-angled corner; the default sub-pixel step
moves each corner to the point whose vectors to its neighbours are
orthogonal to the image gradient there (Förstner's operator, OpenCV's
``cornerSubPix``), which is unbiased for straight-sided corners (0.1-0.2 px
on synthetic roofs).  ``subpixel='quadratic'`` takes the vertex of the
quadratic through the 3 x 3 response instead.  Points are ``(col, row)``,
pixel centres at integers.

References
----------
.. [1] Harris, C., Stephens, M. (1988). A combined corner and edge detector.
   Proc. 4th Alvey Vision Conference, 147-151.
.. [2] Förstner, W., Gülch, E. (1987). A fast operator for detection and
   precise location of distinct points, corners and centres of circular
   features. ISPRS Intercommission Workshop, Interlaken, 281-305.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from rooftrace.image.projection import window_slices

__all__ = ["HarrisOptions", "harris_response", "harris_corners"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HarrisOptions:
    """Options of the Harris corner detector (section ``[harris]``).

    Attributes
    ----------
    sigma_d : float, default 1.0
        Derivative scale (px).
    sigma_i : float, default 2.0
        Integration scale (px).
    k : float, default 0.04
        Harris' sensitivity constant (Harris & Stephens 1988).
    min_distance : int, default 3
        Minimum distance between corners (px).
    threshold_rel : float, default 0.01
        Fraction of the largest response in the searched area.
    threshold_abs : float, default 1e-6
        Absolute floor on the response (grey^4 / px^4): keeps flat or noise-only areas cornerless.
    subpixel : {'gradient', 'quadratic'}, default 'gradient'
        Sub-pixel refinement (see the module notes).
    """

    section = "harris"

    sigma_d: float = 1.0
    sigma_i: float = 2.0
    k: float = 0.04
    min_distance: int = 3
    threshold_rel: float = 0.01
    threshold_abs: float = 1e-6
    subpixel: str = "gradient"

    def __post_init__(self):
        if self.subpixel not in ("gradient", "quadratic"):
            raise ValueError(f"harris.subpixel must be 'gradient' or 'quadratic', got {self.subpixel!r}")
        for name in ("sigma_d", "sigma_i"):
            if getattr(self, name) <= 0:
                raise ValueError(f"harris.{name} must be positive, got {getattr(self, name)}")
        if not 0 < self.k < 0.25:
            raise ValueError(f"harris.k must be in (0, 0.25), got {self.k}")
        if self.min_distance < 1:
            raise ValueError(f"harris.min_distance must be >= 1, got {self.min_distance}")


def harris_response(image: np.ndarray, sigma_d: float = 1.0, sigma_i: float = 2.0, k: float = 0.04) -> np.ndarray:
    """Harris response (H, W) of a grey image (H, W)."""
    img = np.asarray(image, float)
    gx = ndi.gaussian_filter(img, sigma_d, order=(0, 1), mode="nearest")
    gy = ndi.gaussian_filter(img, sigma_d, order=(1, 0), mode="nearest")
    axx = ndi.gaussian_filter(gx * gx, sigma_i, mode="nearest")
    ayy = ndi.gaussian_filter(gy * gy, sigma_i, mode="nearest")
    axy = ndi.gaussian_filter(gx * gy, sigma_i, mode="nearest")
    return axx * ayy - axy * axy - k * (axx + ayy) ** 2


def _region(mask_or_window, shape, pad):
    """Slices of the searched box and the mask inside it."""
    import cv2  # here, not at the top: the run's config reads HarrisOptions and a LiDAR-only run needs no OpenCV
    if mask_or_window is None:
        return (slice(0, shape[0]), slice(0, shape[1])), None
    arr = np.asarray(mask_or_window)
    if arr.shape == tuple(shape) and arr.dtype == bool:
        rows, cols = np.nonzero(arr)
        if not len(rows):
            return None, None
        sl = (slice(max(rows.min() - pad, 0), min(rows.max() + pad + 1, shape[0])),
              slice(max(cols.min() - pad, 0), min(cols.max() + pad + 1, shape[1])))
        return sl, arr[sl]
    poly = np.asarray(arr, float).reshape(-1, 4, 2)
    lo, hi = poly.reshape(-1, 2).min(0), poly.reshape(-1, 2).max(0)
    sl = window_slices(np.array([lo, hi]), shape, pad)
    if sl is None:
        return None, None
    sub = np.zeros((sl[0].stop - sl[0].start, sl[1].stop - sl[1].start), np.uint8)
    shifted = poly - [sl[1].start, sl[0].start]
    # fillPoly takes integer vertices; 4 fractional bits keep the rectangles exact to 1/16 px
    cv2.fillPoly(sub, [np.round(p * 16).astype(np.int32) for p in shifted], 1, lineType=cv2.LINE_8, shift=4)
    return sl, sub.astype(bool)


def harris_corners(image: np.ndarray, mask_or_window=None, *, options: HarrisOptions | None = None) -> np.ndarray:
    """Sub-pixel Harris corners.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, C)
        Grey values, float (e.g. [0, 1]); a colour image is averaged to grey.
    mask_or_window : ndarray, optional
        ``None`` searches the whole image; a bool mask (H, W) searches where
        it is True; a window (4, 2) or windows (M, 4, 2) of corner pixels
        (col, row) search inside those rectangles.  The response is computed
        on the bounding box only, padded so that the filters see context.
    options : HarrisOptions, optional

    Returns
    -------
    ndarray of shape (C, 2) float64
        Corners (col, row), strongest first.

    Examples
    --------
    >>> img = np.zeros((40, 40)); img[10:30, 10:30] = 1.0   # square, corners at 9.5 / 29.5
    >>> c = harris_corners(img)
    >>> len(c)
    4
    """
    opt = options or HarrisOptions()
    img = np.asarray(image, float)
    if img.ndim == 3:  # colour (H, W, C): corners of the grey mean
        img = img.mean(axis=2)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D (H, W) or colour (H, W, C), got shape {img.shape}")
    import cv2  # see _region

    pad = int(np.ceil(3 * (opt.sigma_d + opt.sigma_i))) + 1
    sl, mask = _region(mask_or_window, img.shape, pad)
    if sl is None:
        return np.zeros((0, 2))
    resp = harris_response(img[sl], opt.sigma_d, opt.sigma_i, opt.k)
    size = 2 * opt.min_distance + 1
    peak = resp == ndi.maximum_filter(resp, size=size, mode="nearest")
    thr = max(opt.threshold_abs, opt.threshold_rel * float(resp.max()))
    peak &= resp > thr
    # peaks on the crop border may be cut-off maxima of structure outside it
    peak[[0, -1], :] = False
    peak[:, [0, -1]] = False
    if mask is not None:
        peak &= mask
    r, c = np.nonzero(peak)
    if not len(r):
        return np.zeros((0, 2))
    # quadratic fit on the 3 x 3 neighbourhood: Newton step -H^-1 g
    f = lambda dr, dc: resp[r + dr, c + dc]  # noqa: E731
    gx = 0.5 * (f(0, 1) - f(0, -1))
    gy = 0.5 * (f(1, 0) - f(-1, 0))
    hxx = f(0, 1) - 2 * f(0, 0) + f(0, -1)
    hyy = f(1, 0) - 2 * f(0, 0) + f(-1, 0)
    hxy = 0.25 * (f(1, 1) - f(1, -1) - f(-1, 1) + f(-1, -1))
    det = hxx * hyy - hxy * hxy
    ok = (det > 0) & (hxx < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dx = np.where(ok, -(hyy * gx - hxy * gy) / det, 0.0)
        dy = np.where(ok, -(hxx * gy - hxy * gx) / det, 0.0)
    dx, dy = np.clip(dx, -0.5, 0.5), np.clip(dy, -0.5, 0.5)
    local = np.column_stack([c + dx, r + dy])
    if opt.subpixel == "gradient":
        half = int(np.ceil(2 * opt.sigma_i)) + 1
        crop = np.ascontiguousarray(img[sl], dtype=np.float32)
        refined = cv2.cornerSubPix(crop, local.astype(np.float32).reshape(-1, 1, 2).copy(), (half, half), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3)).reshape(-1, 2)
        # a corner that wanders off its search window had no clean corner to lock onto
        moved = np.abs(refined - local).max(axis=1) <= half
        local = np.where(moved[:, None], refined.astype(float), local)
    pts = local + [sl[1].start, sl[0].start]
    order = np.argsort(-resp[r, c], kind="stable")
    return pts[order]
