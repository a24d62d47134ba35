"""One roof refined with the image: :func:`refine_building` (Marcato & Dal Poz).

The steps (see :mod:`rooftrace.refine` for the many-building entry point):
topology of the LiDAR roof; candidate image lines and Harris corners in
windows around its projected lines; the MRF energy minimised by the genetic
algorithm (and, when small enough, exactly, to report the gap); the
selected lines put back together along the projected topology; the refined
pixels brought back onto the LiDAR roof planes.  The options and the result
type are in :mod:`rooftrace.refine.options`.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from rooftrace.errors import GeometryError
from rooftrace.grouping.exact import exact_minimise
from rooftrace.grouping.ga import genetic_minimise
from rooftrace.grouping.mrf import build_problem
from rooftrace.grouping.reconstruct import junction_planes, reconstruct_image, ridge_lines, to_object_space
from rooftrace.grouping.registration import GROWTH_RANGE, RoofShift, beyond_wall, estimate_shift, shift_references
from rooftrace.grouping.topology import roof_topology
from rooftrace.image.walls import wall_strips
from rooftrace.refine.options import BuildingRefinement, RefineOptions, keep_input

__all__ = ["RefineOptions", "BuildingRefinement", "refine_building", "fuse_positions", "keep_input"]

log = logging.getLogger(__name__)


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


def fuse_positions(image_points: np.ndarray, lidar_points: np.ndarray, use: np.ndarray, image_sigma: float,
                   lidar_sigma: float) -> np.ndarray:
    """Least-squares fusion of refined image vertices with the projected LiDAR ones (pixels).

    The registration error is mostly common to a roof (camera orientation,
    LiDAR offset), so the LiDAR vertices are first moved by the median shift
    ``t`` of the image vertices; each used vertex then becomes
    ``(p_img / σ_i² + (p_lidar + t) / σ_l²) / (1 / σ_i² + 1 / σ_l²)``.
    With a sparse cloud (σ_l of pixels) the image dominates; with a dense
    one whose outline is as good as an image edge both count.

    Parameters
    ----------
    image_points, lidar_points : ndarray of shape (J, 2)
    use : ndarray of shape (J,) bool
        Vertices the image supports; the others are returned unchanged.
    image_sigma, lidar_sigma : float
        Precision (px) of an image vertex and of a LiDAR vertex.
    """
    out = np.asarray(image_points, float).copy()
    if not use.any():
        return out
    t = np.median(image_points[use] - lidar_points[use], axis=0)
    wi, wl = 1.0 / image_sigma**2, 1.0 / max(lidar_sigma, 1e-9) ** 2
    out[use] = (wi * image_points[use] + wl * (lidar_points[use] + t)) / (wi + wl)
    return out


def _wall_flags(candidates, n: int) -> np.ndarray:
    """The ``wall`` flags (n,) float of a LineCandidates (zeros when it has none, e.g. precomputed elsewhere)."""
    wall = np.asarray(getattr(candidates, "wall", np.zeros(0)), bool)
    return wall.astype(float) if len(wall) == n else np.zeros(n)


def refine_building(outline, ridges, image: np.ndarray, camera, *, points_xyz: np.ndarray | None = None,
                    building_xyz: np.ndarray | None = None, planes: np.ndarray | None = None,
                    options: RefineOptions | None = None, seed: int = 0, candidates: list | None = None,
                    corners: np.ndarray | None = None, lidar_sigma: float | None = None,
                    ground_z: float | None = None) -> BuildingRefinement:
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
    lidar_sigma : float, optional
        Planimetric precision (m) of the LiDAR outline vertices, for
        :func:`fuse_positions`; default ``options.lidar_sigma``.
    ground_z : float, optional
        Ground height (m) at the building: predicts the visible walls
        (:func:`rooftrace.image.walls.wall_strips`); None: no wall step.

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
        return keep_input(source_outline, ridges, f"degenerate: {exc}")
    ref_points = camera.project(np.array([j.point for j in topo.junctions]))
    if not _inside_image(camera, ref_points):
        return keep_input(source_outline, ridges, "outside_image")
    # outward image normals of the sides (the shift estimate) and, with the ground height, the visible walls
    has_ground = ground_z is not None and bool(np.isfinite(ground_z))
    width, outward = wall_strips(camera, topo.lines, topo.kinds, outline, ground_z if has_ground else np.nan)
    width = width if has_ground else None
    if candidates is None:
        from rooftrace.image.candidates import extract_candidates

        candidates = extract_candidates(image, camera, topo.lines, list(topo.kinds), points_xyz=points_xyz,
                                        building_xyz=building_xyz, wall_width=width, outward=outward,
                                        options=opt.candidates)
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
    # ...but its image lines still vote for the roof's common shift (a curved wall is all short sides)
    vote_sets = list(cand_sets)
    vote_usable = [il & (opt.wall_penalty * _wall_flags(c, len(cs)) == 0)
                   for il, c, cs in zip(image_line, candidates, cand_sets)]
    for s_ in np.flatnonzero(short):
        cand_sets[s_], image_line[s_] = refs[s_:s_ + 1], np.zeros(1, bool)
    # a wall foot (or a shadow beyond it) with the roof edge found inward of it is the wrong line
    penalty = [np.zeros(len(cs)) if short[s_] else opt.wall_penalty * _wall_flags(c, len(cs))
               for s_, (c, cs) in enumerate(zip(candidates, cand_sets))]
    error = np.array([c.registration_error for c in candidates], float)
    roof_shift = RoofShift(np.zeros(2), 0.0, 0)
    if opt.register:
        usable = [image_line[s_] & (p == 0) for s_, p in enumerate(penalty)]
        radius = min(opt.max_shift_k * float(error.max(initial=0.0)) + 1.0, opt.register_max_px)
        roof_shift = estimate_shift(refs, vote_sets, outward, vote_usable, radius=max(radius, 2.0))
        if width is not None and opt.wall_penalty > 0:
            # a side whose only image lines lie where its wall's foot is expected: the projection competes
            far = beyond_wall(refs, cand_sets, outward, width, roof_shift, usable)
            for s_ in np.flatnonzero([f.any() and not (u & ~f).any() for f, u in zip(far, usable)]):
                cand_sets[s_] = np.concatenate([cand_sets[s_], refs[s_:s_ + 1]])
                image_line[s_] = np.append(image_line[s_], False)
                penalty[s_] = np.append(penalty[s_] + opt.wall_penalty * far[s_], 0.0)
        # the camera's share of the registration error (px², per axis) is the prior of a common shift
        centre = np.array([j.point for j in topo.junctions]).mean(axis=0, keepdims=True)
        sigma_c2 = float(np.asarray(camera.registration_error(centre, 0.0, 0.0)).ravel()[0]) ** 2 / 2.0
        roof_shift = roof_shift.shrunk(sigma_c2)
    # the energy measures candidates against the projections moved by the roof's common shift
    problem = build_problem(shift_references(refs, roof_shift), cand_sets, topo.pairs, corners, opt.mrf,
                            penalties=penalty)
    ga = genetic_minimise(problem, opt.ga, seed=seed)
    exact = exact_minimise(problem, opt.exact_max_table) if opt.exact_max_table > 0 else None
    choice = exact.choice if (opt.solver == "exact" and exact is not None) else ga.choice
    selected = np.stack([cs[k] for cs, k in zip(cand_sets, choice)])

    limit = np.array([opt.max_shift_k * max(error[line] for line, _ in j.members) + opt.max_shift_margin_px
                      for j in topo.junctions])
    chosen_image = np.array([image_line[s_][k] for s_, k in enumerate(choice)])
    # the LiDAR outline as the image sees it: sides moved outward by the roof's common growth
    expected = ref_points
    if opt.grow and roof_shift.n_sides >= 3 and GROWTH_RANGE[0] <= roof_shift.growth <= GROWTH_RANGE[1]:
        grown = refs.copy()
        side = np.isfinite(outward).all(axis=1)
        grown[side] += roof_shift.growth * outward[side][:, None, :]
        expected = reconstruct_image(topo, grown, ref_points, limit).points
        rec = reconstruct_image(topo, np.where((~chosen_image & side)[:, None, None], grown, selected), ref_points,
                                limit)
    else:
        rec = reconstruct_image(topo, selected, ref_points, limit)
    jplanes = junction_planes(topo, planes, opt.plane_tolerance)
    jlines = ridge_lines(topo, planes, opt.plane_tolerance) if opt.ridges_on_planes else None
    original = np.array([j.point for j in topo.junctions])
    # a junction of projected lines only is the LiDAR point itself: keep it exactly
    supported = np.array([any(chosen_image[line] for line, _ in j.members) for j in topo.junctions])
    pixels = rec.points
    use = rec.moved & supported
    carried = np.zeros(len(use), bool)
    if opt.fuse and use.any():
        pixels = fuse_positions(rec.points, expected, use, opt.image_sigma_px,
                                (lidar_sigma if lidar_sigma is not None else opt.lidar_sigma)
                                / camera.ground_sample_distance)
        shifts = rec.points[use] - expected[use]
        t = np.median(shifts, axis=0)
        spread = np.median(np.linalg.norm(shifts - t, axis=1))
        if use.sum() >= 3 and np.hypot(*t) > max(opt.carry_shift_px, 2.0 * spread):
            # a clear registration error is common to the roof: vertices without image support follow it
            carried = ~use
            pixels[carried] = expected[carried] + t
    if expected is not ref_points:
        # without image support and without a clear common shift, a vertex still follows the growth
        grown_v = ~use & ~carried & (np.linalg.norm(expected - ref_points, axis=1) > 1e-9)
        pixels = np.where(grown_v[:, None], expected, pixels)
        carried = carried | grown_v
    xyz, ok = to_object_space(camera, pixels, jplanes, original, opt.max_move, jlines)
    moved = (use | carried) & ok
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
        choice=choice, image_outline=np.where(moved[:, None], pixels, ref_points)[:n_out], kinds=topo.kinds,
        ring_sizes=topo.ring_sizes, references=refs, selected=selected,
        candidate_sets=cand_sets, seconds=time.perf_counter() - t0,
        image_shift=(*roof_shift.translation.tolist(), roof_shift.growth, roof_shift.n_sides),
        lines3d=np.asarray(topo.lines, float), outward=outward, image_chosen=chosen_image & ~short,
        lidar_sigma_px=(lidar_sigma if lidar_sigma is not None else opt.lidar_sigma) / camera.ground_sample_distance)
