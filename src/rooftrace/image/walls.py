"""Visible wall strips beside projected roof edges, and the roof edge among parallel lines (ours).

In a frame image a wall that faces the camera shows as a strip between the
roof edge (eave) and the wall's foot: relief displacement moves the eave
away from the nadir point more than the foot.  Across the projected side,
the foot lies ``w`` px *outward* of the eave, with

    w = (P(m_ground) - P(m_eave)) . n_out

``P`` the projection, ``m`` the side's middle at eave and at ground height,
``n_out`` the outward image normal of the side.  ``w > 0``: the wall is
visible.  Seed 000's candidates then hold up to three parallel lines at
the side (roof edge, foot of the wall, and a cast shadow beyond), and
when the roof and the wall are of similar brightness the roof edge is too
weak for Canny while the foot is strong.

:func:`wall_strips` predicts ``w`` per outline side; :func:`mark_wall_lines`
searches, inward of each step candidate of such a side, for the roof edge
along the whole candidate (the mean derivative across it: averaging along
tens of pixels finds steps of a few grey levels), adds it when found, and
marks the outer line of every roof-edge/foot pair so that the grouping can
penalise it.

Pixel coordinates are ``(col, row)`` with pixel centres at integers.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy import ndimage as ndi

from rooftrace.image.edges import gaussian_gradient
from rooftrace.image.refit import refit_lines

__all__ = ["wall_strips", "mark_wall_lines"]


def wall_strips(camera, lines3d, kinds, outline, ground_z: float) -> tuple[np.ndarray, np.ndarray]:
    """Predicted visible wall width (px) and outward image normal of each outline side.

    Parameters
    ----------
    camera : FrameCamera or OrthoCamera
    lines3d : ndarray of shape (M, 2, 3)
        Outline sides and ridges (object space, m).
    kinds : sequence of str
        ``'outline'`` or ``'ridge'`` per line.
    outline : Polygon
        The roof outline (plan is enough), to tell the outward side.
    ground_z : float
        Ground height (m) at the building.

    Returns
    -------
    width : ndarray of shape (M,)
        ``w`` of the module notes (px); 0 for ridges and sides whose wall is
        hidden or lower than 0.
    outward : ndarray of shape (M, 2)
        Unit outward normal of each projected side (col, row); NaN for ridges.

    Examples
    --------
    >>> from shapely.geometry import box
    >>> from rooftrace.image.camera import FrameCamera
    >>> cam = FrameCamera((400, 400), 0.01, 100.0, np.array([-30.0, 0.0, 1000.0, 0, 0, 0]))
    >>> lines = np.array([[[-5, -5, 10], [-5, 5, 10]], [[5, 5, 10], [5, -5, 10]]], float)
    >>> w, n = wall_strips(cam, lines, ["outline"] * 2, box(-5, -5, 5, 5), 0.0)
    >>> w.round(1).tolist(), (n[0].round(1) + 0.0).tolist()     # the west wall faces the camera
    ([2.5, 0.0], [-1.0, 0.0])
    """
    lines = np.asarray(lines3d, float).reshape(-1, 2, 3)
    width = np.zeros(len(lines))
    outward = np.full((len(lines), 2), np.nan)
    side = np.flatnonzero(np.array([k == "outline" for k in kinds], bool))
    if not len(side):
        return width, outward
    seg = lines[side]
    mid = seg.mean(axis=1)
    d_xy = seg[:, 1, :2] - seg[:, 0, :2]
    n_xy = np.column_stack([d_xy[:, 1], -d_xy[:, 0]]) / np.maximum(np.linalg.norm(d_xy, axis=1), 1e-12)[:, None]
    flat = shapely.force_2d(outline)
    step = 0.05  # m: a point just beside the side, inside or outside the roof
    inside = shapely.contains_xy(flat, mid[:, 0] + step * n_xy[:, 0], mid[:, 1] + step * n_xy[:, 1])
    n_xy = np.where(inside[:, None], -n_xy, n_xy)
    ends = camera.project(seg.reshape(-1, 3)).reshape(-1, 2, 2)
    top = camera.project(mid)
    off = camera.project(mid + np.column_stack([n_xy, np.zeros(len(mid))]))
    foot = camera.project(np.column_stack([mid[:, :2], np.full(len(mid), float(ground_z))]))
    u = ends[:, 1] - ends[:, 0]
    u = u / np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None]
    n_img = np.column_stack([-u[:, 1], u[:, 0]])
    n_img = np.where((np.einsum("ij,ij->i", off - top, n_img) < 0)[:, None], -n_img, n_img)
    w = np.einsum("ij,ij->i", foot - top, n_img)
    width[side] = np.where(np.isfinite(w), np.maximum(w, 0.0), 0.0)
    outward[side] = n_img
    return width, outward


def _mean_profile(gx, gy, seg, normal, offsets, spacing=1.0):
    """Mean derivative along ``normal`` across segment (2, 2), at each offset (O,) -> (O,)."""
    length = float(np.linalg.norm(seg[1] - seg[0]))
    t = np.linspace(0.0, 1.0, max(int(length / spacing), 1) + 1)
    pts = seg[0] + t[:, None] * (seg[1] - seg[0])
    q = pts[:, None, :] + offsets[None, :, None] * normal
    coords = [q[..., 1].ravel(), q[..., 0].ravel()]
    d = (ndi.map_coordinates(gx, coords, order=3, mode="nearest") * normal[0]
         + ndi.map_coordinates(gy, coords, order=3, mode="nearest") * normal[1]).reshape(q.shape[:2])
    return d.mean(axis=0), len(t)


def mark_wall_lines(image: np.ndarray, segments, sources, outward, width: float, *, sigma: float = 0.7,
                    noise: float = 0.01, margin: float = 1.5, min_ratio: float = 0.1, z: float = 5.0,
                    angle_tol: float = 3.0) -> tuple[np.ndarray, list, np.ndarray]:
    """Add the roof edge inward of a visible wall's foot, and mark the outer line of each such pair.

    Parameters
    ----------
    image : ndarray of shape (H, W) float
        Grey image (or crop) holding the segments.
    segments : ndarray of shape (K, 2, 2)
        Candidates (col, row) of one outline side.
    sources : sequence of str
        Their provenance; Steger lines (bars) are not searched from.
    outward : ndarray of shape (2,)
        Unit outward normal of the side in the image.
    width : float
        Predicted visible wall width ``w`` (px, :func:`wall_strips`).
    sigma : float, default 0.7
        Derivative scale (px).
    noise : float, default 0.01
        Grey noise std, for the significance of a mean derivative.
    margin : float, default 1.5
        Tolerance (px) on ``w``: a roof edge is sought, and a pair accepted,
        up to ``w + margin`` inward.
    min_ratio : float, default 0.1
        Weakest inner step, as a fraction of the outer line's.
    z : float, default 5.0
        Significance of the inner step, in standard errors of the mean
        derivative under white noise.
    angle_tol : float, default 3.0
        Degrees within which two candidates are parallel.

    Returns
    -------
    segments : ndarray of shape (K', 2, 2)
        The input, then the roof edges found (source ``'inner'``).
    sources : list of str
    wall : ndarray of shape (K',) bool
        True for a line with a roof edge inward of it within the wall strip.
    """
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    src = list(sources)
    n = np.asarray(outward, float)
    if not len(seg) or not width > 0 or not np.isfinite(n).all():
        return seg, src, np.zeros(len(seg), bool)
    gx, gy = gaussian_gradient(np.asarray(image, float), sigma)
    s_g = noise / (sigma**2 * np.sqrt(8 * np.pi))  # std of one derivative component under white noise
    inner_off = np.arange(-(width + margin), -0.75 + 1e-9, 0.25)
    added = []
    for k in range(len(seg)):
        if src[k] == "steger":
            continue
        prof, n_samples = _mean_profile(gx, gy, seg[k], n, np.concatenate([inner_off, [0.0]]))
        own = abs(prof[-1])
        inner = np.abs(prof[:-1])
        # a local maximum of the inner profile, not the flank of the line's own step
        peak = np.flatnonzero((inner[1:-1] >= inner[:-2]) & (inner[1:-1] >= inner[2:])) + 1
        if not len(peak):
            continue
        best = peak[np.argmax(inner[peak])]
        if inner[best] < max(min_ratio * own, z * s_g / np.sqrt(n_samples)):
            continue
        guess = seg[k] + inner_off[best] * n
        fit, ok = refit_lines(image, guess[None], sigma, 1.0)
        added.append(fit[0] if ok[0] else guess)
    if added:
        seg = np.concatenate([seg, np.array(added)])
        src += ["inner"] * len(added)
    # pairs: j lies outward of i by 0.75 .. w + margin px, parallel and overlapping
    d = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-12)[:, None]
    par = np.abs(u @ u.T) >= np.cos(np.radians(angle_tol))
    mid = seg.mean(axis=1)
    sep = (mid[None, :] - mid[:, None]) @ n  # (i, j): how far j lies outward of i
    along = np.einsum("ijkd,id->ijk", seg[None, :, :, :] - seg[:, None, None, 0, :], u)  # j's ends along i
    ov = np.minimum(length[:, None], along.max(axis=2)) - np.maximum(0.0, along.min(axis=2))
    overlap = ov / np.maximum(np.minimum(length[:, None], length[None, :]), 1e-12)
    pair = par & (sep >= 0.75) & (sep <= width + margin) & (overlap >= 0.5)
    np.fill_diagonal(pair, False)
    return seg, src, pair.any(axis=0)
