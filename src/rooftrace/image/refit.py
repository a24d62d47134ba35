"""Sub-pixel re-location of candidate lines on the image gradient (ours, beyond seeds 000/003).

A candidate from Canny's chains is located with Canny's scale (``sigma`` 1 px
on top of the image's own blur), and :func:`~rooftrace.image.linework.merge_collinear`
may join fragments of two different edges up to 3 px apart into one slightly
tilted segment.  Both errors matter at the 1 px level: a roof edge next to a
visible wall strip 1-3 px wide comes out 0.5-0.7 px outward (the two steps
merge under the smoothing), and a merged roof edge + neighbour edge misses
the true side by 2 px at one end.

:func:`refit_lines` re-measures each segment:

1. samples every ``spacing`` px along it; at each, the directional derivative
   across the segment (Gaussian derivatives at a smaller ``sigma``) on
   offsets ``-search .. +search`` px;
2. keeps, per sample, the sub-pixel maximum of the derivative with the
   segment's own polarity (the sign of the step it was found on), so a
   neighbouring step of the other sign (a bright wall after a dark roof, a
   shadow) cannot capture it;
3. fits a line to those points robustly: the best of the lines through pairs
   of a dozen evenly spaced points (most points within ``tolerance``, an
   exhaustive and so deterministic RANSAC), then total least squares on its
   inliers;
4. keeps the longest run of consecutive inliers as the new extent.

Segments with too few inliers keep their input geometry.  Pixel coordinates
are ``(col, row)`` with pixel centres at integers.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

from rooftrace.image.edges import gaussian_gradient

__all__ = ["refit_lines", "edge_profile_peaks"]

_STEP = 0.25  # px between offsets of the across-line profile


def edge_profile_peaks(gx: np.ndarray, gy: np.ndarray, points: np.ndarray, normals: np.ndarray,
                       polarity: np.ndarray, search: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel offsets and strengths of the signed gradient maxima across lines.

    Parameters
    ----------
    gx, gy : ndarray of shape (H, W)
        Gaussian derivatives along columns and rows.
    points : ndarray of shape (S, 2)
        Sample points (col, row).
    normals : ndarray of shape (S, 2)
        Unit normals (col, row) at each sample.
    polarity : ndarray of shape (S,)
        +1 or -1: the sign of the step to look for along ``normals``.
    search : float, default 2.0
        Half-length (px) of the profile.

    Returns
    -------
    offset : ndarray of shape (S,)
        Position of the maximum along the normal (px), NaN when the maximum
        lies at the profile's end (the edge is farther than ``search``).
    strength : ndarray of shape (S,)
        Signed derivative at the maximum (grey / px).

    Examples
    --------
    >>> img = np.zeros((20, 20)); img[:, 10:] = 1.0
    >>> gx, gy = gaussian_gradient(img, 0.7)
    >>> off, _ = edge_profile_peaks(gx, gy, np.array([[9.0, 10.0]]), np.array([[1.0, 0.0]]), np.array([1.0]))
    >>> round(float(off[0]), 2)
    0.5
    """
    o = np.arange(-search, search + 1e-9, _STEP)
    q = points[:, None, :] + o[None, :, None] * normals[:, None, :]
    coords = [q[..., 1].ravel(), q[..., 0].ravel()]
    # cubic splines: a bilinear profile peaks on a pixel centre, whatever the edge's sub-pixel position
    d = (ndi.map_coordinates(gx, coords, order=3, mode="nearest").reshape(q.shape[:2]) * normals[:, 0:1]
         + ndi.map_coordinates(gy, coords, order=3, mode="nearest").reshape(q.shape[:2]) * normals[:, 1:2])
    d = d * polarity[:, None]
    k = np.argmax(d, axis=1)
    rows = np.arange(len(d))
    inner = (k > 0) & (k < len(o) - 1)
    kk = np.clip(k, 1, len(o) - 2)
    dm, d0, dp = d[rows, kk - 1], d[rows, kk], d[rows, kk + 1]
    denom = dm - 2 * d0 + dp
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(denom < 0, 0.5 * (dm - dp) / denom, 0.0)
    offset = np.where(inner, o[kk] + np.clip(delta, -0.5, 0.5) * _STEP, np.nan)
    return offset, d[rows, k]


def _robust_line(pts: np.ndarray, tolerance: float, n_hyp: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre, unit direction and inlier mask of the line most points of (P, 2) lie on."""
    idx = np.unique(np.linspace(0, len(pts) - 1, min(n_hyp, len(pts))).round().astype(int))
    i, j = np.triu_indices(len(idx), 1)
    a, b = pts[idx[i]], pts[idx[j]]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    good = length > 2.0  # pairs too close give no direction
    if not good.any():
        good = length > 0
    a, d = a[good], d[good] / length[good, None]
    n = np.column_stack([-d[:, 1], d[:, 0]])
    res = np.abs(np.einsum("hpk,hk->hp", pts[None] - a[:, None], n))
    # inlier count first; the summed residual of the inliers breaks ties
    score = (res <= tolerance).sum(axis=1) - np.where(res <= tolerance, res, 0).sum(axis=1) / (tolerance * len(pts) + 1)
    inl = res[int(np.argmax(score))] <= tolerance
    for _ in range(2):  # TLS on the inliers, then the inliers of that line
        c = pts[inl].mean(axis=0)
        _, _, vt = np.linalg.svd(pts[inl] - c, full_matrices=False)
        u = vt[0]
        nrm = np.array([-u[1], u[0]])
        new = np.abs((pts - c) @ nrm) <= tolerance
        if new.sum() < 2:
            break
        inl = new
    return c, u, inl


def _longest_run(mask: np.ndarray, max_gap: int) -> tuple[int, int]:
    """First and last index of the longest run of True allowing gaps of at most ``max_gap`` False."""
    idx = np.flatnonzero(mask)
    breaks = np.flatnonzero(np.diff(idx) > max_gap + 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(idx) - 1]])
    best = int(np.argmax(idx[ends] - idx[starts]))
    return int(idx[starts[best]]), int(idx[ends[best]])


def refit_lines(image: np.ndarray, segments, sigma: float = 0.7, search: float = 2.0, *, spacing: float = 1.0,
                tolerance: float = 0.5, min_support: float = 0.5, max_gap: int = 3,
                min_points: int = 5, min_strength: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Re-locate segments at the sub-pixel gradient maxima across them (see the module notes).

    Parameters
    ----------
    image : ndarray of shape (H, W) float
        Grey image (or a crop of it) in which the segments lie.
    segments : ndarray of shape (K, 2, 2)
        Segments (col, row) in that image's pixel coordinates.
    sigma : float, default 0.7
        Scale (px) of the Gaussian derivatives: smaller than Canny's so a
        step 2 px from another stays apart.
    search : float, default 2.0
        How far (px) across the segment the maximum is sought.
    spacing : float, default 1.0
        Distance (px) between samples along a segment.
    tolerance : float, default 0.5
        Largest distance (px) of an inlier to the fitted line.
    min_support : float, default 0.5
        Fraction of the samples that must be inliers of the kept run;
        otherwise the segment is returned unchanged.
    max_gap : int, default 3
        Samples without an inlier that a run may bridge.
    min_points : int, default 5
        Fewest inliers of a refitted segment.
    min_strength : float, default 0
        Weakest derivative (grey / px) of a sample; a segment found on
        another channel (a colour edge of equal grey) keeps its geometry.

    Returns
    -------
    segments : ndarray of shape (K, 2, 2)
        Refitted segments, the input where the refit failed.
    refitted : ndarray of shape (K,) bool

    Examples
    --------
    >>> img = np.zeros((30, 40)); img[:, 20:] = 1.0          # step between columns 19 and 20
    >>> seg = np.array([[[18.0, 3.0], [21.0, 26.0]]])       # a tilted guess
    >>> out, ok = refit_lines(img, seg)
    >>> ok.tolist(), out[0, :, 0].round(2).tolist()
    ([True], [19.5, 19.5])
    """
    img = np.asarray(image, float)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D (H, W), got shape {img.shape}")
    if not (sigma > 0 and search > 0 and spacing > 0 and tolerance > 0):
        raise ValueError("sigma, search, spacing and tolerance must be positive")
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    out, ok = seg.copy(), np.zeros(len(seg), bool)
    if not len(seg):
        return out, ok
    gx, gy = gaussian_gradient(img, sigma)
    d = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-12)[:, None]
    n = np.column_stack([-u[:, 1], u[:, 0]])
    counts = np.maximum(np.ceil(length / spacing).astype(int) + 1, 2)
    sid = np.repeat(np.arange(len(seg)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(len(sid)) - first) / (counts[sid] - 1)
    pts = seg[sid, 0] + t[:, None] * d[sid]
    # polarity: the sign of the step on the segment itself, summed over its samples
    on = ndi.map_coordinates(gx, [pts[:, 1], pts[:, 0]], order=1, mode="nearest") * n[sid, 0] \
        + ndi.map_coordinates(gy, [pts[:, 1], pts[:, 0]], order=1, mode="nearest") * n[sid, 1]
    polarity = np.where(np.bincount(sid, on, len(seg)) >= 0, 1.0, -1.0)
    offset, strength = edge_profile_peaks(gx, gy, pts, n[sid], polarity[sid], search)
    # a sample counts when its step is at least a third of the segment's typical step
    typical = np.array([np.median(strength[sid == k]) for k in range(len(seg))])
    valid = np.isfinite(offset) & (strength > min_strength) & (strength >= typical[sid] / 3.0)
    peaks = pts + np.nan_to_num(offset)[:, None] * n[sid]
    for k in range(len(seg)):
        mine = sid == k
        v = valid[mine]
        if v.sum() < max(min_points, 2):
            continue
        p = peaks[mine]
        c, dirn, inl_v = _robust_line(p[v], tolerance)
        inl = np.zeros(len(p), bool)
        inl[np.flatnonzero(v)[inl_v]] = True
        if inl.sum() < min_points:
            continue
        i0, i1 = _longest_run(inl, max_gap)
        run = np.zeros(len(p), bool)
        run[i0:i1 + 1] = inl[i0:i1 + 1]
        if run.sum() < max(min_points, min_support * len(p)):
            continue
        if dirn @ u[k] < 0:
            dirn = -dirn
        s = (p[run] - c) @ dirn
        out[k] = [c + s.min() * dirn, c + s.max() * dirn]
        ok[k] = True
    return out, ok
