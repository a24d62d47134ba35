"""Candidate image lines for every projected roof outline side and ridge (Marcato & Dal Poz §2.1, Marcato & Dal Poz 2011).

For each 3D line:

1. project it and propagate its registration error
   (:func:`~rooftrace.image.projection.project_lines`);
2. open a window around it (:func:`~rooftrace.image.projection.line_windows`);
3. detect Canny step edges and Steger lines in the window, link them into
   chains and split the chains into straight, sub-pixel segments;
4. choose between Canny and Steger (Marcato & Dal Poz 2011: 3 deg, 4 px, 1 px; by
   default the rule's Steger lines are added and the Canny lines kept);
5. remove terrain lines when LiDAR points are given (Marcato & Dal Poz);
6. merge collinear fragments (9 deg, 3 px);
6b. re-locate each candidate at the sub-pixel gradient maxima across it,
   with a robust line fit (:func:`~rooftrace.image.refit.refit_lines`, ours);
6c. beside a visible wall, look for the roof edge inward of each line and
   mark the outer line of each roof-edge/wall-foot pair
   (:func:`~rooftrace.image.walls.mark_wall_lines`, ours);
7. keep candidates of at least 15 % of the projected length within 20 deg
   of its direction (Marcato & Dal Poz); a line left without candidates keeps its
   projection as the only one (source ``'projected'``).

Pixel coordinates are ``(col, row)`` with pixel centres at integers.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rooftrace.image.edges import canny_edges, link_chains, noise_sigma
from rooftrace.image.linework import filter_candidates, fit_segments, merge_collinear, select_canny_steger
from rooftrace.image.projection import (
    clip_to_window,
    in_window,
    line_windows,
    project_lines,
    window_frame,
    window_slices,
)
from rooftrace.image.refit import refit_lines
from rooftrace.image.steger import steger_lines, steger_sigma
from rooftrace.image.terrain import PixelHeights, sample_segments, terrain_lines
from rooftrace.image.walls import mark_wall_lines

__all__ = ["CandidateOptions", "LineCandidates", "extract_candidates", "KINDS"]

log = logging.getLogger(__name__)

#: the kinds of 3D lines
KINDS = ("outline", "ridge")


@dataclass(frozen=True)
class CandidateOptions:
    """Options of the candidate extraction (section ``[candidates]``).

    Attributes
    ----------
    sigma_xy, sigma_z : float, default 0.48, 0.15
        LiDAR planimetric / altimetric precision (m), Marcato & Dal Poz §3.
    window_k : float, default 3.0
        Window half-width and end extension in registration errors (ours).
    window_margin : float, default 3.0
        Extra window half-width (px, ours).
    canny_sigma : float, default 1.0
        Canny's Gaussian scale (px).
    canny_low, canny_high : float or None
        Canny hysteresis thresholds (grey / px); ``None``: derived from
        ``min_contrast`` and the window's noise (see
        :func:`~rooftrace.image.edges.canny_edges`).
    steger_sigma : float or None
        Steger's scale (px); ``None``: ``max(line_width / (2 sqrt 3), 1)``
        (Steger's condition sigma >= w / sqrt 3, Marcato & Dal Poz 2011).
    steger_low, steger_high : float or None
        Steger hysteresis thresholds (grey / px^2); ``None``: derived (see
        :func:`~rooftrace.image.steger.steger_lines`).
    line_width : float, default 4.0
        Expected full width of ridge lines (px).
    steger_bias_correction : bool, default False
        Remove the asymmetric-contrast bias of Steger's line centres (Marcato & Dal Poz 2011
        eq. 11) with the bar model fitted to each point's two edges.
    min_contrast : float, default 0.05
        Weakest step or bar (grey levels in [0, 1]) that may seed a detection.
    split_tolerance : float, default 1.0
        Largest deviation of a chain from its straight piece (px).
    min_segment : float, default 5.0
        Shortest detected segment (px).
    selection : {'both', 'seed003', 'canny'}, default 'both'
        Canny/Steger choice (see :func:`~rooftrace.image.linework.select_canny_steger`):
        the rule's Steger lines added to all Canny lines, the seed's rule
        (flanking Canny pairs replaced), or Canny only.  ``'both'`` is the
        default because it measured better (docs/design-notes.md, "Image
        line candidates"): more true sides and ridges among the candidates,
        and refined outlines with PoLiS 0.116 m against 0.130 m for the
        seed's rule in ``bench_refine.py``.
    select_angle, select_separation, select_equidistance : float, default 3.0, 4.0, 1.0
        Canny/Steger selection tolerances (deg, px, px), Marcato & Dal Poz 2011 §3.
    merge_angle, merge_distance : float, default 9.0, 3.0
        Collinear merging tolerances (deg, px), issue 7.
    min_length_fraction : float, default 0.15
        Shortest candidate as a fraction of the projected length, Marcato & Dal Poz §2.1.
    max_angle : float, default 20.0
        Largest angle to the projected line (deg), Marcato & Dal Poz §2.1.
    terrain_height_tolerance : float, default 1.0
        Metres below the lowest roof edge that make a line terrain-compatible (ours).
    refit : bool, default True
        Re-locate merged candidates on the gradient at ``refit_sigma``
        (:func:`~rooftrace.image.refit.refit_lines`, ours): straightens
        fragments of two edges merged into one tilted line and removes the
        outward pull of a thin wall strip.  False: the seeds' lines as found.
    refit_sigma, refit_search : float, default 0.7, 2.0
        Derivative scale (px) and search half-length across the line (px)
        of the refit.
    wall_lines : bool, default True
        With predicted wall widths (``wall_width`` of
        :func:`extract_candidates`), search the roof edge inward of lines
        beside a visible wall and mark wall feet (ours).
    wall_min_px, wall_margin : float, default 1.0, 1.5
        Narrowest visible wall (px) that is searched; tolerance (px) on its
        predicted width.
    """

    section = "candidates"

    sigma_xy: float = 0.48
    sigma_z: float = 0.15
    window_k: float = 3.0
    window_margin: float = 3.0
    canny_sigma: float = 1.0
    canny_low: float | None = None
    canny_high: float | None = None
    steger_sigma: float | None = None
    steger_low: float | None = None
    steger_high: float | None = None
    line_width: float = 4.0
    steger_bias_correction: bool = False
    min_contrast: float = 0.05
    split_tolerance: float = 1.0
    min_segment: float = 5.0
    selection: str = "both"
    select_angle: float = 3.0
    select_separation: float = 4.0
    select_equidistance: float = 1.0
    merge_angle: float = 9.0
    merge_distance: float = 3.0
    min_length_fraction: float = 0.15
    max_angle: float = 20.0
    terrain_height_tolerance: float = 1.0
    refit: bool = True
    refit_sigma: float = 0.7
    refit_search: float = 2.0
    wall_lines: bool = True
    wall_min_px: float = 1.0
    wall_margin: float = 1.5

    def __post_init__(self):
        positive = ("sigma_xy", "sigma_z", "canny_sigma", "line_width", "split_tolerance", "refit_sigma",
                    "refit_search")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"candidates.{name} must be positive, got {getattr(self, name)}")
        non_negative = ("wall_min_px", "wall_margin", "window_k", "window_margin", "min_contrast", "min_segment", "select_angle",
                        "select_separation", "select_equidistance", "merge_angle", "merge_distance",
                        "min_length_fraction", "max_angle", "terrain_height_tolerance")
        for name in non_negative:
            if not getattr(self, name) >= 0:
                raise ValueError(f"candidates.{name} must be >= 0, got {getattr(self, name)}")
        if self.steger_sigma is not None and not self.steger_sigma > 0:
            raise ValueError(f"candidates.steger_sigma must be positive, got {self.steger_sigma}")
        if self.selection not in ("seed003", "both", "canny"):
            raise ValueError(f"candidates.selection must be 'seed003', 'both' or 'canny', got {self.selection!r}")
        if self.max_angle > 90:
            raise ValueError(f"candidates.max_angle must be at most 90 degrees, got {self.max_angle}")


@dataclass
class LineCandidates:
    """The candidate image lines of one projected outline side or ridge.

    Attributes
    ----------
    reference : ndarray of shape (2, 2)
        Projected endpoints (col, row).
    registration_error : float
        Registration error (px), the larger of the two endpoints'.
    window : ndarray of shape (4, 2)
        Corner pixels (col, row) of the search rectangle.
    candidates : ndarray of shape (K, 2, 2)
        Candidate segments (col, row), K >= 1.
    source : list of str
        Per candidate: ``'canny'``, ``'steger'``, ``'merged'`` or ``'projected'``.
    kind : str
        ``'outline'`` or ``'ridge'``.
    projected_only : bool
        True when nothing survived and the projected line is the only candidate.
    wall : ndarray of shape (K,) bool
        Per candidate: the foot of a visible wall (or a line beyond it) with
        a roof edge found inward of it (:func:`~rooftrace.image.walls.mark_wall_lines`).
    """

    reference: np.ndarray
    registration_error: float
    window: np.ndarray
    candidates: np.ndarray
    source: list[str] = field(default_factory=list)
    kind: str = "outline"
    projected_only: bool = False
    wall: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


def _detect(crop: np.ndarray, mask: np.ndarray, opt: CandidateOptions):
    """Canny and Steger segments (crop pixel coordinates) inside the window mask.

    Canny runs on the colour crop when there is one; Steger on its grey mean.
    """
    grey = crop if crop.ndim == 2 else crop.mean(axis=2)
    edges, epts = canny_edges(crop, opt.canny_sigma, opt.canny_low, opt.canny_high,
                              min_contrast=opt.min_contrast, mask=mask)
    lines, lpts = steger_lines(grey, opt.steger_sigma, opt.steger_low, opt.steger_high, line_width=opt.line_width,
                               min_contrast=opt.min_contrast, mask=mask, correct_bias=opt.steger_bias_correction)
    canny = fit_segments(link_chains(edges, epts), opt.split_tolerance, opt.min_segment)
    steger = fit_segments(link_chains(lines, lpts), opt.split_tolerance, opt.min_segment)
    return canny, steger


def extract_candidates(
    image: np.ndarray,
    camera,
    lines3d,
    kinds: Sequence[str],
    *,
    points_xyz: np.ndarray | None = None,
    building_xyz: np.ndarray | None = None,
    wall_width: np.ndarray | None = None,
    outward: np.ndarray | None = None,
    options: CandidateOptions | None = None,
) -> list[LineCandidates]:
    """Candidate image lines for each 3D outline side and ridge of one building.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, C) float64
        Grey image in [0, 1], indexed [row, col]; or a colour image
        (channels last), whose colour edges Canny also sees (roof and ground
        of equal brightness but different colour).
    camera : FrameCamera or OrthoCamera
    lines3d : ndarray of shape (M, 2, 3) float64
        Object-space segments (outline sides and ridges), CRS units.
    kinds : sequence of str, length M
        ``'outline'`` or ``'ridge'`` per line.
    points_xyz : ndarray of shape (P, 3), optional
        LiDAR points (all classes) for the terrain-line filter; ``None``
        skips the filter.
    building_xyz : ndarray of shape (Q, 3), optional
        The building's own points (where the building is, for the terrain
        filter); ``None`` uses samples along its projected lines.
    wall_width, outward : ndarray of shape (M,) and (M, 2), optional
        Predicted visible wall width (px) and outward image normal per line
        (:func:`~rooftrace.image.walls.wall_strips`); ``None`` skips the
        wall step.
    options : CandidateOptions, optional

    Returns
    -------
    list of LineCandidates
        One per input line, in order; each has at least one candidate.

    Notes
    -----
    The Marcato & Dal Poz 2011 test runs in every window: outline sides are usually step
    edges (Canny keeps them), ridges usually lines (a Steger line flanked by
    Canny's double response); each kind can show either profile.  With
    ``selection='seed003'`` the Steger line replaces the flanking pair, as in
    the paper; the default keeps both and leaves the choice to the grouping.

    Examples
    --------
    >>> from rooftrace.image.camera import FrameCamera
    >>> cam = FrameCamera((200, 200), 0.01, 100.0, np.array([0, 0, 1000.0, 0, 0, 0]))
    >>> img = np.zeros((200, 200)); img[60:140, 60:140] = 0.8      # a roof, 8 m x 8 m at 0.1 m
    >>> line = np.array([[[-3.0, 4.2, 0.0], [3.0, 4.2, 0.0]]])   # north side, 0.2 m off
    >>> out = extract_candidates(img, cam, line, ["outline"])
    >>> out[0].reference[:, 1].tolist()                            # projected 2 px off
    [57.5, 57.5]
    >>> out[0].source, out[0].candidates[:, :, 1].round(1).tolist()   # the edge, rows 59 | 60
    (['canny'], [[59.5, 59.5]])
    """
    opt = options or CandidateOptions()
    img = np.asarray(image, float)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] > 4):
        raise ValueError(f"image must be grey (H, W) or colour (H, W, C), got shape {img.shape}")
    lines = np.asarray(lines3d, float).reshape(-1, 2, 3) if np.size(lines3d) else np.zeros((0, 2, 3))
    kinds = list(kinds)
    if len(kinds) != len(lines):
        raise ValueError(f"kinds has {len(kinds)} entries for {len(lines)} lines")
    bad = sorted({k for k in kinds if k not in KINDS})
    if bad:
        raise ValueError(f"kinds must be 'outline' or 'ridge', got {bad}")
    if not len(lines):
        return []
    reference, error = project_lines(camera, lines, sigma_xy=opt.sigma_xy, sigma_z=opt.sigma_z)
    windows = line_windows(reference, error, opt.window_k, opt.window_margin)
    s_max = max(opt.canny_sigma, opt.steger_sigma or steger_sigma(opt.line_width))
    pad = int(np.ceil(4 * s_max)) + 2

    heights = bld_cr = None
    if points_xyz is not None and len(points_xyz):
        lo, hi = windows.reshape(-1, 2).min(0) - pad, windows.reshape(-1, 2).max(0) + pad
        heights = PixelHeights(camera, points_xyz, (lo[0], lo[1], hi[0], hi[1]),
                               sigma_xy=opt.sigma_xy, sigma_z=opt.sigma_z)
        if building_xyz is not None and len(building_xyz):
            bld_cr = camera.project(np.asarray(building_xyz, float).reshape(-1, 3))
            bld_cr = bld_cr[np.isfinite(bld_cr).all(axis=1)]
        else:
            bld_cr, _ = sample_segments(reference)
        is_outline = np.array([k == "outline" for k in kinds])
        z_edge = float(lines[is_outline, :, 2].min() if is_outline.any() else lines[:, :, 2].min())

    out = []
    for i in range(len(lines)):
        ref, win = reference[i], windows[i]
        found = np.zeros((0, 2, 2))
        sources: list[str] = []
        wall = np.zeros(0, bool)
        # a line seen end-on (shorter than a pixel) has no direction to search along
        usable = np.isfinite(ref).all() and np.hypot(*(ref[1] - ref[0])) >= 1.0
        sl = window_slices(win, img.shape[:2], pad) if usable else None
        if sl is not None:
            crop = img[sl]
            r0, c0 = sl[0].start, sl[1].start
            rows, cols = np.indices(crop.shape[:2])
            inside = in_window(np.column_stack([cols.ravel() + c0, rows.ravel() + r0]), win).reshape(crop.shape[:2])
            if inside.any():
                canny, steger = _detect(crop, inside, opt)
                found, sources = select_canny_steger(canny, steger, opt.select_angle, opt.select_separation,
                                                     opt.select_equidistance, mode=opt.selection)
                found = found + [c0, r0]
                if heights is not None and len(found):
                    drop = terrain_lines(found, heights, bld_cr, z_edge, opt.terrain_height_tolerance)
                    found = found[~drop]
                    sources = [s for s, d in zip(sources, drop) if not d]
                found, sources = merge_collinear(found, sources, opt.merge_angle, opt.merge_distance)
                if opt.refit and len(found):
                    # only the part beside the side counts: past its ends a line is usually another
                    # building's edge, collinear within the merge tolerance, that would tilt the fit
                    p0, u, nrm, length = window_frame(ref)
                    m, h = float(error[i]) + 1.0, 1e6
                    box = np.array([p0 - m * u - h * nrm, p0 + (length + m) * u - h * nrm,
                                    p0 + (length + m) * u + h * nrm, p0 - m * u + h * nrm])
                    found, kept = clip_to_window(found, box)
                    sources = [s for s, k in zip(sources, kept) if k]
                    grey = crop if crop.ndim == 2 else crop.mean(axis=2)
                    # step edges only: a Steger line is the centre of a bar, between two opposite steps
                    step = np.array([s != "steger" for s in sources], bool)
                    # a step of half the weakest contrast Canny may seed on, at the refit's scale
                    floor = 0.5 * opt.min_contrast / (np.sqrt(2 * np.pi) * np.hypot(opt.refit_sigma, 0.5))
                    found[step] = refit_lines(grey, found[step] - [c0, r0], opt.refit_sigma, opt.refit_search,
                                              min_strength=floor)[0] + [c0, r0]
                    # two fragments refitted onto one edge are one candidate
                    found, sources = merge_collinear(found, sources, 3.0, 0.5, duplicate_tol=0.5)
                if (opt.wall_lines and wall_width is not None and outward is not None and len(found)
                        and wall_width[i] >= opt.wall_min_px):
                    grey = crop if crop.ndim == 2 else crop.mean(axis=2)
                    found, sources, wall = mark_wall_lines(grey, found - [c0, r0], sources, outward[i],
                                                           float(wall_width[i]), sigma=opt.refit_sigma,
                                                           noise=noise_sigma(grey), margin=opt.wall_margin)
                    found = found + [c0, r0]
                else:
                    wall = np.zeros(len(found), bool)
                # a merged line's ends may stick out of the window by a fraction of a pixel
                found, inside_win = clip_to_window(found, win)
                sources = [s for s, k in zip(sources, inside_win) if k]
                wall = wall[inside_win]
                keep = filter_candidates(found, ref, opt.min_length_fraction, opt.max_angle)
                found, wall = found[keep], wall[keep]
                sources = [s for s, k in zip(sources, keep) if k]
        projected_only = len(found) == 0
        if projected_only:
            found, sources = ref[None].copy(), ["projected"]
        wall = wall if not projected_only else np.zeros(1, bool)
        out.append(LineCandidates(ref.copy(), float(error[i]), win, found, sources, kinds[i], projected_only, wall))
    log.debug("candidates: %d lines, %d candidates, %d projected only", len(out),
              sum(len(c.candidates) for c in out), sum(c.projected_only for c in out))
    return out
