"""Image refinement of LiDAR roofs (Marcato & Dal Poz): candidates -> MRF grouping -> reconstruction -> 3D.

For each building:

1. the roof's line topology (outline sides + ridges, :func:`roof_topology`);
2. candidate image lines per side/ridge in windows around their projections
   (:func:`rooftrace.image.candidates.extract_candidates`, Marcato & Dal Poz §2.1 and
   Marcato & Dal Poz 2011) and Harris corners in those windows;
3. the MRF energy (eq. 6-13) minimised by the genetic algorithm (§2.3); the
   exact minimiser runs too when the problem is small enough and the gap
   between the two is reported (``ga_exact_gap``);
4. reconstruction of the selected lines along the projected topology (§2.4);
5. back to object space: each refined pixel's ray meets the roof plane of its
   vertex (or a horizontal plane through the LiDAR vertex);
6. (ours, ``RefineOptions.orientation``) for a frame camera with an EO
   covariance: the exterior orientation corrected from the lines matched in
   all buildings (:func:`rooftrace.grouping.orientation.correct_orientation`)
   and steps 2-5 run again with the corrected camera, so that the camera's
   registration error leaves the object-space result too.

A building that cannot be refined keeps its input geometry; ``refine_status``
says why.  No I/O here: the CLI and the pipeline read and write.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import cKDTree

from rooftrace.errors import GeometryError
from rooftrace.grouping.orientation import EO_NAMES, OrientationCorrection, correct_orientation
from rooftrace.refine.building import refine_building
from rooftrace.refine.options import BuildingRefinement, RefineOptions, keep_input

__all__ = ["RefineOptions", "RefineResult", "BuildingRefinement", "refine_building", "refine_buildings",
           "assign_ridges", "correct_from_matches", "orientation_summary"]

log = logging.getLogger(__name__)


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
    camera : FrameCamera or OrthoCamera or None
        The camera of the last pass: the input one, or the corrected one.
    orientation : OrientationCorrection or None
        The exterior orientation correction (``RefineOptions.orientation``);
        ``delta`` is the total over the rounds.
    """

    outlines: list
    ridges: list
    attributes: dict
    ridge_attributes: dict
    buildings: list
    camera: object = None
    orientation: OrientationCorrection | None = None

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
                "exact_checked": int(ran.sum()), "ga_reached_exact": int((gaps[ran] <= 1e-9).sum()),
                **({"orientation": orientation_summary(self.orientation)} if self.orientation is not None else {})}


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


@dataclass(frozen=True)
class LidarRoofs:
    """The LiDAR roofs an image refines, as the LiDAR stages made them.

    Attributes
    ----------
    building_ids : sequence of int
        Id of each building, in building-id order.
    outlines : sequence of Polygon with Z or None
        Roof outline of each building (map CRS, m); None for a building
        whose outline failed (it stays as it is).
    ridges : sequence of LineString with Z
        Every ridge, hip, valley and step edge of every building.
    ridge_building_ids : sequence of int
        Building of each ridge.
    ridge_kinds : sequence of str
        Kind of each ridge (``ridge``, ``hip``, ``valley``, ``step``).
    planes : mapping of int to ndarray of shape (K, 4)
        Roof planes ``a X + b Y + c Z + d = 0`` per building id; a building
        without an entry is projected through horizontal planes.
    """

    building_ids: Sequence[int]
    outlines: Sequence
    ridges: Sequence = ()
    ridge_building_ids: Sequence[int] = ()
    ridge_kinds: Sequence[str] = ()
    planes: Mapping[int, np.ndarray] = dataclasses.field(default_factory=dict)


def refine_roofs(roofs: LidarRoofs, image: np.ndarray, camera, *, points_xyz: np.ndarray | None = None,
                 options: RefineOptions | None = None, seed: int = 0) -> RefineResult:
    """Refine the LiDAR roofs of a run with one image, every building in one pass.

    An untiled run and the merge of a tiled run both call this, so that they
    refine the same inputs the same way: the exterior-orientation correction
    (``[refine] orientation``) uses the line matches of all buildings
    jointly, and the genetic algorithm of building ``i`` (in building-id
    order) is seeded with ``seed + i``.

    Parameters
    ----------
    roofs : LidarRoofs
        Outlines, ridges and roof planes of every building.
    image : ndarray of shape (H, W)
        Grey image in [0, 1].
    camera : FrameCamera or OrthoCamera
        Orientation of ``image``, same CRS as the roofs.
    points_xyz : ndarray of shape (N, 3), float64, optional
        LiDAR points of any class (m), in input order: at least every point
        within ``options.context`` of each building (the refinement's ground
        height, LiDAR precision and terrain-line filter use them).
    options : RefineOptions, optional
    seed : int, default 0
        Seed of the genetic algorithm.

    Returns
    -------
    RefineResult

    Examples
    --------
    >>> from rooftrace.synth import SceneOptions, simulate_scene
    >>> scene = simulate_scene(SceneOptions(seed=1, size=40.0, density=8.0, trees=False))
    >>> truth = scene.truth
    >>> roofs = LidarRoofs([1], truth["roof_outlines"].geometries, truth["ridges"].geometries,
    ...                    [1] * len(truth["ridges"]), ["ridge"] * len(truth["ridges"]))
    >>> refined = refine_roofs(roofs, scene.image.mean(axis=0) / 255.0, scene.camera, points_xyz=scene.cloud.xyz)
    >>> len(refined.outlines)
    1
    """
    ids = [int(b) for b in roofs.building_ids]
    return refine_buildings(list(roofs.outlines), list(roofs.ridges), image, camera, points_xyz=points_xyz,
                            planes=[roofs.planes.get(b) for b in ids], building_ids=ids,
                            ridge_building_ids=[int(b) for b in roofs.ridge_building_ids],
                            ridge_kinds=list(roofs.ridge_kinds), options=options, seed=seed)


def refine_buildings(outlines: Sequence, ridges: Sequence, image: np.ndarray, camera, *,
                     points_xyz: np.ndarray | None = None, planes: Sequence | None = None,
                     building_ids: Sequence[int] | None = None, ridge_building_ids: Sequence[int] | None = None,
                     options: RefineOptions | None = None, seed: int = 0,
                     ridge_kinds: Sequence[str] | None = None) -> RefineResult:
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
    ridge_kinds : sequence of str, optional
        Kind of each ridge (``ridge``, ``hip``, ``valley``, ``step``), carried
        to ``ridge_attributes['kind']``; default ``'ridge'``.

    Returns
    -------
    RefineResult

    Examples
    --------
    >>> from rooftrace.synth import SceneOptions, simulate_scene
    >>> scene = simulate_scene(SceneOptions(seed=1, size=40.0, density=8.0, trees=False))
    >>> grey = scene.image.mean(axis=0) / 255.0
    >>> truth = scene.truth
    >>> refined = refine_buildings(truth["roof_outlines"].geometries, truth["ridges"].geometries, grey, scene.camera,
    ...                            points_xyz=scene.cloud.xyz)
    >>> len(refined.outlines), len(refined.attributes["refine_status"])
    (1, 1)
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
    kinds = ["ridge"] * len(ridges) if ridge_kinds is None else [str(k) for k in ridge_kinds]
    if len(kinds) != len(ridges):
        raise ValueError(f"ridge_kinds has {len(kinds)} entries for {len(ridges)} ridges")
    by_building: dict[int, list[int]] = {}
    for r, b in enumerate(ridge_ids):
        by_building.setdefault(b, []).append(r)

    pts = None if points_xyz is None or not len(points_xyz) else np.asarray(points_xyz, float).reshape(-1, 3)
    tree = cKDTree(pts[:, :2]) if pts is not None else None
    jobs = []
    for i, poly in enumerate(outlines):
        local = sigma = ground = None
        if poly is not None and not poly.is_empty and tree is not None:
            x0, y0, x1, y1 = poly.bounds
            near = tree.query_ball_point([(x0 + x1) / 2, (y0 + y1) / 2], np.hypot(x1 - x0, y1 - y0) / 2 + opt.context)
            local = pts[np.sort(np.asarray(near, int))]
            # the ground under the walls: a low percentile of the points around (robust to a few low outliers)
            ground = float(np.percentile(local[:, 2], 2.0)) if len(local) >= 20 else None
            n_in = int(shapely.contains_xy(shapely.force_2d(poly), local[:, 0], local[:, 1]).sum())
            # a fraction of the mean point spacing 1/sqrt(density) (boundary points sit within a spacing of the edge)
            sigma = opt.lidar_sigma_spacing / np.sqrt(n_in / poly.area) if n_in >= 10 and poly.area > 0 else None
        b_opt = opt
        if sigma is not None and opt.derive_sigma:
            # windows and registration errors follow this roof's LiDAR precision, not Marcato & Dal Poz's 0.48 m
            from rooftrace.image.candidates import CandidateOptions

            b_opt = dataclasses.replace(opt, candidates=dataclasses.replace(opt.candidates or CandidateOptions(),
                                                                            sigma_xy=sigma))
        # the building's own points would mark the true edges, which lie outside a LiDAR outline
        # shrunk by half a point spacing, as "off the building": the projected lines stand for it
        jobs.append(dict(points_xyz=local if opt.terrain_filter else None, building_xyz=None,
                         planes=None if planes is None else planes[i], options=b_opt, seed=seed + i,
                         lidar_sigma=sigma, ground_z=ground))

    def one_pass(cam) -> list:
        out = []
        for i, (poly, bid) in enumerate(zip(outlines, ids)):
            mine = [ridges[r] for r in by_building.get(bid, [])]
            try:
                res = refine_building(poly, mine, img, cam, **jobs[i])
            except (GeometryError, np.linalg.LinAlgError) as exc:
                log.warning("building %d: not refined (%s)", bid, exc)
                res = keep_input(poly, mine, f"kept: {exc}")
            if res.status != "refined":
                log.info("building %d: %s", bid, res.status)
            out.append(res)
        return out

    buildings = one_pass(camera)
    correction, used = None, camera
    uncertain = getattr(camera, "exterior_covariance", None) is not None
    if (opt.orientation and getattr(camera, "kind", None) == "frame"
            and (uncertain or opt.orientation_parameters != "auto")):
        for _ in range(opt.orientation_rounds):
            try:
                # each round starts from the last correction; the prior stays the input camera's
                correction = correct_from_matches(camera, buildings, start=used.exterior,
                                                  parameters=opt.orientation_parameters,
                                                  min_lines=opt.orientation_min_lines,
                                                  image_sigma_px=opt.image_sigma_px)
            except GeometryError as exc:
                log.warning("exterior orientation not corrected: %s", exc)
                break
            used = correction.camera
            buildings = one_pass(used)
    new_ridges = list(ridges)
    ridge_refined = [False] * len(ridges)
    for bid, res in zip(ids, buildings):
        for r, geom, flag in zip(by_building.get(bid, []), res.ridges, res.ridge_refined):
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
    ridge_attributes = {"building_id": ridge_ids, "kind": kinds,
                        "refined": [int(f) for f in ridge_refined]}
    return RefineResult([b.outline for b in buildings], new_ridges, attributes, ridge_attributes, buildings,
                        used, correction)


def correct_from_matches(camera, buildings, *, start=None, parameters: str = "auto", min_lines: int = 12,
                         image_sigma_px: float = 0.7) -> OrientationCorrection:
    """:func:`correct_orientation` from the lines the grouping matched in refined buildings.

    Parameters
    ----------
    camera : FrameCamera
        The camera the buildings were refined with (prior and start).
    buildings : sequence of BuildingRefinement
        Refined buildings; their ``lines3d``, ``selected``, ``outward``,
        ``image_chosen`` and ``lidar_sigma_px`` give the matches (lines whose selected line is an
        image line), one growth per building.
    start : ndarray of shape (6,), optional
        Starting EO; default the camera's.
    parameters : {'auto', 'full', 'reduced'}, default 'auto'
    min_lines : int, default 12
    image_sigma_px : float, default 0.7
        Precision of an image line (px).  A ridge match gets this sigma, an
        outline side ``hypot(image_sigma_px, lidar_sigma_px)`` with its
        building's LiDAR planimetric precision in pixels (the end points of
        a LiDAR outline side scatter by about that much; a ridge from two
        fitted planes far less).

    Returns
    -------
    OrientationCorrection

    Raises
    ------
    GeometryError
        Too few matches, or matches that do not determine the orientation.
    """
    l3, l2, out, grp, sig = [], [], [], [], []
    for k, b in enumerate(buildings):
        if b.status != "refined" or b.image_chosen is None or not np.any(b.image_chosen):
            continue
        use = np.flatnonzero(b.image_chosen)
        l3.append(np.asarray(b.lines3d, float)[use])
        l2.append(np.asarray(b.selected, float)[use])
        out.append(np.asarray(b.outward, float)[use])
        grp.append(np.full(len(use), k))
        # an outline side's end points carry the LiDAR outline's error too; a ridge (two planes) hardly any
        side = np.isfinite(np.asarray(b.outward, float)[use]).all(axis=1)
        sig.append(np.where(side, np.hypot(image_sigma_px, b.lidar_sigma_px), image_sigma_px))
    if not l3:
        raise GeometryError("no image line was matched: nothing to correct the orientation with")
    l3, l2 = np.concatenate(l3), np.concatenate(l2)
    keep = np.linalg.norm(l2[:, 1] - l2[:, 0], axis=1) > 1e-6
    out = np.concatenate(out)[keep]
    return correct_orientation(camera, l3[keep], l2[keep], outward=out, sigma_px=np.concatenate(sig)[keep],
                               groups=np.concatenate(grp)[keep], start=start, parameters=parameters,
                               min_lines=min_lines)


def orientation_summary(correction: OrientationCorrection) -> dict:
    """A JSON-ready summary: parameters, EO change (m, deg) and its standard deviations, lines, RMS (px)."""
    deg = np.array([1.0, 1.0, 1.0, *(3 * [180.0 / np.pi])])
    return {"parameters": list(correction.parameters),
            "delta": {k: float(v) for k, v in zip(EO_NAMES, correction.delta * deg)},
            "std": {k: float(v) for k, v in zip(EO_NAMES, correction.std() * deg)},
            "lines": correction.n_lines, "inliers": correction.n_inliers, "rms_px": correction.rms}
