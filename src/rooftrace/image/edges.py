"""Canny step edges with sub-pixel positions, and linking of edge or line pixels into chains.

Arrays are indexed ``[row, col]``; points are returned as ``(col, row)``
with pixel centres at integers (the camera convention).  Gradients are
Gaussian derivatives: ``gx`` along columns (x right), ``gy`` along rows
(y down).

References
----------
.. [1] Canny, J. (1986). A computational approach to edge detection. IEEE
   TPAMI 8(6), 679-698. :doi:`10.1109/TPAMI.1986.4767851`
.. [2] Immerkær, J. (1996). Fast noise variance estimation. Computer Vision
   and Image Understanding 64(2), 300-302. :doi:`10.1006/cviu.1996.0060`
"""

from __future__ import annotations

import logging

import numpy as np
from numba import njit
from scipy import ndimage as ndi

__all__ = ["noise_sigma", "gaussian_gradient", "canny_edges", "link_chains"]

log = logging.getLogger(__name__)

_SQRT_2PI = np.sqrt(2 * np.pi)
_LAPLACE_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float)


def noise_sigma(image: np.ndarray) -> float:
    """Standard deviation of additive white noise, robust to edges.

    Immerkær's mask (a difference of two Laplacians) cancels image structure
    up to second order; its response to white noise of std ``s`` has std
    ``6 s``.  The median absolute response (x 1.4826) keeps the estimate
    from being inflated by the few pixels on edges.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> round(noise_sigma(0.5 + 0.02 * rng.standard_normal((200, 200))), 2)
    0.02
    """
    img = np.asarray(image, float)
    if img.ndim != 2 or min(img.shape) < 3:
        return 0.0
    resp = ndi.convolve(img, _LAPLACE_MASK, mode="reflect")[1:-1, 1:-1]
    return float(1.4826 * np.median(np.abs(resp)) / 6.0)


def gaussian_gradient(image: np.ndarray, sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian derivatives ``(gx, gy)`` of shape (H, W): d/dcol and d/drow."""
    img = np.asarray(image, float)
    gx = ndi.gaussian_filter(img, sigma, order=(0, 1), mode="nearest")
    gy = ndi.gaussian_filter(img, sigma, order=(1, 0), mode="nearest")
    return gx, gy


def _colour_gradient(img: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Di Zenzo's colour gradient of (H, W, C): direction and magnitude of the
    largest eigenvalue of the channel-averaged structure tensor.

    Averaging (not summing) over channels makes a grey step of contrast c
    in every channel give the magnitude of a grey image's step c, so the
    thresholds mean the same; an edge in one channel only (roof and ground
    of equal brightness but different colour) is still found.
    """
    jxx = jyy = jxy = 0.0
    for k in range(img.shape[2]):
        gx, gy = gaussian_gradient(img[..., k], sigma)
        jxx = jxx + gx * gx
        jyy = jyy + gy * gy
        jxy = jxy + gx * gy
    c = img.shape[2]
    jxx, jyy, jxy = jxx / c, jyy / c, jxy / c
    lam = 0.5 * (jxx + jyy + np.sqrt((jxx - jyy) ** 2 + 4 * jxy * jxy))
    theta = 0.5 * np.arctan2(2 * jxy, jxx - jyy)
    mag = np.sqrt(np.maximum(lam, 0.0))
    # the direction's sign is arbitrary: non-maximum suppression looks both ways
    return mag * np.cos(theta), mag * np.sin(theta), mag


def hysteresis(candidates: np.ndarray, strength: np.ndarray, low: float, high: float) -> np.ndarray:
    """Canny's hysteresis: the candidate pixels above ``low`` connected (8-neighbours) to one above ``high``."""
    weak = candidates & (strength >= low)
    labels, n = ndi.label(weak, structure=np.ones((3, 3), bool))
    if n == 0:
        return weak
    strong = np.zeros(n + 1, bool)
    strong[np.unique(labels[weak & (strength >= high)])] = True
    strong[0] = False
    return strong[labels]


def canny_edges(
    image: np.ndarray,
    sigma: float = 1.0,
    low: float | None = None,
    high: float | None = None,
    *,
    min_contrast: float = 0.05,
    mask: np.ndarray | None = None,
    noise: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Canny edge pixels and their sub-pixel positions.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, C)
        Grey or colour values, float (e.g. [0, 1]).  Colour uses Di Zenzo's
        gradient (channel-averaged structure tensor).
    sigma : float, default 1.0
        Gaussian scale of the derivative filters (px).
    low, high : float or None
        Hysteresis thresholds on the gradient magnitude (grey / px).  ``None``
        derives them: ``high = max(min_contrast / (sqrt(2 pi) sigma), 4 s_g)``
        with ``s_g = noise / (sigma^2 sqrt(8 pi))`` the std of one gradient
        component under white noise, and ``low = high / 2``.
    min_contrast : float, default 0.05
        Weakest step (grey levels) that may seed an edge when thresholds are derived.
    mask : ndarray of shape (H, W) of bool, optional
        Only pixels inside are reported (filtering uses the whole array, so
        the mask border does not create edges).
    noise : float, optional
        Noise std (grey); ``None`` estimates it with :func:`noise_sigma`.

    Returns
    -------
    edges : ndarray of shape (H, W) of bool
        Thin edge pixels after non-maximum suppression and hysteresis.
    points : ndarray of shape (H, W, 2)
        Sub-pixel (col, row) of each edge pixel (NaN elsewhere): the vertex
        of the parabola through the gradient magnitude at -1, 0, +1 px along
        the gradient direction.

    Examples
    --------
    >>> img = np.zeros((20, 20)); img[:, 10:] = 1.0   # step between columns 9 and 10
    >>> edges, pts = canny_edges(img)
    >>> float(np.nanmean(pts[edges][:, 0]).round(2))
    9.5
    """
    img = np.asarray(image, float)
    if img.ndim not in (2, 3):
        raise ValueError(f"image must be 2-D (H, W) or colour (H, W, C), got shape {img.shape}")
    if sigma <= 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    if img.ndim == 2:
        gx, gy = gaussian_gradient(img, sigma)
        mag = np.hypot(gx, gy)
    else:
        gx, gy, mag = _colour_gradient(img, sigma)
    if high is None or low is None:
        if noise is not None:
            s = noise
        elif img.ndim == 2:
            s = noise_sigma(img)
        else:  # RMS over channels, as the colour gradient
            s = float(np.sqrt(np.mean([noise_sigma(img[..., k]) ** 2 for k in range(img.shape[2])])))
        s_g = s / (sigma**2 * np.sqrt(8 * np.pi))
        h = max(min_contrast / (_SQRT_2PI * sigma), 4.0 * s_g)
        high = h if high is None else high
        low = 0.5 * high if low is None else low
    if low > high:
        raise ValueError(f"low threshold {low} exceeds high threshold {high}")
    shape = img.shape[:2]
    rows, cols = np.nonzero(mag >= low)
    edges = np.zeros(shape, bool)
    points = np.full(shape + (2,), np.nan)
    if len(rows):
        m0 = mag[rows, cols]
        nx, ny = gx[rows, cols] / m0, gy[rows, cols] / m0
        coords_p = np.array([rows + ny, cols + nx])
        coords_m = np.array([rows - ny, cols - nx])
        mp = ndi.map_coordinates(mag, coords_p, order=1, mode="nearest")
        mm = ndi.map_coordinates(mag, coords_m, order=1, mode="nearest")
        is_max = (m0 >= mp) & (m0 > mm)
        nms = np.zeros(shape, bool)
        nms[rows[is_max], cols[is_max]] = True
        edges = hysteresis(nms, mag, low, high)
        if mask is not None:
            edges &= np.asarray(mask, bool)
        sel = edges[rows, cols]
        denom = mm[sel] - 2 * m0[sel] + mp[sel]
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.where(denom < 0, 0.5 * (mm[sel] - mp[sel]) / denom, 0.0)
        delta = np.clip(delta, -0.5, 0.5)
        points[rows[sel], cols[sel], 0] = cols[sel] + delta * nx[sel]
        points[rows[sel], cols[sel], 1] = rows[sel] + delta * ny[sel]
    return edges, points


# neighbour offsets (drow, dcol): the 4-neighbours first so that ties prefer them
_OFFSETS = np.array([[0, 1], [1, 0], [0, -1], [-1, 0], [1, 1], [1, -1], [-1, 1], [-1, -1]], np.int64)


@njit(cache=True)
def _trace(mask, offsets):
    h, w = mask.shape
    deg = np.zeros((h, w), np.int64)
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                for k in range(8):
                    rr, cc = r + offsets[k, 0], c + offsets[k, 1]
                    if 0 <= rr < h and 0 <= cc < w and mask[rr, cc]:
                        deg[r, c] += 1
    visited = np.zeros((h, w), np.bool_)
    n_total = 0
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                n_total += 1
    order = np.empty((n_total, 2), np.int64)
    starts = np.empty(n_total + 1, np.int64)
    n_pts = 0
    n_chains = 0
    # pass 0 starts at chain ends (one neighbour) or isolated pixels; pass 1 picks up loops
    for p in range(2):
        for r0 in range(h):
            for c0 in range(w):
                if not mask[r0, c0] or visited[r0, c0]:
                    continue
                if p == 0 and deg[r0, c0] > 1:
                    continue
                starts[n_chains] = n_pts
                n_chains += 1
                r, c = r0, c0
                dr, dc = 0.0, 0.0
                while True:
                    visited[r, c] = True
                    order[n_pts, 0] = r
                    order[n_pts, 1] = c
                    n_pts += 1
                    best = -1
                    best_score = -1e9
                    for k in range(8):
                        rr, cc = r + offsets[k, 0], c + offsets[k, 1]
                        if 0 <= rr < h and 0 <= cc < w and mask[rr, cc] and not visited[rr, cc]:
                            # keep going straight: score by the turn w.r.t. the last step
                            norm = np.sqrt(offsets[k, 0] ** 2 + offsets[k, 1] ** 2)
                            score = (offsets[k, 0] * dr + offsets[k, 1] * dc) / norm - 0.01 * k
                            if score > best_score:
                                best_score = score
                                best = k
                    if best < 0:
                        break
                    dr = float(offsets[best, 0])
                    dc = float(offsets[best, 1])
                    r += offsets[best, 0]
                    c += offsets[best, 1]
    starts[n_chains] = n_pts
    return order[:n_pts], starts[: n_chains + 1]


def link_chains(mask: np.ndarray, points: np.ndarray | None = None, min_points: int = 2) -> list[np.ndarray]:
    """Link thin edge or line pixels into ordered chains (8-connectivity).

    Chains start at end pixels (one neighbour), so an open curve is traced
    end to end; at a junction the trace goes straight on and the other
    branch becomes its own chain.  Closed curves are traced last.

    Parameters
    ----------
    mask : ndarray of shape (H, W) of bool
        Thin pixels (Canny edges or Steger line pixels).
    points : ndarray of shape (H, W, 2), optional
        Sub-pixel (col, row) per pixel; pixel centres are used where absent.
    min_points : int, default 2
        Shorter chains are dropped.

    Returns
    -------
    list of ndarray of shape (n, 2)
        (col, row) per chain, in order.  The result is deterministic.

    Examples
    --------
    >>> m = np.zeros((5, 5), bool); m[2, 1:4] = True
    >>> link_chains(m)[0].tolist()
    [[1.0, 2.0], [2.0, 2.0], [3.0, 2.0]]
    """
    m = np.ascontiguousarray(np.asarray(mask, bool))
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {m.shape}")
    if not m.any():
        return []
    order, starts = _trace(m, _OFFSETS)
    if points is None:
        xy = order[:, ::-1].astype(float)
    else:
        xy = points[order[:, 0], order[:, 1]]
        bad = ~np.isfinite(xy).all(axis=1)
        xy[bad] = order[bad, ::-1]
    chains = [xy[starts[i] : starts[i + 1]] for i in range(len(starts) - 1)]
    return [ch for ch in chains if len(ch) >= min_points]
