"""The common image shift of one roof, estimated from its candidate lines before grouping (ours).

Seed 000's proximity term (eq. 7-8) measures candidates against the projected
LiDAR lines.  Their error is mostly common to the roof: the camera's
orientation error moves the whole roof by the same few pixels, and a LiDAR
outline lies inside the true one by about half a point spacing on every
side.  A candidate on the far side of the true edge by that much (a wall's
foot, a shadow) is then nearer the projection than the true edge.

:func:`estimate_shift` models the offset of the true edge of outline side
``s`` from its projection, along the side's outward image normal ``n_s``, as

    o_s = n_s . t + b

(``t`` the common image translation, ``b`` the common outward growth) and
finds ``(t, b)`` as the hypothesis most sides agree with: on a grid, each
side votes with its best-agreeing candidate (a Gaussian of the residual,
weighted by the candidate's length); the winner is refined by least squares
on the sides within ``inlier_px`` of it.  Ridges are not used (their
offsets carry no growth term and they are few).

:func:`shift_references` moves the projected lines by the estimate, for
the energy only, after :meth:`RoofShift.shrunk` has weighed the estimate
against the camera's own orientation error (and re-estimated ``b`` for the
weighed ``t``).  The refinement then moves the sides that keep their
projection, and the vertices without image support, outward by ``b``
(``RefineOptions.grow``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["RoofShift", "estimate_shift", "shift_references", "beyond_wall", "GROWTH_RANGE"]

#: growth ``b`` searched (px): a LiDAR outline lies up to a few pixels inside the roof edge, rarely outside
GROWTH_RANGE = (-1.0, 3.0)


@dataclass(frozen=True)
class RoofShift:
    """A roof's common image shift.

    Attributes
    ----------
    translation : ndarray of shape (2,)
        ``t`` (px, col/row).
    growth : float
        ``b`` (px, outward positive).
    n_sides : int
        Sides within ``inlier_px`` of the estimate (0: no estimate, all zero).
    variance : float
        Variance (px², per axis) of ``translation``, from the least-squares
        residuals (at least ``0.25`` px²: the model's own error).
    offsets, normals : ndarray of shape (n_sides,), (n_sides, 2)
        Outward offset (px) of each inlier side's candidate and the side's
        outward normal: :meth:`shrunk` re-estimates the growth from them.
    """

    translation: np.ndarray
    growth: float
    n_sides: int
    variance: float = np.inf
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def shrunk(self, prior_variance: float) -> RoofShift:
        """The translation weighted against a prior of zero with ``prior_variance`` (px², per axis).

        ``t · σ_C² / (σ_C² + σ_t²)``: with a camera whose orientation is
        known exactly (σ_C = 0) the roof does not move; with one off by
        pixels the estimate is used nearly as is.
        """
        k = 0.0
        if np.isfinite(self.variance) and prior_variance > 0:
            k = prior_variance / (prior_variance + self.variance)
        t = k * self.translation
        # the growth that goes with the shrunk translation (least squares with t fixed: a mean), far
        # better determined than the joint estimate when few sides face few directions
        b = float(np.mean(self.offsets - self.normals @ t)) if len(self.offsets) else self.growth
        return RoofShift(t, b, self.n_sides, self.variance, self.offsets, self.normals)


def _offsets(references: np.ndarray, candidates: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Outward offset (K,) of each candidate's middle from the reference line (2, 2)."""
    return (candidates.mean(axis=1) - references[0]) @ outward


def estimate_shift(references: np.ndarray, candidates, outward: np.ndarray, usable, *, radius: float = 8.0,
                   growth_range: tuple[float, float] = GROWTH_RANGE, step: float = 0.5, sigma: float = 1.0,
                   inlier_px: float = 1.0, min_sides: int = 3) -> RoofShift:
    """Common translation and outward growth of a roof's candidate lines (see the module notes).

    Parameters
    ----------
    references : ndarray of shape (M, 2, 2)
        Projected lines (col, row).
    candidates : sequence of M ndarrays (K_s, 2, 2)
        Candidate image lines per line.
    outward : ndarray of shape (M, 2)
        Unit outward image normal of each outline side; NaN rows (ridges)
        are not used.
    usable : sequence of M ndarrays (K_s,) bool
        Candidates that may vote (image lines, not projections or marked
        wall feet).
    radius : float, default 8.0
        Largest translation searched (px), e.g. three registration errors.
    growth_range : (float, float), default (-1, 3)
        Range of ``b`` searched (px).
    step, sigma, inlier_px : float, default 0.5, 1.0, 1.0
        Grid step, vote width and inlier distance (px).
    min_sides : int, default 3
        Fewest agreeing sides, with normals in two directions, for an estimate.

    Returns
    -------
    RoofShift

    Examples
    --------
    >>> refs = np.array([[[0, 0], [20, 0]], [[20, 0], [20, 20]], [[20, 20], [0, 20]], [[0, 20], [0, 0]]], float)
    >>> out = np.array([[0, -1], [1, 0], [0, 1], [-1, 0]], float)
    >>> true = refs + [2.0, 1.0] + out[:, None] * 1.5          # moved by (2, 1), grown by 1.5
    >>> cands = [np.stack([t, t + o * 4]) for t, o in zip(true, out)]   # plus a line 4 px beyond
    >>> est = estimate_shift(refs, cands, out, [np.array([True, True])] * 4)
    >>> est.translation.round(2).tolist(), round(est.growth, 2), est.n_sides
    ([2.0, 1.0], 1.5, 4)
    """
    refs = np.asarray(references, float).reshape(-1, 2, 2)
    normals = np.asarray(outward, float).reshape(-1, 2)
    none = RoofShift(np.zeros(2), 0.0, 0)
    sides = [s for s in range(len(refs)) if np.isfinite(normals[s]).all() and np.any(usable[s])]
    if len(sides) < min_sides:
        return none
    off, wgt, side_of = [], [], []
    for s in sides:
        c = np.asarray(candidates[s], float).reshape(-1, 2, 2)[np.asarray(usable[s], bool)]
        ref_len = max(float(np.linalg.norm(refs[s, 1] - refs[s, 0])), 1e-9)
        off.append(_offsets(refs[s], c, normals[s]))
        wgt.append(np.minimum(np.linalg.norm(c[:, 1] - c[:, 0], axis=1) / ref_len, 1.0))
        side_of.append(np.full(len(c), len(side_of)))
    off, wgt, side_of = np.concatenate(off), np.concatenate(wgt), np.concatenate(side_of)
    n = normals[sides][side_of]  # (C, 2)
    g = np.arange(-radius, radius + 1e-9, step)
    tx, ty = np.meshgrid(g, g, indexing="ij")
    inside = tx**2 + ty**2 <= radius**2
    t = np.column_stack([tx[inside], ty[inside]])  # (T, 2)
    b = np.arange(growth_range[0], growth_range[1] + 1e-9, step)  # (B,)
    pred = (t @ n.T)[:, None, :] + b[None, :, None]  # (T, B, C)
    vote = wgt * np.exp(-0.5 * ((off - pred) / sigma) ** 2)
    # each side votes once, with its best candidate
    best = np.zeros(pred.shape[:2] + (len(sides),))
    np.maximum.at(best.transpose(2, 0, 1), side_of, vote.transpose(2, 0, 1))
    score = best.sum(axis=2)
    # ties (flat score): the smallest move
    score = score - 1e-6 * (np.linalg.norm(t, axis=1)[:, None] + np.abs(b)[None, :])
    i, j = np.unravel_index(int(np.argmax(score)), score.shape)
    t0, b0 = t[i], b[j]
    # least squares on each side's nearest candidate within inlier_px
    res = np.abs(off - (n @ t0 + b0))
    rows = []
    for k in range(len(sides)):
        mine = np.flatnonzero((side_of == k) & (res <= inlier_px))
        if len(mine):
            rows.append(mine[np.argmin(res[mine])])
    rows = np.array(rows, int)
    a = np.column_stack([n[rows], np.ones(len(rows))])
    if len(rows) < min_sides or np.linalg.svd(n[rows], compute_uv=False)[-1] < 0.3:
        return none  # too few sides, or all parallel: t along them is unknown
    sol, *_ = np.linalg.lstsq(a, off[rows], rcond=None)
    dof = max(len(rows) - 3, 1)
    s2 = max(float(np.sum((a @ sol - off[rows]) ** 2)) / dof, 0.25)
    var = s2 * float(np.trace(np.linalg.pinv(a.T @ a)[:2, :2])) / 2.0
    return RoofShift(sol[:2], float(sol[2]), int(len(rows)), var, off[rows], n[rows])


def shift_references(references: np.ndarray, shift: RoofShift) -> np.ndarray:
    """References (M, 2, 2) moved by the translation ``t``.

    In the energy the growth ``b`` only keeps ``t`` unbiased: moving the
    lines outward by it too made the proximity term prefer wall feet over
    roof edges (correctness 94.0 % instead of 94.2 % in
    benchmarks/bench_refine.py).  The geometry uses it (``RefineOptions.grow``).
    """
    return np.asarray(references, float) + shift.translation


def beyond_wall(references: np.ndarray, candidates, outward: np.ndarray, width: np.ndarray, shift: RoofShift,
                usable, min_width: float = 1.5) -> list:
    """Candidates lying where a visible wall's foot is expected rather than the roof edge.

    With the roof's shift (the raw estimate: weighed by an exact camera it
    would be zero, and the LiDAR outline's own side errors then flag true
    edges, PoLiS 0.130 m instead of 0.120 m at 2 pts/m² in bench_refine.py), the
    roof edge of side ``s`` is expected at the outward offset
    ``n_s . t + b`` and the foot of its visible wall ``width[s]`` px beyond.
    A usable candidate past the middle of the two (plus 0.5 px) is flagged.

    Parameters
    ----------
    references, candidates, outward, usable
        As for :func:`estimate_shift`.
    width : ndarray of shape (M,)
        Predicted visible wall widths (px; :func:`rooftrace.image.walls.wall_strips`).
    shift : RoofShift
    min_width : float, default 1.5
        Narrower walls are not judged (their foot is too close to the edge).

    Returns
    -------
    list of M ndarrays (K_s,) bool
    """
    out = [np.zeros(len(np.asarray(c).reshape(-1, 2, 2)), bool) for c in candidates]
    if shift.n_sides == 0:
        return out
    refs = np.asarray(references, float).reshape(-1, 2, 2)
    for s, c in enumerate(candidates):
        n = np.asarray(outward[s], float)
        if not (width[s] >= min_width and np.isfinite(n).all()):
            continue
        o = _offsets(refs[s], np.asarray(c, float).reshape(-1, 2, 2), n)
        out[s] = np.asarray(usable[s], bool) & (o - (n @ shift.translation + shift.growth) > 0.5 * width[s] + 0.5)
    return out
