"""Benchmark of the building-part split (LiDAR only, no footprints) and of the footprint assignment.

Datasets:

* ``synth``: a simulated scene (ray-cast ALS, 12 pts/m², trees, rooftrace.synth)
  of terraced rows with exact truth: rows with height steps between houses,
  rows of gables across the row (party gutters), a row of identical houses
  (no boundary in the data: one part is the right answer there) and single
  houses that must stay whole.  Truth: each house's roof outline.
* ``delft``: AHN3 Delft (the two tiles, EPSG:7415) against the 160 BGT
  ``pand`` footprints (ground-level walls: the roofs overhang them by
  0.2–1 m; parts are roof outlines).

For every reference polygon (house or BGT footprint) the best intersection
over union (IoU) with a part and with a whole building is measured; a
reference is *found* at IoU ≥ 0.5.  Counts: reference polygons, buildings
and parts overlapping them, parts holding ≥ 2 references (each with ≥ 50 %
of its area inside the part: under-split) and references cut into ≥ 2 parts
(each part holding ≥ 25 % of it: over-split).

With ``--footprints`` on Delft the footprint run is measured too: buildings
per footprint status, the share of each footprint's area its roof outline
covers, and the outline area beyond the footprint (the overhang).

Usage::

    .venv/bin/python benchmarks/bench_parts.py --dataset synth
    .venv/bin/python benchmarks/bench_parts.py --dataset delft --footprints
    .venv/bin/python benchmarks/bench_parts.py --dataset delft --from delft.gpkg   # layers of a `rooftrace run`
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pyproj
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
DELFT = ROOT.parent / "shared" / "data" / "3dfier_delft_ahn3_bgt"


def _intersections(refs: list, cands: list) -> np.ndarray:
    """``a[i, j]``: area (m²) of reference i intersecting candidate j."""
    a = np.zeros((len(refs), len(cands)))
    if refs and cands:
        tree = shapely.STRtree(cands)
        for i, r in enumerate(refs):
            for j in tree.query(r, predicate="intersects"):
                a[i, j] = r.intersection(cands[j]).area
    return a


def score(refs: list, buildings: list, parts: list) -> dict:
    """IoU matching of reference polygons to whole buildings and to parts (see the module docstring)."""
    refs = [shapely.force_2d(r) for r in refs]
    tree = shapely.STRtree(refs)

    def near(polys):
        return [shapely.force_2d(p) for p in polys if len(tree.query(shapely.force_2d(p), predicate="intersects"))]

    buildings, parts = near(buildings), near(parts)
    out = {"n_reference": len(refs), "n_buildings": len(buildings), "n_parts": len(parts)}
    for name, cands in (("buildings", buildings), ("parts", parts)):
        inter = _intersections(refs, cands)
        ref_area = np.array([r.area for r in refs])[:, None]
        iou = inter / (ref_area + np.array([c.area for c in cands])[None, :] - inter) if cands else inter
        best = iou.max(axis=1) if iou.size else np.zeros(len(refs))
        share = inter / ref_area  # share of each reference's area inside each candidate
        out[f"found_{name}"] = float(np.mean(best >= 0.5)) if len(refs) else float("nan")
        out[f"mean_iou_{name}"] = float(np.mean(best)) if len(refs) else float("nan")
        out[f"under_split_{name}"] = int(np.sum((share >= 0.5).sum(axis=0) >= 2))
        out[f"over_split_{name}"] = int(np.sum((share >= 0.25).sum(axis=1) >= 2))
    return out


def _terrace_scene(seed: int = 3):
    from rooftrace.synth import SceneOptions, simulate_scene
    from rooftrace.synth.buildings import Building

    o = np.array([500.0, 500.0])
    houses = []
    houses += Building.terrace(1, o + (40, 40), [5.0, 5.5, 6.0, 5.0], 9.0, angle_deg=15.0,
                               eave_heights=[6.0, 7.2, 6.0, 5.0], ridge_heights=[9.5, 10.8, 9.6, 8.4], overhang=0.4)
    houses += [Building.rectangle(10 + i, o + (100 + 6.0 * i, 40), 10.0, 6.0, angle_deg=90.0, kind="gable",
                                  eave_height=6.5, ridge_height=9.5,
                                  overhang_sides=(0.4, 0.4, 0.0 if i else 0.4, 0.0 if i < 3 else 0.4))
               for i in range(4)]
    houses += Building.terrace(20, o + (40, 110), [6.0, 6.0, 6.0], 10.0, angle_deg=-30.0,
                               eave_heights=[6.0, 6.0, 6.0], ridge_heights=[9.0, 9.0, 9.0], overhang=0.4)
    houses += Building.terrace(30, o + (110, 110), [7.0, 7.0, 8.0], 10.0, angle_deg=0.0, kind="flat",
                               eave_heights=[6.0, 9.0, 7.5], ridge_heights=[6.0, 9.0, 7.5], overhang=0.0)
    houses += [Building.l_shape(40, o + (40, 170), 18.0, 8.0, 6.0, kind="hip", eave_height=6.0, ridge_height=9.2),
               Building.rectangle(41, o + (110, 170), 15.0, 9.0, kind="gable", eave_height=6.0,
                                  ridge_height=10.0).with_dormers([-3.2, 3.2])]
    scene = simulate_scene(SceneOptions(seed=seed, size=200.0, origin=tuple(o), image=False), buildings=houses)
    # the identical row is one roof: its truth is the row (nothing in the data separates its houses)
    truth = {b.building_id: b.roof_outline for b in scene.buildings}
    same = shapely.union_all([truth.pop(k) for k in (20, 21, 22)], grid_size=1e-6)
    return scene, [*truth.values(), same]


def run_synth(seed: int) -> dict:
    from rooftrace.pipeline import run_pipeline

    scene, refs = _terrace_scene(seed)
    t0 = time.perf_counter()
    result = run_pipeline(scene.cloud)
    seconds = time.perf_counter() - t0
    parts = [p for bp in result.parts for p in bp.polygons]
    buildings = [o.polygon for o in result.outlines if o.polygon is not None]
    return {**score(refs, buildings, parts), "seconds": seconds}


def score_gpkg(path: Path) -> dict:
    """Delft scores of the ``roof_outlines`` and ``building_parts`` layers of an existing run."""
    from rooftrace.io.footprints import read_footprints
    from rooftrace.io.vector import read_layer

    bgt = read_footprints(DELFT / "bgt_pand.sqlite", pyproj.CRS.from_epsg(7415))
    outlines = [g for g in read_layer(path, "roof_outlines").geometries if g is not None]
    return score(list(bgt.polygons), outlines, list(read_layer(path, "building_parts").geometries))


def run_delft(footprints: bool) -> dict:
    from rooftrace.io.footprints import read_footprints
    from rooftrace.io.points import read_points
    from rooftrace.pipeline import run_pipeline

    cloud = read_points([DELFT / "ahn3_cropped_1.laz", DELFT / "ahn3_cropped_2.laz"], "EPSG:7415")
    bgt = read_footprints(DELFT / "bgt_pand.sqlite", cloud.crs)
    refs = list(bgt.polygons)
    t0 = time.perf_counter()
    result = run_pipeline(cloud)
    out = {"seconds": time.perf_counter() - t0}
    parts = [p for bp in result.parts for p in bp.polygons]
    buildings = [o.polygon for o in result.outlines if o.polygon is not None]
    out.update(score(refs, buildings, parts))
    if footprints:
        t0 = time.perf_counter()
        fp = run_pipeline(cloud, footprints=bgt)
        out["seconds_footprints"] = time.perf_counter() - t0
        status = fp.assignment.status
        out["footprint_status"] = {k: status.count(k) for k in sorted(set(status))}
        cover, beyond = [], []
        for o, poly, s in zip(fp.outlines, bgt.polygons, status):
            if s == "ok" and o.polygon is not None:
                g = shapely.force_2d(o.polygon)
                cover.append(g.intersection(poly).area / poly.area)
                beyond.append(g.difference(poly).area / max(poly.length, 1e-9))  # mean overhang width (m)
        out["footprint_cover_median"] = float(np.median(cover))
        out["footprint_cover_p10"] = float(np.percentile(cover, 10))
        out["overhang_width_median"] = float(np.median(beyond))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", choices=("synth", "delft"), default="synth")
    ap.add_argument("--footprints", action="store_true", help="Delft: also run with the BGT footprints")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--from", dest="existing", type=Path,
                    help="Delft: score the layers of this `rooftrace run` GeoPackage instead of running")
    ap.add_argument("--no-record", action="store_true")
    args = ap.parse_args(argv)
    if args.existing is not None:
        res = score_gpkg(args.existing)
    else:
        res = run_synth(args.seed) if args.dataset == "synth" else run_delft(args.footprints)
    print(json.dumps(res, indent=1))
    if not args.no_record:
        from _results import record

        rows = [{"method": "rooftrace parts", "metric": "found", "value": res["found_parts"], "target": None},
                {"method": "rooftrace parts", "metric": "mean_iou", "value": res["mean_iou_parts"]},
                {"method": "rooftrace parts", "metric": "n_parts", "value": res["n_parts"]},
                {"method": "rooftrace parts", "metric": "under_split", "value": res["under_split_parts"]},
                {"method": "rooftrace parts", "metric": "over_split", "value": res["over_split_parts"]},
                {"method": "whole buildings", "metric": "found", "value": res["found_buildings"]},
                {"method": "whole buildings", "metric": "mean_iou", "value": res["mean_iou_buildings"]},
                {"method": "whole buildings", "metric": "n_parts", "value": res["n_buildings"]},
                {"method": "whole buildings", "metric": "under_split", "value": res["under_split_buildings"]},
                {"method": "reference", "metric": "n_reference", "value": res["n_reference"]}]
        if "footprint_status" in res:
            rows += [{"method": "--footprints", "metric": f"status_{k}", "value": v}
                     for k, v in res["footprint_status"].items()]
            rows += [{"method": "--footprints", "metric": k, "value": res[k], "unit": "m" if "width" in k else ""}
                     for k in ("footprint_cover_median", "footprint_cover_p10", "overhang_width_median")]
        record("parts", args.dataset, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
