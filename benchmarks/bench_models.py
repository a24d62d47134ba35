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
  0.15 m; flat LoD 1.2 roofs score about 1.6 m there);
- **time**: the run, its model step, and the CityJSONSeq / CityJSON writing
  (target: writing adds at most 20 % to the run);
- **memory** of writing: the peak of Python allocations (tracemalloc) while
  writing ``k`` copies of the buildings, ``k = 1, 4``: flat when the writers
  stream.

Usage::

    .venv/bin/python benchmarks/bench_models.py
    .venv/bin/python benchmarks/bench_models.py --val3dity /opt/val3dity/bin/val3dity
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

import laspy
import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _data import DATA
from _results import record
from rooftrace.io.models import write_models
from rooftrace.io.points import read_points
from rooftrace.model import LODS, solid_errors
from rooftrace.model.measure import roof_height_at
from rooftrace.pipeline import run_pipeline
from val3dity import BUILD_HINT, validate

DELFT = DATA / "3dfier_delft_ahn3_bgt"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--val3dity", default=None, help="val3dity binary (default: $VAL3DITY, the PATH, build.sh's place)")
    ap.add_argument("--repeats", type=int, default=3, help="writes timed (best of)")
    args = ap.parse_args()
    files = [DELFT / f"ahn3_cropped_{i}.laz" for i in (1, 2)]
    cloud = read_points(files, "EPSG:28992")

    t0 = time.perf_counter()
    result = run_pipeline(cloud)
    run_s = time.perf_counter() - t0
    models = result.models
    n = len(models)
    print(f"run {run_s:.1f} s (models {result.timings['models']:.1f} s), {n} buildings with an outline")

    rows = []
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
    z6 = []
    for f in files:
        las = laspy.read(f)
        keep = np.asarray(las.classification) == 6
        z6.append(np.column_stack([np.asarray(las.x)[keep], np.asarray(las.y)[keep], np.asarray(las.z)[keep]]))
    pts = np.vstack(z6)
    covered = None
    for lod in LODS:
        solids = [p.lods[lod] for m in models for p in m.parts if lod in p.lods]
        h = roof_height_at(solids, pts[:, :2])
        if lod == "2.2":
            covered = np.isfinite(h)
        d = (pts[:, 2] - h)[np.isfinite(h)]
        rmse = float(np.sqrt(np.mean(d * d)))
        med = float(np.median(np.abs(d)))
        p90 = float(np.percentile(np.abs(d), 90))
        print(f"LoD {lod}: vertical RMSE of {len(d)} class-6 points {rmse:.3f} m (median |dz| {med:.3f} m, "
              f"90th percentile {p90:.3f} m, {np.mean(np.abs(d) > 1):.1%} off by more than 1 m)")
        rows.append({"method": "rooftrace", "metric": f"p90_abs_dz_lod{lod.replace('.', '')}", "value": p90,
                     "unit": "m", "target": None})
        rows.append({"method": "rooftrace", "metric": f"rmse_class6_lod{lod.replace('.', '')}", "value": rmse,
                     "unit": "m", "target": "<= 0.15" if lod == "2.2" else None})
        rows.append({"method": "rooftrace", "metric": f"median_abs_dz_lod{lod.replace('.', '')}", "value": med,
                     "unit": "m", "target": None})
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
    else:
        print(BUILD_HINT + "; own check only")
    shutil.rmtree(tmp, ignore_errors=True)
    print(record("models", "delft", rows))


if __name__ == "__main__":
    main()
