"""Options and result of the image refinement of one roof (section ``[refine]``; Marcato & Dal Poz).

:class:`RefineOptions` holds every option of the refinement (``[mrf]``,
``[ga]``, ``[candidates]`` and ``[harris]`` nest in it);
:class:`BuildingRefinement` is what :func:`rooftrace.refine.building.refine_building`
returns for one building.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from shapely.geometry import Polygon

from rooftrace.grouping.ga import GAOptions
from rooftrace.grouping.mrf import MRFOptions
from rooftrace.options import make_options, optional

__all__ = ["RefineOptions", "BuildingRefinement", "keep_input"]



@dataclass(frozen=True)
class RefineOptions:
    """Options of the image refinement (section ``[refine]``; ``[mrf]`` and ``[ga]`` nest here).

    Attributes
    ----------
    junction_tolerance : float, default 1.0
        Plan distance (m) joining ridge ends to outline vertices, sides and
        each other (topology; ours).
    simplify_tolerance : float or None, default 0
        Douglas-Peucker tolerance (m, plan) applied to the LiDAR outline
        first, so that vertices that hardly change its shape do not become
        sides of their own; None (``"auto"`` in a config file): half the
        image GSD.  Off by default: on the pipeline's outlines it cost accuracy (mean PoLiS 0.107 m with
        None, 0.099 m without, 12 pts/m², benchmarks/bench_refine.py).
    min_side_px : float, default 6
        Sides projecting shorter than this (px) keep their projected line
        as their only candidate (ours: a few pixels of edge fix no direction).
    ridges_on_planes : bool, default True
        Move ridge points only along the intersection of their two LiDAR
        roof planes (ours; see :func:`rooftrace.grouping.ridge_lines`).
    fuse : bool, default True
        Fuse each refined vertex with its projected LiDAR vertex by least
        squares (:func:`fuse_positions`; ours).  False: the image alone, as
        in Marcato & Dal Poz.
    derive_sigma : bool, default True
        With LiDAR points, take each roof's planimetric precision as half
        its mean point spacing (for the candidate windows, registration
        errors and the fusion) instead of a fixed ``candidates.sigma_xy``.
    lidar_sigma_spacing : float, default 0.5
        That precision as a fraction of the mean point spacing.
    image_sigma_px : float, default 0.7
        Precision of a vertex from image lines (px), measured on the
        simulated scenes of benchmarks/bench_refine.py.
    carry_shift_px : float, default 1.0
        When the median shift of the image-supported vertices from their
        projections exceeds this (px) and twice their median deviation from
        it (a camera or LiDAR offset, not edge noise), the vertices without
        image support move by it too.
    lidar_sigma : float, default 0.48
        Planimetric precision (m) of LiDAR outline vertices when it cannot
        be derived (Marcato & Dal Poz §3); :func:`rooftrace.refine.refine_buildings`
        derives half the mean point spacing of each roof from its points.
    plane_tolerance : float, default 0.5
        Largest vertical distance (m) of a LiDAR vertex to the roof plane it
        is re-projected onto; beyond it, a horizontal plane (ours).
    max_shift_k, max_shift_margin_px : float, default 3.0, 3.0
        A reconstructed vertex may move at most ``k · e + margin`` px from its
        projection, e the largest registration error of its lines (the
        candidate windows' own size, so a vertex cannot leave them).
    max_move : float, default 5.0
        Largest planimetric move (m) of a vertex in object space.
    solver : {'ga', 'exact'}, default 'ga'
        Whose labelling is used: the seed's genetic algorithm, or the exact
        minimum when it could be computed.
    exact_max_table : int, default 4194304
        Largest table of the exact minimiser (entries); 0 switches it off.
    context : float, default 10.0
        Margin (m) around a building within which LiDAR points are used for
        the terrain-line filter.
    wall_penalty : float, default 5.0
        Energy added to a candidate marked as the foot of a visible wall
        with the roof edge inward of it (ours; needs ``ground_z``, see
        :func:`rooftrace.image.walls.wall_strips`); 0 switches it off.
        Five times the largest unary term of Marcato & Dal Poz (``w_length`` · 1 for
        a candidate as long as its side): the roof edge wins unless the
        pairwise terms strongly disagree.
    register : bool, default True
        Measure the proximity term (Marcato & Dal Poz eq. 7-8) against the projected
        lines moved by the roof's common image shift, estimated from the
        candidates (:func:`rooftrace.grouping.registration.estimate_shift`;
        ours) and weighed against the camera's orientation error (its EO
        covariance): a camera without covariance moves nothing.
    grow : bool, default True
        Move the sides that keep their projected LiDAR line, and the
        vertices without image support, outward by the roof's common growth
        ``b`` (px), estimated from the sides that have image lines with the
        translation fixed at its camera-weighed value
        (:meth:`rooftrace.grouping.registration.RoofShift.shrunk`); needs
        ``register``.  A LiDAR outline lies inside the true one by about
        half a point spacing; without it those sides stay there (mean PoLiS
        0.1228 m instead of 0.0964 m at 2 pts/m², seeds 1-5 of
        benchmarks/bench_refine.py; ours).
    orientation : bool, default True
        Correct the camera's exterior orientation from the lines the
        grouping matched (:func:`rooftrace.grouping.orientation.correct_orientation`,
        over all buildings at once), then refine again with the corrected
        camera (ours; frame cameras only).  With ``orientation_parameters``
        'auto' only a camera with an ``exterior_covariance`` is corrected:
        one without is taken as exact, as everywhere else in the refinement.
    orientation_rounds : int, default 1
        Rounds of matching, correction and refinement.
    orientation_parameters : {'auto', 'full', 'reduced'}, default 'auto'
        Parameters corrected: all six (its covariance as the prior), or
        forced, even for a camera without covariance: ``'full'`` all six,
        ``'reduced'`` ``X0, Y0, Z0, kappa`` (see
        :func:`~rooftrace.grouping.orientation.correct_orientation`).
    orientation_min_lines : int, default 12
        Fewest matched image lines (and inliers) to correct the orientation;
        with fewer the camera is kept (a warning says so).
    register_max_px : float, default 12.0
        Largest shift searched (px); the search radius is otherwise
        ``max_shift_k · e + 1`` with ``e`` the largest registration error.
    terrain_filter : bool, default False
        Remove candidate lines lying on the terrain (Marcato & Dal Poz §2.1) when
        LiDAR points are given.  Off by default: on the simulated scenes of
        benchmarks/bench_refine.py it removed true roof edges next to the
        ground (mean PoLiS 0.160 m with it, 0.139 m without, at 2 pts/m²;
        1.55 px vs 0.81 px with a 3 px camera error).
    mrf, ga : MRFOptions, GAOptions
        Energy and optimiser (a TOML ``[mrf]`` / ``[ga]`` table, see
        :meth:`from_config`).
    """

    section = "refine"

    junction_tolerance: float = 1.0
    simplify_tolerance: float | None = optional(0.0, none="auto")
    min_side_px: float = 6.0
    ridges_on_planes: bool = True
    fuse: bool = True
    derive_sigma: bool = True
    lidar_sigma_spacing: float = 0.5
    image_sigma_px: float = 0.7
    carry_shift_px: float = 1.0
    lidar_sigma: float = 0.48
    plane_tolerance: float = 0.5
    max_shift_k: float = 3.0
    max_shift_margin_px: float = 3.0
    max_move: float = 5.0
    solver: str = "ga"
    exact_max_table: int = 2**22
    context: float = 10.0
    terrain_filter: bool = False
    wall_penalty: float = 5.0
    register: bool = True
    grow: bool = True
    orientation: bool = True
    orientation_rounds: int = 1
    orientation_parameters: str = "auto"
    orientation_min_lines: int = 12
    register_max_px: float = 12.0
    mrf: MRFOptions = field(default_factory=MRFOptions)
    ga: GAOptions = field(default_factory=GAOptions)
    candidates: object = None
    corners: object = None

    def __post_init__(self) -> None:
        if isinstance(self.mrf, dict):
            object.__setattr__(self, "mrf", MRFOptions(**self.mrf))
        if isinstance(self.ga, dict):
            object.__setattr__(self, "ga", GAOptions(**self.ga))
        if self.solver not in ("ga", "exact"):
            raise ValueError(f"refine.solver must be 'ga' or 'exact', got {self.solver!r}")
        for name in ("junction_tolerance", "plane_tolerance", "max_move", "context"):
            if not getattr(self, name) > 0:
                raise ValueError(f"refine.{name} must be > 0, got {getattr(self, name)!r}")
        if not (self.image_sigma_px > 0 and self.lidar_sigma > 0):
            raise ValueError("refine.image_sigma_px and refine.lidar_sigma must be > 0")
        if self.simplify_tolerance is not None and self.simplify_tolerance < 0:
            raise ValueError(f"refine.simplify_tolerance must be >= 0, got {self.simplify_tolerance!r}")
        if not self.wall_penalty >= 0:
            raise ValueError(f"refine.wall_penalty must be >= 0, got {self.wall_penalty!r}")
        if self.orientation_parameters not in ("auto", "full", "reduced"):
            raise ValueError("refine.orientation_parameters must be 'auto', 'full' or 'reduced', "
                             f"got {self.orientation_parameters!r}")
        if self.orientation_rounds < 1 or self.orientation_min_lines < 3:
            raise ValueError("refine.orientation_rounds must be >= 1 and refine.orientation_min_lines >= 3, got "
                             f"{self.orientation_rounds!r} and {self.orientation_min_lines!r}")
        if self.max_shift_k < 0 or self.max_shift_margin_px < 0 or self.exact_max_table < 0:
            raise ValueError("refine.max_shift_k, max_shift_margin_px and exact_max_table must be >= 0")

    @classmethod
    def from_config(cls, config: dict | None = None, **overrides) -> RefineOptions:
        """Options from a parsed TOML config: ``[refine]``, ``[mrf]``, ``[ga]``, ``[candidates]``, ``[harris]``."""
        from rooftrace.image.candidates import CandidateOptions
        from rooftrace.image.corners import HarrisOptions

        config = config or {}
        nested = {"mrf": make_options(MRFOptions, config), "ga": make_options(GAOptions, config),
                  "candidates": make_options(CandidateOptions, config),
                  "corners": make_options(HarrisOptions, config)}
        return make_options(cls, config, **{**nested, **overrides})


@dataclass
class BuildingRefinement:
    """The refinement of one building.

    ``outline`` and ``ridges`` are in object space; ``image_outline`` (V, 2),
    ``references`` (M, 2, 2), ``selected`` (M, 2, 2) and ``candidate_sets``
    (M arrays (K_s, 2, 2)) are pixels, one per topology line (``kinds``),
    kept for diagnostics and evaluation.  ``lines3d`` (M, 2, 3) are the
    LiDAR lines (m), ``outward`` (M, 2) the outward image normals of the
    outline sides (NaN for ridges) and ``image_chosen`` (M,) bool tells the
    lines whose selected line is an image line: the matches the orientation
    correction uses, with ``lidar_sigma_px`` the LiDAR outline's planimetric
    precision in pixels.
    """

    outline: Polygon
    ridges: list
    ridge_refined: list
    status: str
    candidates_per_side: list = field(default_factory=list)
    refined_sides: list = field(default_factory=list)
    energy: float = float("nan")
    exact_energy: float = float("nan")
    ga_exact_gap: float = float("nan")
    choice: np.ndarray | None = None
    image_outline: np.ndarray | None = None
    kinds: tuple = ()
    ring_sizes: tuple = ()
    references: np.ndarray | None = None
    selected: np.ndarray | None = None
    candidate_sets: list = field(default_factory=list)
    seconds: float = float("nan")
    image_shift: tuple = ()
    lines3d: np.ndarray | None = None
    outward: np.ndarray | None = None
    image_chosen: np.ndarray | None = None
    lidar_sigma_px: float = float("nan")


def keep_input(outline, ridges, status: str) -> BuildingRefinement:
    """The refinement of a building left as it was, with the reason in ``status``."""
    return BuildingRefinement(outline, list(ridges), [False] * len(ridges), status)
