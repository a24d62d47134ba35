"""Benchmark of the 3D models (LoD 1.2 / 1.3 / 2.2) on AHN3 Delft, without footprints.

What it measures, on the LiDAR-only buildings of ``rooftrace run`` (both
Delft tiles, EPSG:28992):

- **validity**: the share of buildings with a valid solid at each LoD, by
  rooftrace's own check (``rooftrace.model.solid_errors``; a level that fails
  it is never written, so "built" is "valid") and, when a val3dity binary is
  found (``--val3dity``, ``$PATH`` or ``/opt/val3dity/bin``), by val3dity
  on the written CityJSON file;
- **vertical RMSE** of the provider's building points (class 6 of the Delft
  LAZ, not rooftrace's classification) to the roof surfaces of each LoD,
  over the points that lie under a modelled roof (target for LoD 2.2:
  0.15 m; flat LoD 1.2 roofs score about 1.6 m there), with the median and
  95th percentile of ``|dz|`` and the share off by more than 1 m;
- **where the LoD 2.2 misfit comes from**: the same points split into those
  rooftrace put on a roof plane and that lie under that plane's face, those
  on a plane but under another face (the roof-face partition's share),
  those of a rooftrace building on no plane (walls, chimneys, small
  structures) and those of no rooftrace building; each class's share of the
  points and of the sum of squares, and the RMSE were every plane point
  under its own plane (the floor of any face partition of these planes);
  with ``--footprints`` also the share of the sum of squares from points
  within 0.3 m of a footprint's boundary (the facades); the points on no
  plane further by kind (``wall``, ``small``, ``planar``, ``non_planar``:
  ``_no_plane_kinds``), in the strict sum of squares and the top-surface one;
- **the issue's RMSE calibrated**: every candidate definition (points
  inside the BGT footprints, without facade points, top surface only; pooled
  or per building; 3D distance to the solid) for every level
  (:func:`metric_variants`); the one whose flat LoD 1.2 score reproduces the
  issue's "about 1.6 m" (:data:`CALIBRATED_RMSE`) carries the 0.15 m target;
- **complementary LoD 2.2 figures**, beside the strict RMSE, never instead
  of it: the RMSE of the top surface only (class-6 points with no class-6
  point more than 0.5 m higher within 0.3 m in plan: no facade points under
  an overhang) and the median over buildings of each building's RMSE;
- **time**: the run, its model step, and the CityJSONSeq / CityJSON writing
  (target: writing adds at most 20 % to the run);
- **memory** of writing: the peak of Python allocations (tracemalloc) while
  writing ``k`` copies of the buildings, ``k = 1, 4``: flat when the writers
  stream.

Usage::

    .venv/bin/python benchmarks/bench_models.py
    .venv/bin/python benchmarks/bench_models.py --val3dity /opt/val3dity/bin/val3dity
    .venv/bin/python benchmarks/bench_models.py --footprints ../shared/data/3dfier_delft_ahn3_bgt/bgt_pand.sqlite
    .venv/bin/python benchmarks/bench_models.py --ign   # IGN LiDAR HD Montpellier, LiDAR only

Recorded as dataset ``delft`` (LiDAR-only buildings), ``delft_footprints`` or ``ign``.
"""

from __future__ import annotations

import argparse
import copy
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import shapely
from scipy.spatial import ConvexHull, QhullError, cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _data import DATA
from _results import record
from rooftrace.graph import components
from rooftrace.io.footprints import read_footprints
from rooftrace.io.models import write_models
from rooftrace.io.points import read_points
from rooftrace.model import LODS, solid_errors
from rooftrace.model.measure import roof_height_at, surface_distance
from rooftrace.pipeline import points_by_building, run_pipeline
from rooftrace.roof.planes import fit_planes, plane_height, point_normals
from rooftrace.roof.structure import RoofOptions
from val3dity import BUILD_HINT, validate

DELFT = DATA / "3dfier_delft_ahn3_bgt"
IGN = DATA / "ign_montpellier_lidarhd_bdortho"


def _misfit_sources(cloud, result, index: np.ndarray, xyz: np.ndarray, footprints) -> list[dict]:
    """The LoD 2.2 sum of squares of the class-6 points ``xyz`` (cloud ``index``) under a roof, by source."""
    solids = [p.lods["2.2"] for m in result.models for p in m.parts if "2.2" in p.lods]
    dz = xyz[:, 2] - roof_height_at(solids, xyz[:, :2])
    building = result.building_id if result.building_id is not None else result.detection.building_id
    members = points_by_building(building)
    own = np.full(len(cloud.xyz), np.nan)  # height of each plane point's own plane under it
    in_building = np.zeros(len(cloud.xyz), bool)
    for st in result.structures:
        idx = members.get(st.building_id)
        if idx is None:
            continue
        in_building[idx] = True
        on = np.asarray(st.labels) >= 0
        own[idx[on]] = plane_height(st.planes[st.labels[on]], cloud.xyz[idx[on], :2])
    own = own[index]
    on_plane = np.isfinite(own)
    own_face = on_plane & (np.abs(xyz[:, 2] - dz - own) <= 0.1)
    sources = {"own_face": own_face, "other_face": on_plane & ~own_face,
               "no_plane": in_building[index] & ~on_plane, "no_building": ~in_building[index]}
    sse = float(np.sum(dz**2))
    rows = []
    for name, sel in sources.items():
        share, sse_share = float(np.mean(sel)), float(np.sum(dz[sel] ** 2)) / sse
        rmse = float(np.sqrt(np.mean(dz[sel] ** 2))) if sel.any() else float("nan")
        print(f"LoD 2.2 misfit, {name}: {share:.1%} of the points, {sse_share:.1%} of the sum of squares "
              f"(RMSE {rmse:.3f} m)")
        rows += [{"method": "rooftrace", "metric": f"lod22_points_share_{name}", "value": share, "unit": ""},
                 {"method": "rooftrace", "metric": f"lod22_sse_share_{name}", "value": sse_share, "unit": ""}]
    floor = np.where(on_plane, xyz[:, 2] - own, dz)
    floor_rmse = float(np.sqrt(np.mean(floor**2)))
    print(f"LoD 2.2 RMSE were every plane point under its own plane: {floor_rmse:.3f} m")
    rows.append({"method": "rooftrace", "metric": "rmse_class6_lod22_plane_points_own_face", "value": floor_rmse,
                 "unit": "m"})
    # the points on no plane, by what they are, in the strict metric and in the top-surface one
    kind = _no_plane_kinds(cloud, result, members)[index]
    top = top_surface(xyz)
    sse_top = float(np.sum(dz[top] ** 2))
    for k, name in enumerate(NO_PLANE_KINDS):
        sel = sources["no_plane"] & (kind == k)
        share, sse_share = float(np.mean(sel)), float(np.sum(dz[sel] ** 2)) / sse
        top_share = float(np.sum(dz[sel & top] ** 2)) / sse_top
        print(f"LoD 2.2 misfit, no_plane {name}: {share:.1%} of the points, {sse_share:.1%} of the sum of squares, "
              f"{top_share:.1%} of the top-surface one")
        rows += [{"method": "rooftrace", "metric": f"lod22_points_share_no_plane_{name}", "value": share, "unit": ""},
                 {"method": "rooftrace", "metric": f"lod22_sse_share_no_plane_{name}", "value": sse_share, "unit": ""},
                 {"method": "rooftrace", "metric": f"lod22_top_sse_share_no_plane_{name}", "value": top_share,
                  "unit": ""}]
    if footprints is not None:
        walls = shapely.union_all(footprints.polygons).boundary
        facade = shapely.distance(walls, shapely.points(xyz[:, :2])) <= 0.3
        share = float(np.sum(dz[facade] ** 2)) / sse
        print(f"LoD 2.2 misfit within 0.3 m of a footprint boundary: {np.mean(facade):.1%} of the points, "
              f"{share:.1%} of the sum of squares; RMSE of the others {np.sqrt(np.mean(dz[~facade] ** 2)):.3f} m")
        rows += [{"method": "rooftrace", "metric": "lod22_points_share_facade_03m", "value": float(np.mean(facade)),
                  "unit": ""},
                 {"method": "rooftrace", "metric": "lod22_sse_share_facade_03m", "value": share, "unit": ""}]
    return rows


def metric_variants(models, pts: np.ndarray, reference) -> list[dict]:
    """The fit of the class-6 points ``pts`` to each LoD under candidate definitions of the issue's RMSE.

    Calibration, not choice: the issue gives one anchor (flat LoD 1.2 roofs
    score about 1.6 m on Delft with the BGT footprints), so each definition
    is computed for every level and the one that reproduces the anchor says
    what the 0.15 m LoD 2.2 target means (:data:`CALIBRATED_RMSE`).
    ``reference`` are the provider's footprints (BGT), used only to select
    points, in both modes (None: no ``in_footprint`` variants).  Metric ``rmse_<selection>_<aggregation>_lodXX``;
    the points, each under the roof of the level's building over it:

    - selection ``all`` (every such point), ``in_footprint`` (inside a
      reference footprint: no overhang or facade points beyond the
      cadastral wall line), ``no_wall`` (no class-6 point more than 1 m
      higher within 0.5 m in plan: no facade points) and ``top`` (none more
      than 0.5 m higher within 0.3 m, :func:`top_surface`);
    - aggregation ``pooled`` (one RMSE of all points), ``building_mean`` /
      ``building_median`` (each building's RMSE, buildings with 10 points or
      more, then the mean / median);
    - ``mesh3d_<selection>_pooled``: the 3D distance to the nearest surface
      (roof, wall, ground) of the building's solids instead of the vertical
      one, as roofer/3DBAG measure a model against its points.

    ``rmse_all_pooled`` is the strict figure (``rmse_class6_lodXX``).
    """
    inside = np.zeros(len(pts), bool)
    if reference is not None:
        ip, _ = shapely.STRtree(reference).query(shapely.points(pts[:, :2]), predicate="intersects")
        inside[ip] = True
    pairs = cKDTree(pts[:, :2]).query_pairs(0.5, output_type="ndarray")
    highest = pts[:, 2].copy()
    np.maximum.at(highest, pairs[:, 0], pts[pairs[:, 1], 2])
    np.maximum.at(highest, pairs[:, 1], pts[pairs[:, 0], 2])
    selections = {"all": np.ones(len(pts), bool), "in_footprint": inside, "no_wall": highest <= pts[:, 2] + 1.0,
                  "top": top_surface(pts)}
    if reference is None:
        del selections["in_footprint"]
    order = np.argsort(pts[:, 0], kind="stable")
    xs = pts[order, 0]
    rows = []
    for lod in LODS:
        key = lod.replace(".", "")
        per_building = [[p.lods[lod] for p in m.parts if lod in p.lods] for m in models]
        per_building = [s for s in per_building if s]
        # each point goes to the building whose roof is highest over it (the pooled roof_height_at's choice)
        h = np.full(len(pts), np.nan)
        owner = np.full(len(pts), -1)
        for b, solids in enumerate(per_building):
            x0 = min(float(r[:, 0].min()) for s in solids for f in s.surfaces for r in f.rings)
            x1 = max(float(r[:, 0].max()) for s in solids for f in s.surfaces for r in f.rings)
            near = order[np.searchsorted(xs, x0):np.searchsorted(xs, x1, side="right")]
            hb = roof_height_at(solids, pts[near, :2])
            higher = np.isfinite(hb) & ~(hb <= h[near])
            h[near[higher]] = hb[higher]
            owner[near[higher]] = b
        dz = pts[:, 2] - h
        under = np.isfinite(h)
        values = {}
        for name, sel in selections.items():
            sel = sel & under
            per = np.array([np.sqrt(np.mean(dz[sel & (owner == b)] ** 2)) for b in range(len(per_building))
                            if np.sum(sel & (owner == b)) >= 10])
            values[f"{name}_pooled"] = np.sqrt(np.mean(dz[sel] ** 2))
            values[f"{name}_building_mean"] = np.mean(per)
            values[f"{name}_building_median"] = np.median(per)
        dist = np.full(len(pts), np.nan)
        for b, solids in enumerate(per_building):
            sel = np.flatnonzero(owner == b)
            if len(sel):
                dist[sel] = surface_distance(solids, pts[sel])
        for name in ("all", "in_footprint") if reference is not None else ("all",):
            values[f"mesh3d_{name}_pooled"] = np.sqrt(np.mean(dist[under & selections[name]] ** 2))
        print(f"LoD {lod} RMSE variants: " + ", ".join(f"{k} {v:.3f}" for k, v in values.items()))
        rows += [{"method": "rooftrace", "metric": f"rmse_{k}_lod{key}", "value": float(v), "unit": "m",
                  "target": "<= 0.15" if lod == "2.2" and k == CALIBRATED_RMSE else None}
                 for k, v in values.items()]
    return rows


#: the variant of :func:`metric_variants` whose flat LoD 1.2 score reproduces the issue's "about 1.6 m" on Delft
#: with the BGT footprints (1.62 m; the next ones: ``no_wall_building_mean`` 1.57, ``top_building_median`` 1.55,
#: ``all_building_mean`` 1.99, ``all_pooled`` 2.82, ``mesh3d_in_footprint_pooled`` 0.87)
CALIBRATED_RMSE = "top_building_mean"


def top_surface(xyz: np.ndarray, radius: float = 0.3, rise: float = 0.5) -> np.ndarray:
    """Points with no other point more than ``rise`` (m) higher within ``radius`` (m) in plan.

    The complementary metric's selection: it drops facade points under a
    roof overhang or just inside a wall line, which no roof surface can fit.
    """
    tree = cKDTree(xyz[:, :2])
    pairs = tree.query_pairs(radius, output_type="ndarray")
    highest = xyz[:, 2].copy()
    np.maximum.at(highest, pairs[:, 0], xyz[pairs[:, 1], 2])
    np.maximum.at(highest, pairs[:, 1], xyz[pairs[:, 0], 2])
    return highest <= xyz[:, 2] + rise


def _no_plane_kinds(cloud, result, members: dict) -> np.ndarray:
    """What each point of a rooftrace building left on no roof plane is: a kind index into ``NO_PLANE_KINDS``.

    Per building, the unlabelled points whose neighbourhood normal is steeper
    than 60 deg are ``wall``; the others are clustered in 3D (linked within
    2.5 point spacings) and each cluster is ``small`` (plan hull under the
    segmentation's ``min_area``, 2 m²: chimneys, small dormers, roof
    clutter), ``planar`` (a least-squares plane fits it within 0.1 m RMS: a
    plane the segmentation missed) or ``non_planar`` (vegetation, curved
    roofs, several small structures touching).  -1 for points on a plane or
    of no building.
    """
    kind = np.full(len(cloud.xyz), -1, np.int8)
    for st in result.structures:
        idx = members.get(st.building_id)
        if idx is None or not (st.labels < 0).any():
            continue
        xyz = cloud.xyz[idx]
        normals, _, _ = point_normals(xyz, 16)
        un = np.flatnonzero(st.labels < 0)
        wall = normals[un, 2] < np.cos(np.radians(60))
        kind[idx[un[wall]]] = NO_PLANE_KINDS.index("wall")
        rest = un[~wall]
        if not len(rest):
            continue
        comp = components(len(rest), cKDTree(xyz[rest]).query_pairs(2.5 * st.spacing, output_type="ndarray"))
        for c in np.unique(comp):
            sel = rest[comp == c]
            try:
                area = ConvexHull(xyz[sel, :2]).volume
            except QhullError:
                area = 0.0
            if area < 2.0:
                kind[idx[sel]] = NO_PLANE_KINDS.index("small")
                continue
            fit = fit_planes(xyz[sel], np.zeros(len(sel), np.int64), 1)
            planar = bool(fit.sigma[0] <= 0.1)
            kind[idx[sel]] = NO_PLANE_KINDS.index("planar" if planar else "non_planar")
    return kind


#: what a point on no roof plane is (:func:`_no_plane_kinds`)
NO_PLANE_KINDS = ("wall", "small", "planar", "non_planar")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--val3dity", default=None, help="val3dity binary (default: $VAL3DITY, the PATH, build.sh's place)")
    ap.add_argument("--repeats", type=int, default=3, help="writes timed (best of)")
    ap.add_argument("--footprints", type=Path, default=None, help="footprints of the run (e.g. bgt_pand.sqlite)")
    ap.add_argument("--ign", action="store_true",
                    help="IGN LiDAR HD Montpellier (LiDAR only, no reference footprints) instead of Delft; "
                         "recorded as dataset ign")
    ap.add_argument("--face-boundaries", choices=("each", "held", "free"), default=None,
                    help="[planes] face_boundaries of the run (default: the configured one); another than the "
                         "default is recorded as dataset delft[_footprints]_faces-VALUE")
    args = ap.parse_args()
    if args.ign and args.footprints:
        ap.error("--ign has no footprints")
    if args.ign:
        cloud = read_points(sorted(IGN.glob("*.laz")))
    else:
        cloud = read_points([DELFT / f"ahn3_cropped_{i}.laz" for i in (1, 2)], "EPSG:28992")
    footprints = read_footprints(args.footprints, cloud.crs) if args.footprints else None

    config = {"planes": {"face_boundaries": args.face_boundaries}} if args.face_boundaries else None
    t0, c0 = time.perf_counter(), time.process_time()
    result = run_pipeline(cloud, footprints=footprints, config=config)
    run_s, run_cpu = time.perf_counter() - t0, time.process_time() - c0
    models = result.models
    n = len(models)
    print(f"run {run_s:.1f} s, CPU {run_cpu:.1f} s (roof {result.timings['roof_planes']:.1f} s, models "
          f"{result.timings['models']:.1f} s), {n} buildings with an outline")

    rows = []
    # size of the models: vertices of the roof faces and of the LoD 2.2 solids' rings (closing vertex not counted)
    face_vertices = sum(len(shapely.get_coordinates(shapely.remove_repeated_points(f))) - 1 - len(f.interiors)
                        for st in result.structures for f in st.faces)
    ring_vertices = sum(len(r) for m in models for p in m.parts if "2.2" in p.lods for s in p.lods["2.2"].surfaces
                        for r in s.rings)
    print(f"roof face vertices {face_vertices}, LoD 2.2 ring vertices {ring_vertices}")
    rows.append({"method": "rooftrace", "metric": "roof_face_vertices", "value": face_vertices, "unit": "",
                 "target": None})
    rows.append({"method": "rooftrace", "metric": "lod22_ring_vertices", "value": ring_vertices, "unit": "",
                 "target": None})
    own = {}
    for lod in LODS:
        solids = [p.lods[lod] for m in models for p in m.parts if lod in p.lods]
        assert all(solid_errors(s) == [] for s in solids)  # built means checked valid
        share = sum(any(lod in p.lods for p in m.parts) for m in models) / max(n, 1)
        own[lod] = share
        print(f"LoD {lod}: {share:.1%} of buildings have a valid solid ({len(solids)} solids)")
        rows.append({"method": "rooftrace", "metric": f"valid_share_lod{lod.replace('.', '')}", "value": share,
                     "unit": "", "target": ">= 0.98" if lod == "2.2" else ">= 1.0"})
    reasons: dict[str, int] = {}
    for m in models:
        for r in (m.attributes.get("status_reason") or "").split("; "):
            if r:
                key = r.split(" (")[0]
                reasons[key] = reasons.get(key, 0) + 1
    print("missing levels:", reasons)

    # the provider's building points (class 6) against the roofs
    provider = np.flatnonzero(cloud.fields["classification"] == 6)
    pts = cloud.xyz[provider]
    covered = None
    for lod in LODS:
        solids = [p.lods[lod] for m in models for p in m.parts if lod in p.lods]
        h = roof_height_at(solids, pts[:, :2])
        if lod == "2.2":
            covered = np.isfinite(h)
        d = (pts[:, 2] - h)[np.isfinite(h)]
        rmse = float(np.sqrt(np.mean(d * d)))
        med = float(np.median(np.abs(d)))
        p95 = float(np.percentile(np.abs(d), 95))
        over = float(np.mean(np.abs(d) > 1))
        print(f"LoD {lod}: vertical RMSE of {len(d)} class-6 points {rmse:.3f} m (median |dz| {med:.3f} m, "
              f"95th percentile {p95:.3f} m, {over:.1%} off by more than 1 m)")
        rows.append({"method": "rooftrace", "metric": f"p95_abs_dz_lod{lod.replace('.', '')}", "value": p95,
                     "unit": "m", "target": None})
        rows.append({"method": "rooftrace", "metric": f"share_dz_over_1m_lod{lod.replace('.', '')}", "value": over,
                     "unit": "", "target": None})
        rows.append({"method": "rooftrace", "metric": f"rmse_class6_lod{lod.replace('.', '')}", "value": rmse,
                     "unit": "m", "target": "<= 0.15" if lod == "2.2" else None})
        rows.append({"method": "rooftrace", "metric": f"median_abs_dz_lod{lod.replace('.', '')}", "value": med,
                     "unit": "m", "target": None})
    # complementary figures, never instead of the strict one: the top surface only (no facade points under an
    # overhang), and the median over buildings of each building's RMSE (a few buildings do not dominate it)
    solids = [p.lods["2.2"] for m in models for p in m.parts if "2.2" in p.lods]
    d = pts[covered, 2] - roof_height_at(solids, pts[covered, :2])
    top = top_surface(pts[covered])
    top_rmse = float(np.sqrt(np.mean(d[top] ** 2)))
    per_building = []
    for m in models:
        its = [p.lods["2.2"] for p in m.parts if "2.2" in p.lods]
        if not its:
            continue
        x0, y0, x1, y1 = shapely.bounds(shapely.union_all([p.footprint for p in m.parts if "2.2" in p.lods]))
        near = np.flatnonzero((pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1))
        dm = pts[near, 2] - roof_height_at(its, pts[near, :2])
        if np.isfinite(dm).any():
            per_building.append(float(np.sqrt(np.nanmean(dm**2))))
    med_building = float(np.median(per_building))
    print(f"LoD 2.2, top surface only ({top.mean():.1%} of the points): RMSE {top_rmse:.3f} m; median over "
          f"{len(per_building)} buildings of their RMSE {med_building:.3f} m")
    rows += [{"method": "rooftrace", "metric": "rmse_class6_lod22_top_surface", "value": top_rmse, "unit": "m",
              "target": None},
             {"method": "rooftrace", "metric": "rmse_class6_lod22_building_median", "value": med_building,
              "unit": "m", "target": None}]
    rows += _misfit_sources(cloud, result, provider[covered], pts[covered], footprints)
    # what the RMSE is: every candidate definition, for every level (the LoD 1.2 anchor decides)
    if args.ign:
        reference = None
    else:
        reference = (footprints or read_footprints(DELFT / "bgt_pand.sqlite", cloud.crs)).polygons
    rows += metric_variants(models, pts, reference)
    # where the misfit is: by plan distance to the model's outline (facades, steps near it)
    solids = [p.lods["2.2"] for m in models for p in m.parts if "2.2" in p.lods]
    outline = shapely.union_all([p.footprint for m in models for p in m.parts if "2.2" in p.lods])
    h = roof_height_at(solids, pts[covered, :2])
    d = pts[covered, 2] - h
    dist = shapely.distance(outline.boundary, shapely.points(pts[covered, :2]))
    for lo, hi in ((0, 1), (1, 2), (2, np.inf)):
        sel = (dist >= lo) & (dist < hi)
        print(f"LoD 2.2, points {lo}-{hi} m inside the outline: {sel.sum()} points, RMSE "
              f"{np.sqrt(np.mean(d[sel] ** 2)):.3f} m")
    # the same, only where every level has a roof (a like-for-like comparison)
    for lod in LODS:
        solids = [p.lods[lod] for m in models for p in m.parts if lod in p.lods]
        h = roof_height_at(solids, pts[covered, :2])
        d = (pts[covered, 2] - h)[np.isfinite(h)]
        print(f"LoD {lod} under LoD 2.2 roofs: RMSE {np.sqrt(np.mean(d * d)):.3f} m")

    # writing: time and memory
    tmp = Path(tempfile.mkdtemp())
    times = {}
    for name in ("city.jsonl", "city.json"):
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            write_models([tmp / f"delft.{name}"], models, cloud.crs, overwrite=True)
            best = min(best, time.perf_counter() - t0)
        times[name] = best
        size = (tmp / f"delft.{name}").stat().st_size
        print(f"write .{name}: {best:.2f} s ({best / run_s:.1%} of the run), {size / 1e6:.1f} MB")
        rows.append({"method": "rooftrace", "metric": f"write_{name.replace('.', '_')}_share_of_run",
                     "value": best / run_s, "unit": "", "target": "<= 0.20"})
    rows.append({"method": "rooftrace", "metric": "run_time_s", "value": run_s, "unit": "s", "target": None})
    rows.append({"method": "rooftrace", "metric": "run_cpu_s", "value": run_cpu, "unit": "s", "target": None})
    rows.append({"method": "rooftrace", "metric": "roof_time_s", "value": result.timings["roof_planes"], "unit": "s",
                 "target": None})
    rows.append({"method": "rooftrace", "metric": "models_time_s", "value": result.timings["models"], "unit": "s",
                 "target": None})
    peaks = {}
    for k in (1, 4):
        many = []
        for c in range(k):
            for m in models:
                m2 = copy.copy(m)
                m2.building_id = m.building_id + c * 100000
                many.append(m2)
        tracemalloc.start()
        write_models([tmp / "mem.city.jsonl"], iter(many), cloud.crs, overwrite=True)
        peaks[k] = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        print(f"write {len(many)} buildings: peak Python allocation {peaks[k]:.1f} MiB")
        rows.append({"method": "rooftrace", "metric": f"write_peak_mib_x{k}", "value": peaks[k], "unit": "MiB",
                     "target": None})
    checked = validate(tmp / "delft.city.json", binary=args.val3dity)
    if checked is not None:
        for lod, row in sorted(checked["lod"].items()):
            print(f"val3dity LoD {lod}: {row['valid']}/{row['solids']} solids valid ({row['share']:.1%}); "
                  f"errors {dict(checked['errors'])}")
            rows.append({"method": "val3dity", "metric": f"valid_share_lod{lod.replace('.', '')}",
                         "value": row["share"], "unit": "", "target": ">= 0.98" if lod == "2.2" else "1.0"})
            rows.append({"method": "val3dity", "metric": f"solids_lod{lod.replace('.', '')}", "value": row["solids"],
                         "unit": "", "target": None})
        # errors between the solids of one building (601: its parts overlap) or of the file belong to no LoD
        rows.append({"method": "val3dity", "metric": "feature_errors", "value": sum(checked["feature_errors"].values())
                     + len(checked["dataset_errors"]), "unit": "", "target": "0"})
    else:
        print(BUILD_HINT + "; own check only")
    shutil.rmtree(tmp, ignore_errors=True)
    dataset = "ign" if args.ign else "delft" if footprints is None else "delft_footprints"
    if args.face_boundaries and args.face_boundaries != RoofOptions().face_boundaries:
        dataset += f"_faces-{args.face_boundaries}"
    print(record("models", dataset, rows))


if __name__ == "__main__":
    main()
