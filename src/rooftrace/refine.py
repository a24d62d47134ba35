"""Image refinement of LiDAR roofs (seed 000): candidates -> MRF grouping -> reconstruction -> 3D.

For each building:

1. the roof's line topology (outline sides + ridges, :func:`roof_topology`);
2. candidate image lines per side/ridge in windows around their projections
   (:func:`rooftrace.image.candidates.extract_candidates`, seed 000 §2.1 and
   seed 003) and Harris corners in those windows;
3. the MRF energy (eq. 6-13) minimised by the genetic algorithm (§2.3); the
   exact minimiser runs too when the problem is small enough and the gap
   between the two is reported (``ga_exact_gap``);
4. reconstruction of the selected lines along the projected topology (§2.4);
5. back to object space: each refined pixel's ray meets the roof plane of its
   vertex (or a horizontal plane through the LiDAR vertex).

A building that cannot be refined keeps its input geometry; ``refine_status``
says why.  No I/O here: the CLI and the pipeline read and write.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import shapely
from scipy.spatial import cKDTree
from shapely.geometry import LineString, Polygon

from rooftrace import config as _config
from rooftrace.errors import GeometryError
from rooftrace.grouping import (
    GAOptions, MRFOptions, build_problem, exact_minimise, genetic_minimise, junction_planes, reconstruct_image,
    ridge_lines, roof_topology, to_object_space,
)

__all__ = ["RefineOptions", "RefineResult", "BuildingRefinement", "refine_building", "refine_buildings",
           "assign_ridges"]

log = logging.getLogger(__name__)

_config.KNOWN_SECTIONS.update({"refine", "mrf", "ga"})


@dataclass(frozen=True)
class RefineOptions:
    """Options of the image refinement (section ``[refine]``; ``[mrf]`` and ``[ga]`` nest here).

    Attributes
    ----------
    junction_tolerance : float, default 1.0
        Plan distance (m) joining ridge ends to outline vertices, sides and
        each other (topology; ours).
    simplify_tolerance : float or None, default None
        Douglas-Peucker tolerance (m, plan) applied to the LiDAR outline
        first, so that vertices that do not change its shape do not become
        sides of their own; None: half the image GSD (ours).
    min_side_px : float, default 6
        Sides projecting shorter than this (px) keep their projected line
        as their only candidate (ours: a few pixels of edge fix no direction).
    ridges_on_planes : bool, default True
        Move ridge points only along the intersection of their two LiDAR
        roof planes (ours; see :func:`rooftrace.grouping.ridge_lines`).
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
    terrain_filter : bool, default False
        Remove candidate lines lying on the terrain (seed 000 §2.1) when
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
    simplify_tolerance: float | None = None
    min_side_px: float = 6.0
    ridges_on_planes: bool = True
    plane_tolerance: float = 0.5
    max_shift_k: float = 3.0
    max_shift_margin_px: float = 3.0
    max_move: float = 5.0
    solver: str = "ga"
    exact_max_table: int = 2**22
    context: float = 10.0
    terrain_filter: bool = False
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
        if self.simplify_tolerance is not None and self.simplify_tolerance < 0:
            raise ValueError(f"refine.simplify_tolerance must be >= 0, got {self.simplify_tolerance!r}")
        if self.max_shift_k < 0 or self.max_shift_margin_px < 0 or self.exact_max_table < 0:
            raise ValueError("refine.max_shift_k, max_shift_margin_px and exact_max_table must be >= 0")

    @classmethod
    def from_config(cls, config: dict | None = None, **overrides) -> "RefineOptions":
        """Options from a parsed TOML config: ``[refine]``, ``[mrf]``, ``[ga]``, ``[candidates]``, ``[corners]``."""
        from rooftrace.image.candidates import CandidateOptions
        from rooftrace.image.corners import HarrisOptions

        config = config or {}
        nested = {"mrf": _config.make_options(MRFOptions, config), "ga": _config.make_options(GAOptions, config),
                  "candidates": _config.make_options(CandidateOptions, config),
                  "corners": _config.make_options(HarrisOptions, config)}
        return _config.make_options(cls, config, **{**nested, **overrides})


@dataclass
class BuildingRefinement:
    """The refinement of one building.

    ``outline`` and ``ridges`` are in object space; ``image_outline`` (V, 2),
    ``references`` (M, 2, 2), ``selected`` (M, 2, 2) and ``candidate_sets``
    (M arrays (K_s, 2, 2)) are pixels, one per topology line (``kinds``),
    kept for diagnostics and evaluation.
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


@dataclass
class RefineResult:
    """Refined roofs of many buildings, ready for the output layers.

    Attributes
    ----------
    outlines : list of Polygon with Z
        One per input outline, in input order (input geometry when not refined).
    ridges : list of LineString with Z
        Every input ridge, in input order.
    attributes : dict of str to list
        Per building: ``building_id``, ``refine_status``,
        ``candidates_per_side`` (e.g. "2,1,3,1"), ``refined_sides`` (1 =
        replaced by an image line, 0 = kept), ``n_sides``, ``n_refined``,
        ``refine_energy``, ``exact_energy`` and ``ga_exact_gap`` (NaN when
        the exact minimiser did not run).
    ridge_attributes : dict of str to list
        Per ridge: ``building_id``, ``kind``, ``refined`` (0/1).
    buildings : list of BuildingRefinement
    """

    outlines: list
    ridges: list
    attributes: dict
    ridge_attributes: dict
    buildings: list

    @property
    def ridge_building_ids(self) -> list:
        return list(self.ridge_attributes["building_id"])

    def summary(self) -> dict:
        statuses: dict[str, int] = {}
        for s in self.attributes["refine_status"]:
            statuses[s] = statuses.get(s, 0) + 1
        gaps = np.array(self.attributes["ga_exact_gap"], float)
        ran = np.isfinite(gaps)
        return {"buildings": len(self.outlines), "status": statuses, "ridges": len(self.ridges),
                "sides": int(sum(self.attributes["n_sides"])), "sides_refined": int(sum(self.attributes["n_refined"])),
                "exact_checked": int(ran.sum()), "ga_reached_exact": int((gaps[ran] <= 1e-9).sum())}


def _inside_image(camera, cr: np.ndarray) -> bool:
    w, h = camera.image_size
    return bool(np.isfinite(cr).all() and (cr[:, 0] >= 0).all() and (cr[:, 0] <= w - 1).all()
                and (cr[:, 1] >= 0).all() and (cr[:, 1] <= h - 1).all())


def _rings(xyz: np.ndarray, sizes) -> Polygon:
    bounds = np.cumsum((0,) + tuple(sizes))
    return Polygon(xyz[: bounds[1]], [xyz[a:b] for a, b in zip(bounds[1:-1], bounds[2:])])


def _acceptable(refined: Polygon, outline) -> bool:
    """Valid in plan, and its area within a factor 2 of the LiDAR outline's."""
    flat = shapely.force_2d(refined)
    return bool(flat.is_valid and 0.5 <= flat.area / max(shapely.force_2d(outline).area, 1e-12) <= 2.0)


def _kept(outline, ridges, status: str) -> BuildingRefinement:
    return BuildingRefinement(outline, list(ridges), [False] * len(ridges), status)


def refine_building(outline, ridges, image: np.ndarray, camera, *, points_xyz: np.ndarray | None = None,
                    building_xyz: np.ndarray | None = None, planes: np.ndarray | None = None,
                    options: RefineOptions | None = None, seed: int = 0, candidates: list | None = None,
                    corners: np.ndarray | None = None) -> BuildingRefinement:
    """Refine one roof with the image.

    Parameters
    ----------
    outline : Polygon with Z
        LiDAR roof outline (map CRS, m).
    ridges : sequence of LineString with Z
        Its ridges.
    image : ndarray of shape (H, W) float
        Grey image in [0, 1].
    camera : FrameCamera or OrthoCamera
    points_xyz, building_xyz : ndarray of shape (N, 3), optional
        LiDAR points around the building / on it (terrain-line filter).
    planes : ndarray of shape (K, 4), optional
        Roof planes (a, b, c, d), c > 0; None: horizontal planes through the
        LiDAR vertices.
    options : RefineOptions, optional
    seed : int, default 0
        Seed of the genetic algorithm.
    candidates : list of LineCandidates, optional
        Precomputed candidates, one per topology line (skips the extraction).
    corners : ndarray of shape (C, 2), optional
        Precomputed Harris corners (col, row).

    Returns
    -------
    BuildingRefinement
    """
    t0 = time.perf_counter()
    opt = options or RefineOptions()
    tol = opt.simplify_tolerance if opt.simplify_tolerance is not None else 0.5 * camera.ground_sample_distance
    source_outline = outline
    if outline is not None and outline.geom_type == "Polygon" and tol > 0:
        simple = shapely.simplify(outline, tol, preserve_topology=True)
        outline = simple if simple.geom_type == "Polygon" and not simple.is_empty else outline
    try:
        topo = roof_topology(outline, ridges, opt.junction_tolerance)
    except GeometryError as exc:
        return _kept(source_outline, ridges, f"degenerate: {exc}")
    ref_points = camera.project(np.array([j.point for j in topo.junctions]))
    if not _inside_image(camera, ref_points):
        return _kept(source_outline, ridges, "outside_image")
    if candidates is None:
        from rooftrace.image.candidates import extract_candidates

        candidates = extract_candidates(image, camera, topo.lines, list(topo.kinds), points_xyz=points_xyz,
                                        building_xyz=building_xyz, options=opt.candidates)
    if len(candidates) != topo.n_lines:
        raise ValueError(f"candidates: {len(candidates)} sets for {topo.n_lines} lines")
    if corners is None:
        from rooftrace.image.corners import harris_corners

        corners = harris_corners(image, np.stack([c.window for c in candidates]), options=opt.corners)
    refs = np.stack([np.asarray(c.reference, float) for c in candidates])
    cand_sets = [np.asarray(c.candidates, float).reshape(-1, 2, 2) for c in candidates]
    image_line = [np.array([not getattr(c, "projected_only", False) and (not c.source or c.source[k] != "projected")
                            for k in range(len(cs))]) for c, cs in zip(candidates, cand_sets)]
    # a side a few pixels long has no trustworthy image line: it keeps its projection
    short = np.linalg.norm(refs[:, 1] - refs[:, 0], axis=1) < opt.min_side_px
    for s_ in np.flatnonzero(short):
        cand_sets[s_], image_line[s_] = refs[s_:s_ + 1], np.zeros(1, bool)
    problem = build_problem(refs, cand_sets, topo.pairs, corners, opt.mrf)
    ga = genetic_minimise(problem, opt.ga, seed=seed)
    exact = exact_minimise(problem, opt.exact_max_table) if opt.exact_max_table > 0 else None
    choice = exact.choice if (opt.solver == "exact" and exact is not None) else ga.choice
    selected = np.stack([cs[k] for cs, k in zip(cand_sets, choice)])

    error = np.array([c.registration_error for c in candidates], float)
    limit = np.array([opt.max_shift_k * max(error[line] for line, _ in j.members) + opt.max_shift_margin_px
                      for j in topo.junctions])
    rec = reconstruct_image(topo, selected, ref_points, limit)
    jplanes = junction_planes(topo, planes, opt.plane_tolerance)
    jlines = ridge_lines(topo, planes, opt.plane_tolerance) if opt.ridges_on_planes else None
    original = np.array([j.point for j in topo.junctions])
    xyz, ok = to_object_space(camera, rec.points, jplanes, original, opt.max_move, jlines)
    # a junction of projected lines only is the LiDAR point itself: keep it exactly
    chosen_image = np.array([image_line[s_][k] for s_, k in enumerate(choice)])
    supported = np.array([any(chosen_image[line] for line, _ in j.members) for j in topo.junctions])
    moved = rec.moved & ok & supported
    xyz = np.where(moved[:, None], xyz, original)

    # an invalid ring (tiny or crossing sides): give back the largest moves one by one
    n_out = topo.n_outline
    shift = np.linalg.norm(rec.points - ref_points, axis=1)
    refined = _rings(xyz, topo.ring_sizes)
    while not _acceptable(refined, outline) and moved[:n_out].any():
        j = int(np.argmax(np.where(moved[:n_out], shift[:n_out], -1.0)))
        moved[j], xyz[j] = False, original[j]
        refined = _rings(xyz, topo.ring_sizes)
    status = "refined" if moved.any() else "kept: no vertex moved"
    if not _acceptable(refined, outline):
        refined, status = source_outline, "kept: invalid refined outline"
        moved[:] = False
        xyz = original
    elif not moved.any():
        refined = source_outline

    end_of = {(line, end): j for j, junction in enumerate(topo.junctions) for line, end in junction.members if end >= 0}
    out_ridges, ridge_refined = [], []
    for r, ridge in enumerate(ridges):
        line = int(topo.ridge_index[r]) if r < len(topo.ridge_index) else -1
        if line < 0 or not moved.any():
            out_ridges.append(ridge)
            ridge_refined.append(False)
            continue
        j0, j1 = end_of[(line, 0)], end_of[(line, 1)]
        out_ridges.append(LineString([xyz[j0], xyz[j1]]))
        ridge_refined.append(bool(moved[j0] or moved[j1]))

    sides = [int(image_line[s_][k] and moved[end_of[(s_, 0)]] and moved[end_of[(s_, 1)]])
             for s_, k in enumerate(choice)]
    e_used = problem.energy(choice)
    return BuildingRefinement(
        refined, out_ridges, ridge_refined, status,
        candidates_per_side=[len(c) for c in cand_sets[:n_out]],
        refined_sides=sides[:n_out], energy=float(e_used),
        exact_energy=float(exact.energy) if exact is not None else float("nan"),
        ga_exact_gap=float(ga.energy - exact.energy) if exact is not None else float("nan"),
        choice=choice, image_outline=rec.points[:n_out], kinds=topo.kinds, ring_sizes=topo.ring_sizes, references=refs, selected=selected,
        candidate_sets=cand_sets, seconds=time.perf_counter() - t0)


def assign_ridges(outlines: Sequence, ridges: Sequence) -> list[int]:
    """Index of the outline holding each ridge (its midpoint in plan; nearest outline otherwise; -1 if none)."""
    polys = [shapely.force_2d(o) if o is not None else None for o in outlines]
    out = []
    for ridge in ridges:
        if ridge is None or ridge.is_empty or not polys:
            out.append(-1)
            continue
        mid = ridge.interpolate(0.5, normalized=True)
        dist = [p.distance(mid) if p is not None and not p.is_empty else np.inf for p in polys]
        out.append(int(np.argmin(dist)) if np.isfinite(min(dist)) and min(dist) < 1.0 else -1)
    return out


def refine_buildings(outlines: Sequence, ridges: Sequence, image: np.ndarray, camera, *,
                     points_xyz: np.ndarray | None = None, planes: Sequence | None = None,
                     building_ids: Sequence[int] | None = None, ridge_building_ids: Sequence[int] | None = None,
                     options: RefineOptions | None = None, seed: int = 0) -> RefineResult:
    """Refine many roofs with one image (see the module notes).

    Parameters
    ----------
    outlines : sequence of Polygon with Z
        LiDAR roof outlines, one per building (map CRS).
    ridges : sequence of LineString with Z
        All ridges of all buildings.
    image : ndarray of shape (H, W) float
        Grey image in [0, 1].
    camera : FrameCamera or OrthoCamera
        Its orientation, same CRS as the outlines.
    points_xyz : ndarray of shape (N, 3), optional
        LiDAR points (any class): terrain-line filter.
    planes : sequence of ndarray (K, 4) or None, optional
        Roof planes per building; None entries (or None) use horizontal
        planes through the LiDAR vertices.
    building_ids : sequence of int, optional
        Id of each outline (default 1..n).
    ridge_building_ids : sequence of int, optional
        Building id of each ridge; default: the outline containing it.
    options : RefineOptions, optional
    seed : int, default 0
        Seed of the genetic algorithm (building i uses ``seed + i``).

    Returns
    -------
    RefineResult
    """
    opt = options or RefineOptions()
    img = np.asarray(image, float)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D grey array (H, W), got shape {img.shape}")
    ids = list(range(1, len(outlines) + 1)) if building_ids is None else [int(i) for i in building_ids]
    if len(ids) != len(outlines):
        raise ValueError(f"building_ids has {len(ids)} entries for {len(outlines)} outlines")
    if planes is not None and len(planes) != len(outlines):
        raise ValueError(f"planes has {len(planes)} entries for {len(outlines)} outlines")
    if ridge_building_ids is None:
        owner = assign_ridges(outlines, ridges)
        ridge_ids = [ids[k] if k >= 0 else 0 for k in owner]
    else:
        ridge_ids = [int(i) for i in ridge_building_ids]
        if len(ridge_ids) != len(ridges):
            raise ValueError(f"ridge_building_ids has {len(ridge_ids)} entries for {len(ridges)} ridges")
    by_building: dict[int, list[int]] = {}
    for r, b in enumerate(ridge_ids):
        by_building.setdefault(b, []).append(r)

    pts = None if points_xyz is None or not len(points_xyz) else np.asarray(points_xyz, float).reshape(-1, 3)
    tree = cKDTree(pts[:, :2]) if pts is not None else None
    buildings: list[BuildingRefinement] = []
    new_ridges = list(ridges)
    ridge_refined = [False] * len(ridges)
    for i, (poly, bid) in enumerate(zip(outlines, ids)):
        mine = by_building.get(bid, [])
        local = inside = None
        if poly is not None and not poly.is_empty and tree is not None:
            x0, y0, x1, y1 = poly.bounds
            near = tree.query_ball_point([(x0 + x1) / 2, (y0 + y1) / 2], np.hypot(x1 - x0, y1 - y0) / 2 + opt.context)
            local = pts[np.sort(np.asarray(near, int))]
            # the building's own points would mark the true edges, which lie outside a LiDAR outline
            # shrunk by half a point spacing, as "off the building": the projected lines stand for it
            inside = None
        if not opt.terrain_filter:
            local = None
        try:
            res = refine_building(poly, [ridges[r] for r in mine], img, camera, points_xyz=local, building_xyz=inside,
                                  planes=None if planes is None else planes[i], options=opt, seed=seed + i)
        except (GeometryError, np.linalg.LinAlgError) as exc:
            log.warning("building %d: not refined (%s)", bid, exc)
            res = _kept(poly, [ridges[r] for r in mine], f"kept: {exc}")
        if res.status != "refined":
            log.info("building %d: %s", bid, res.status)
        buildings.append(res)
        for r, geom, flag in zip(mine, res.ridges, res.ridge_refined):
            new_ridges[r], ridge_refined[r] = geom, flag

    attributes = {
        "building_id": ids,
        "refine_status": [b.status for b in buildings],
        "candidates_per_side": [",".join(map(str, b.candidates_per_side)) for b in buildings],
        "refined_sides": [",".join(map(str, b.refined_sides)) for b in buildings],
        "n_sides": [len(b.refined_sides) for b in buildings],
        "n_refined": [int(sum(b.refined_sides)) for b in buildings],
        "refine_energy": [b.energy for b in buildings],
        "exact_energy": [b.exact_energy for b in buildings],
        "ga_exact_gap": [b.ga_exact_gap for b in buildings],
    }
    ridge_attributes = {"building_id": ridge_ids, "kind": ["ridge"] * len(ridges),
                        "refined": [int(f) for f in ridge_refined]}
    return RefineResult([b.outline for b in buildings], new_ridges, attributes, ridge_attributes, buildings)
