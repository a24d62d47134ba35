"""Steger's curvilinear line detector: Gaussian derivatives, Hessian eigen-analysis,
sub-pixel line centres, hysteresis.

For each pixel the Hessian of the Gaussian-smoothed image gives the line's
normal ``n`` (the eigenvector of the eigenvalue ``lambda`` of largest
magnitude).  Along ``n`` the second-order Taylor polynomial has its extremum
at ``t = -(r_x n_x + r_y n_y) / lambda``; the pixel holds a line point when
that extremum falls inside it (``|t n_x|, |t n_y| <= 0.5``).  The line's
strength is ``-lambda`` for bright lines and ``lambda`` for dark ones.

Points are ``(col, row)`` with pixel centres at integers; ``x`` is the
column axis, ``y`` the row axis (down).

References
----------
.. [1] Steger, C. (1998). An unbiased detector of curvilinear structures.
   IEEE TPAMI 20(2), 113-125. :doi:`10.1109/34.659930`
.. [2] Marcato, V. J., Dal Poz, A. P. (2011), SBSR, eq. 5-12.
"""

from __future__ import annotations

import logging

import numpy as np
from numba import njit
from scipy import ndimage as ndi

from rooftrace.image.edges import hysteresis, noise_sigma

__all__ = ["hessian_line_points", "steger_lines", "steger_sigma", "line_position_bias", "line_response"]

log = logging.getLogger(__name__)

_POLARITIES = ("bright", "dark", "both")
_CELL = 0.6  # half-size of the cell a line point may sit in (px)


def steger_sigma(line_width: float) -> float:
    """Smallest Gaussian scale that keeps a bar of full width ``line_width`` px a single line.

    Steger's condition ``sigma >= w / sqrt(3)`` for half-width ``w``
    (Marcato & Dal Poz 2011, after eq. 10), floored at 1 px so that noise is smoothed.
    """
    if line_width <= 0:
        raise ValueError(f"line_width must be positive, got {line_width}")
    return max(0.5 * line_width / np.sqrt(3.0), 1.0)


def line_response(contrast: float, line_width: float, sigma: float) -> float:
    """|r''| at the centre of a symmetric bar of ``contrast`` and full width ``line_width``.

    ``r''(0) = h (g'_s(w) - g'_s(-w)) = 2 h w exp(-w^2 / 2 s^2) / (sqrt(2 pi) s^3)`` (Marcato & Dal Poz 2011 eq. 9).
    """
    w = 0.5 * line_width
    return float(2 * contrast * w * np.exp(-(w * w) / (2 * sigma * sigma)) / (np.sqrt(2 * np.pi) * sigma**3))


def line_position_bias(sigma: float, half_width: float, asymmetry: float) -> float:
    """Shift of the detected line centre for an asymmetric bar (Marcato & Dal Poz 2011 eq. 11).

    For the profile ``0`` left of the bar, ``1`` on it (``|x| <= w``) and
    ``a`` right of it, the smoothed profile's extremum lies at
    ``x = -sigma^2 / (2 w) ln(1 - a)``: towards the darker side, zero only
    for equal contrast on both sides (``a = 0``).

    Examples
    --------
    >>> round(line_position_bias(1.5, 2.0, 0.5), 4)
    0.3899
    """
    if not 0 <= asymmetry < 1:
        raise ValueError(f"asymmetry must be in [0, 1), got {asymmetry}")
    return float(-(sigma**2) / (2 * half_width) * np.log1p(-asymmetry))


def hessian_line_points(image: np.ndarray, sigma: float, polarity: str = "both", *, min_strength: float = 0.0):
    """Per-pixel line strength, sub-pixel centre and normal from the Hessian.

    Parameters
    ----------
    image : ndarray of shape (H, W)
    sigma : float
        Gaussian scale (px).
    polarity : {'bright', 'dark', 'both'}, default 'both'
        Bright lines on a dark background, dark on bright, or either.
    min_strength : float, default 0.0
        Pixels weaker than this are skipped (their normal is left at 0).

    Returns
    -------
    strength : ndarray of shape (H, W)
        Second directional derivative across the line (grey / px^2), 0 where
        the pixel holds no line point of the requested polarity.
    points : ndarray of shape (H, W, 2)
        Sub-pixel (col, row) of the line point in each pixel, NaN elsewhere.
    normals : ndarray of shape (H, W, 2)
        Unit normal (n_col, n_row).
    """
    if polarity not in _POLARITIES:
        raise ValueError(f"polarity must be one of {_POLARITIES}, got {polarity!r}")
    img = np.asarray(image, float)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D (H, W), got shape {img.shape}")
    if sigma <= 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    g = lambda order: ndi.gaussian_filter(img, sigma, order=order, mode="nearest")  # noqa: E731
    code = _POLARITIES.index(polarity)
    return _line_kernel(g((0, 1)), g((1, 0)), g((0, 2)), g((1, 1)), g((2, 0)), code, float(min_strength))


@njit(cache=True)
def _line_kernel(rx, ry, rxx, rxy, ryy, polarity, min_strength):
    """Per pixel: eigen-analysis of the Hessian, Taylor extremum along the normal."""
    h, w = rx.shape
    strength = np.zeros((h, w))
    points = np.full((h, w, 2), np.nan)
    normals = np.zeros((h, w, 2))
    for r in range(h):
        for c in range(w):
            a, b, d = rxx[r, c], rxy[r, c], ryy[r, c]
            half_tr = 0.5 * (a + d)
            root = np.sqrt((0.5 * (a - d)) ** 2 + b * b)
            lp, lm = half_tr + root, half_tr - root
            plus = abs(lp) >= abs(lm)
            lam = lp if plus else lm
            if polarity == 0:
                s = -lam
            elif polarity == 1:
                s = lam
            else:
                s = abs(lam)
            if s <= 0.0 or s < min_strength:
                continue
            theta = 0.5 * np.arctan2(2.0 * b, a - d)  # eigenvector of lp
            if plus:
                nx, ny = np.cos(theta), np.sin(theta)
            else:
                nx, ny = -np.sin(theta), np.cos(theta)
            normals[r, c, 0] = nx
            normals[r, c, 1] = ny
            t = -(rx[r, c] * nx + ry[r, c] * ny) / lam
            # 0.5 would be the pixel's own cell; the quadratic model overshoots
            # on steep, asymmetric profiles and both neighbours would refuse
            # the point, so allow a little overlap (a 2-px run links as one chain)
            if abs(t * nx) > _CELL or abs(t * ny) > _CELL:
                continue
            # the Taylor test alone also fires in the Gaussian tail beside a
            # step edge (there t = sigma^2 / x -> 0); a true line point has the
            # directional derivative change sign across it
            pc, pr = c + t * nx, r + t * ny
            d_minus = _bilinear(rx, pr - ny, pc - nx) * nx + _bilinear(ry, pr - ny, pc - nx) * ny
            d_plus = _bilinear(rx, pr + ny, pc + nx) * nx + _bilinear(ry, pr + ny, pc + nx) * ny
            if d_minus * d_plus < 0.0:
                strength[r, c] = s
                points[r, c, 0] = pc
                points[r, c, 1] = pr
    return strength, points, normals


@njit(cache=True)
def _bilinear(a, r, c):
    h, w = a.shape
    r = min(max(r, 0.0), h - 1.0)
    c = min(max(c, 0.0), w - 1.0)
    r0, c0 = min(int(r), h - 2), min(int(c), w - 2)
    if h < 2 or w < 2:
        return a[int(r), int(c)]
    fr, fc = r - r0, c - c0
    return ((1 - fr) * ((1 - fc) * a[r0, c0] + fc * a[r0, c0 + 1])
            + fr * ((1 - fc) * a[r0 + 1, c0] + fc * a[r0 + 1, c0 + 1]))


def _two_sided(img, sigma, strength, points, normals, line_width, min_contrast):
    """Keep line points whose both sides differ from the centre in the line's sense.

    A bar of contrast h has background on both sides; beside a bright bar
    (or a step) the smoothed profile is convex, and noise can make its
    derivative vanish there.  Such flank points have background on only one
    side.  Sides are sampled at ``line_width / 2 + sigma`` px along the normal
    on the smoothed image; both must exceed ``min_contrast / 2``.
    """
    r, c = np.nonzero(strength > 0)
    if not len(r):
        return strength
    smooth = ndi.gaussian_filter(img, sigma, mode="nearest")
    p = points[r, c]
    n = normals[r, c]
    d = 0.5 * line_width + sigma
    centre = ndi.map_coordinates(smooth, [p[:, 1], p[:, 0]], order=1, mode="nearest")
    side_a = ndi.map_coordinates(smooth, [p[:, 1] + d * n[:, 1], p[:, 0] + d * n[:, 0]], order=1, mode="nearest")
    side_b = ndi.map_coordinates(smooth, [p[:, 1] - d * n[:, 1], p[:, 0] - d * n[:, 0]], order=1, mode="nearest")
    # bright line: sides darker; dark line: sides brighter
    bright = (centre - side_a > 0) & (centre - side_b > 0)
    sign = np.where(bright, 1.0, -1.0)
    ok = (sign * (centre - side_a) >= 0.5 * min_contrast) & (sign * (centre - side_b) >= 0.5 * min_contrast)
    out = strength.copy()
    out[r[~ok], c[~ok]] = 0.0
    return out


_BIAS_TABLE = None


def _bias_table():
    """Model of Marcato & Dal Poz 2011 eq. 7-11 in units of sigma: for a bar 0 | 1 (|x| <= w) | a,
    the detected centre's offset, the half distance between the two edge
    maxima seen from it, and the ratio of the edge gradients, over a grid of
    (w, a).  Returns a KD-tree on (half distance, 4 x ratio) and the offsets."""
    global _BIAS_TABLE
    if _BIAS_TABLE is None:
        from scipy.spatial import cKDTree

        x = np.arange(-9.0, 9.0, 0.005)
        ws = np.linspace(0.3, 4.0, 75)[:, None]
        g_plus = np.exp(-0.5 * (x + ws) ** 2)  # (W, X); the 1/sqrt(2 pi) cancels in the ratio
        g_minus = np.exp(-0.5 * (x - ws) ** 2)
        feats, offs = [], []
        for a in np.linspace(0.0, 0.9, 46):
            d1 = np.abs(g_plus - (1 - a) * g_minus)
            x0 = -np.log1p(-a) / (2 * ws[:, 0])  # (W,)
            is_max = np.zeros_like(d1, bool)
            is_max[:, 1:-1] = (d1[:, 1:-1] > d1[:, :-2]) & (d1[:, 1:-1] >= d1[:, 2:])
            right_side = x[None, :] > x0[:, None]
            r_idx = np.argmax(is_max & right_side, axis=1)
            l_idx = len(x) - 1 - np.argmax((is_max & ~right_side)[:, ::-1], axis=1)
            ok = (is_max & right_side).any(1) & (is_max & ~right_side).any(1)
            rows = np.flatnonzero(ok)
            gl, gr = d1[rows, l_idx[rows]], d1[rows, r_idx[rows]]
            feats.append(np.column_stack([0.5 * (x[r_idx[rows]] - x[l_idx[rows]]), gr / gl]))
            offs.append(x0[rows])
        feats = np.concatenate(feats)
        _BIAS_TABLE = (cKDTree(feats * [1.0, 4.0]), np.concatenate(offs))
    return _BIAS_TABLE


def _correct_bias(img, sigma, points, normals, lines, line_width):
    """Move line points back by the asymmetric-contrast bias (Marcato & Dal Poz 2011 eq. 11).

    Along each point's normal the gradient magnitude of the smoothed image
    has a maximum at each edge of the bar; their half distance and the ratio
    of their heights identify (w, a) in the bar model, hence the bias
    ``-sigma^2/(2w) ln(1-a)`` towards the weaker edge (Steger 1998, §4).
    """
    r, c = np.nonzero(lines)
    if not len(r):
        return points
    gx = ndi.gaussian_filter(img, sigma, order=(0, 1), mode="nearest")
    gy = ndi.gaussian_filter(img, sigma, order=(1, 0), mode="nearest")
    mag = np.hypot(gx, gy)
    p, n = points[r, c], normals[r, c]
    reach = 0.5 * line_width + 3 * sigma
    t = np.arange(-reach, reach + 1e-9, 0.1)
    cols = p[:, 0, None] + t[None, :] * n[:, 0, None]
    rows = p[:, 1, None] + t[None, :] * n[:, 1, None]
    prof = ndi.map_coordinates(mag, [rows.ravel(), cols.ravel()], order=1, mode="nearest").reshape(len(p), -1)
    mid = len(t) // 2
    is_max = np.zeros_like(prof, bool)
    is_max[:, 1:-1] = (prof[:, 1:-1] > prof[:, :-2]) & (prof[:, 1:-1] >= prof[:, 2:])
    right = np.where(is_max[:, mid:].any(1), mid + np.argmax(is_max[:, mid:], axis=1), -1)
    left_rev = is_max[:, :mid][:, ::-1]
    left = np.where(left_rev.any(1), mid - 1 - np.argmax(left_rev, axis=1), -1)
    ok = (left >= 0) & (right >= 0)
    if not ok.any():
        return points
    idx = np.flatnonzero(ok)
    tl, tr = t[left[idx]], t[right[idx]]
    gl, gr = prof[idx, left[idx]], prof[idx, right[idx]]
    weak_right = gr <= gl
    ratio = np.where(weak_right, gr / np.maximum(gl, 1e-12), gl / np.maximum(gr, 1e-12))
    half = 0.5 * (tr - tl) / sigma
    tree, offs = _bias_table()
    _, k = tree.query(np.column_stack([half, 4.0 * ratio]))
    bias = offs[k] * sigma  # towards the weaker edge
    shift = np.where(weak_right, -bias, bias)  # move back towards the stronger one
    out = points.copy()
    out[r[idx], c[idx]] = p[idx] + shift[:, None] * n[idx]
    return out


def steger_lines(
    image: np.ndarray,
    sigma: float | None = None,
    low: float | None = None,
    high: float | None = None,
    *,
    line_width: float = 4.0,
    min_contrast: float = 0.05,
    polarity: str = "both",
    mask: np.ndarray | None = None,
    noise: float | None = None,
    correct_bias: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Steger line pixels and their sub-pixel centres.

    Parameters
    ----------
    image : ndarray of shape (H, W)
        Grey values (e.g. [0, 1]).
    sigma : float or None
        Gaussian scale (px); ``None`` gives :func:`steger_sigma` (``line_width``).
    low, high : float or None
        Hysteresis thresholds on the strength (grey / px^2).  ``None``
        derives ``high = max(line_response(min_contrast, line_width, sigma),
        4 s_2)`` with ``s_2 = noise sqrt(3) / (4 sqrt(pi) sigma^3)`` the std
        of a second Gaussian derivative under white noise, and ``low = high / 2``.
    line_width : float, default 4.0
        Expected full width of the lines (px): a roof ridge in a 10-20 cm image.
    min_contrast : float, default 0.05
        Weakest bar (grey levels) that may seed a line when thresholds are derived.
    polarity : {'bright', 'dark', 'both'}, default 'both'
    mask : ndarray of shape (H, W) of bool, optional
        Only pixels inside are reported.
    noise : float, optional
        Noise std (grey); ``None`` estimates it with :func:`~rooftrace.image.edges.noise_sigma`.
    correct_bias : bool, default False
        Remove the asymmetric-contrast bias of eq. 11 (see :func:`line_position_bias`)
        by identifying each point's bar width and asymmetry from the two edge
        gradients along its normal.

    Returns
    -------
    lines : ndarray of shape (H, W) of bool
        Line pixels after hysteresis.
    points : ndarray of shape (H, W, 2)
        Sub-pixel (col, row) of each line pixel, NaN elsewhere.

    Examples
    --------
    >>> img = np.zeros((21, 21)); img[:, 9:12] = 1.0   # a 3 px bright bar centred on column 10
    >>> lines, pts = steger_lines(img, line_width=3)
    >>> float(np.nanmean(pts[lines][:, 0]).round(3))
    10.0
    """
    s = steger_sigma(line_width) if sigma is None else float(sigma)
    if high is None or low is None:
        nz = noise_sigma(image) if noise is None else noise
        s2 = nz * np.sqrt(3.0) / (4 * np.sqrt(np.pi) * s**3)
        h = max(line_response(min_contrast, line_width, s), 4.0 * s2)
        high = h if high is None else high
        low = 0.5 * high if low is None else low
    if low > high:
        raise ValueError(f"low threshold {low} exceeds high threshold {high}")
    # only pixels above ``low`` can survive hysteresis
    strength, points, normals = hessian_line_points(image, s, polarity, min_strength=low)
    strength = _two_sided(np.asarray(image, float), s, strength, points, normals, line_width, min_contrast)
    lines = hysteresis(strength > 0, strength, low, high)
    if mask is not None:
        lines &= np.asarray(mask, bool)
    if correct_bias:
        points = _correct_bias(np.asarray(image, float), s, points, normals, lines, line_width)
    points[~lines] = np.nan
    return lines, points
