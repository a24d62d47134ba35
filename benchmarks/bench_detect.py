"""Benchmark of ``rooftrace detect`` against the reference classes of real AHN3 and IGN LiDAR HD data.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_detect.py [--data ../shared/data]

For each dataset it runs :func:`rooftrace.lidar.detect.detect_buildings`
(which never reads the file's classes), prints the time per stage, and the
per-point one-vs-rest F1 of class 6 (building) and class 2 (ground) against
the classes in the files:

- Delft (AHN3): counted over the points inside the BGT area (union of the
  ``bgt_*.sqlite`` polygons, shrunk by 2 m).  AHN classes 1 (vegetation,
  street furniture), 9 (water) and 26 (bridges) count as "neither".
- Montpellier (IGN LiDAR HD, six tiles): all points; classes 3/4/5
  (vegetation) and 64 count as "neither".
- City3D scene 001 (AHN3, unclassified, local frame): truth from the one BAG
  footprint F of the L-shaped block, see :func:`footprint_scores` for the
  rule.

It also compares the ground stage alone with a baseline a user might script
(lowest point per 25 m cell + 0.5 m height threshold).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import time
from pathlib import Path

import numpy as np
import pyogrio
import shapely

import _data
from rooftrace.io.points import read_points
from rooftrace.lidar.detect import detect_buildings
from rooftrace.lidar.ground import grid_minimum_ground


def f1(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    tp = float(np.sum(pred & truth))
    precision = tp / max(pred.sum(), 1)
    recall = tp / max(truth.sum(), 1)
    return 2 * tp / max(pred.sum() + truth.sum(), 1), precision, recall


def bgt_area(folder: Path, shrink: float = 2.0):
    polys = []
    for path in sorted(folder.glob("bgt_*.sqlite")):
        df = pyogrio.read_dataframe(path)
        polys.extend(shapely.make_valid(g) for g in df.geometry.values if g is not None)
    area = shapely.union_all(polys).buffer(-shrink)
    shapely.prepare(area)
    return area


def report(name: str, files: list[str], crs: str | None, area=None) -> dict:
    t0 = time.perf_counter()
    cloud = read_points(files, crs)
    t_read = time.perf_counter() - t0
    truth = cloud.fields["classification"].copy()
    cloud.fields["classification"][:] = 0  # make sure nothing can lean on the reference
    t0, c0 = time.perf_counter(), time.process_time()
    det = detect_buildings(cloud)
    t_detect, c_detect = time.perf_counter() - t0, time.process_time() - c0
    inside = np.ones(len(cloud), bool) if area is None else shapely.contains_xy(area, cloud.x, cloud.y)
    cls = det.classification[inside]
    ref = truth[inside]
    fb = f1(cls == 6, ref == 6)
    fg = f1(cls == 2, ref == 2)
    base, _ = grid_minimum_ground(cloud.xyz)
    fbase = f1(base[inside], ref == 2)
    print(f"\n## {name}: {len(cloud)} points ({int(inside.sum())} evaluated), {det.n_buildings} buildings")
    print(f"read {t_read:.2f} s; detect {t_detect:.2f} s (CPU {c_detect:.2f} s); total {t_read + t_detect:.2f} s "
          f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    for stage, sec in det.timings.items():
        print(f"  {stage:<10} {sec:6.2f} s")
    print(f"s_avg {det.mean_spacing:.3f} m, d_avg {det.density:.1f} pts/m2, sigma_H {det.sigma_h:.3f} m, "
          f"entropy threshold {det.params['classify']['entropy_threshold']} ({det.params['classify']['method']})")
    print(f"building F1 {fb[0]:.4f} (precision {fb[1]:.4f}, recall {fb[2]:.4f})")
    print(f"ground   F1 {fg[0]:.4f} (precision {fg[1]:.4f}, recall {fg[2]:.4f})")
    print(f"ground baseline (lowest point per 25 m cell + 0.5 m) F1 {fbase[0]:.4f}")
    return {"building_f1": fb[0], "ground_f1": fg[0], "seconds": t_read + t_detect}


def footprint_scores(xyz: np.ndarray, det, footprint, known=(), ring: tuple[float, float] = (1.0, 5.0),
                     cell: float = 5.0) -> dict:
    """Building scores of a detection against one footprint, in a scene holding other buildings.

    Truth (``z0`` is the median of the lowest z per ``cell`` in the band
    ``F + 1 m .. F + 12 m``, a flat-terrain assumption; the detector's own
    ground is not used):

    - *building*: points inside F shrunk by 1 m and above ``z0 + 2 m`` (roof
      points; the 1 m margin absorbs footprint-to-roof misalignment);
    - *not building*: points in the ring ``F + ring[0] .. F + ring[1]`` above
      ``z0 + 2 m``, minus the known footprints of other buildings (+1 m).
      Other buildings whose footprints are unknown may stand in that ring (one
      gabled neighbour touches the block's south side), so two readings:

      * ``leak``: ring points that are class 6 *and* on a roof level mostly
        inside F (more than half its points in F + 1 m) or on no roof level
        (absorbed walls/edges): what the block's own detection spills into
        its surroundings (crowns, hedges linked to it).  Roof levels mostly
        outside F are another building's roof or a separate false building;
        they are not counted (that would need their truth), but their number
        and points are reported;
      * ``any``: every class-6 ring point counts as false (a lower bound of
        F1: true neighbours count as errors).

    Points between F − 1 m and F + ring[0] (walls, eaves, misalignment) and
    points inside F lower than ``z0 + 2 m`` are not counted.
    """
    inner = shapely.contains_xy(footprint.buffer(-1.0), xyz[:, 0], xyz[:, 1])
    near = shapely.contains_xy(footprint.buffer(1.0), xyz[:, 0], xyz[:, 1])
    band = shapely.contains_xy(footprint.buffer(12.0).difference(footprint.buffer(1.0)), xyz[:, 0], xyz[:, 1])
    cells = np.floor(xyz[band, :2] / cell).astype(np.int64)
    _, inv = np.unique(cells, axis=0, return_inverse=True)
    cell_min = np.full(inv.max() + 1, np.inf)
    np.minimum.at(cell_min, inv.ravel(), xyz[band, 2])
    z0 = float(np.median(cell_min))
    high = xyz[:, 2] > z0 + 2.0
    area = footprint.buffer(ring[1]).difference(footprint.buffer(ring[0]))
    for other in known:
        area = area.difference(other.buffer(1.0))
    in_ring = shapely.contains_xy(area, xyz[:, 0], xyz[:, 1]) & high
    truth = inner & high
    is_b = det.classification == 6
    lvl = det.roof_level_id
    nl = int(lvl.max(initial=0)) + 1
    share = np.bincount(lvl, near, nl) / np.maximum(np.bincount(lvl, minlength=nl), 1)
    own = (lvl == 0) | (share[lvl] > 0.5)
    tp = int(np.sum(truth & is_b))
    out = {"z0": z0, "n_building": int(truth.sum()), "n_ring": int(in_ring.sum()),
           "recall": tp / max(int(truth.sum()), 1),
           "ids": sorted(int(b) for b in np.unique(det.building_id[truth & is_b]))}
    for name, false in (("leak", in_ring & is_b & own), ("any", in_ring & is_b)):
        fp = int(false.sum())
        out[f"{name}_fp"] = fp
        out[f"{name}_rate"] = fp / max(int(in_ring.sum()), 1)
        out[f"{name}_f1"] = 2 * tp / max(2 * tp + fp + int(truth.sum()) - tp, 1)
    other = (share < 0.5) & (np.bincount(lvl, in_ring & is_b, nl) > 0)
    other[0] = False
    out["other_levels"] = int(other.sum())
    out["other_points"] = int(np.sum(in_ring & is_b & ~own))
    return out


def report_city3d(folder: Path) -> dict:
    """Detect on City3D scene 001 and score it against its BAG footprint (:func:`footprint_scores`)."""
    cloud = read_points([str(folder / "scene001" / "001.ply")], None)
    t0 = time.perf_counter()
    det = detect_buildings(cloud)
    t_detect = time.perf_counter() - t0
    fp = shapely.union_all(shapely.get_parts(shapely.from_geojson((folder / "scene001" / "001_footprint.geojson").read_text())))
    known = []
    inst = folder / "instances_002" / "002_footprint.geojson"
    if inst.exists():  # other buildings of the same frame (50 of the 159 BAG footprints of the area)
        known = [shapely.geometry.shape(f["geometry"]) for f in json.loads(inst.read_text())["features"]]
    sc = footprint_scores(cloud.xyz, det, fp, known)
    print(f"\n## City3D scene 001 (AHN3, no CRS): {len(cloud)} points, {det.n_buildings} buildings, detect {t_detect:.2f} s")
    print(f"local ground z0 {sc['z0']:.2f} m; {sc['n_building']} roof points inside F - 1 m, {sc['n_ring']} points "
          f"> z0 + 2 m in the ring F + 1..5 m (known footprints + 1 m removed)")
    print(f"recall inside {sc['recall']:.4f} (building ids {sc['ids']})")
    print(f"leak (class 6 on the block's own roof levels or absorbed) in ring: {sc['leak_fp']} points, "
          f"rate {sc['leak_rate']:.4f}, building F1 {sc['leak_f1']:.4f}")
    print(f"any class 6 in ring: {sc['any_fp']} points, rate {sc['any_rate']:.4f}, building F1 (lower bound) "
          f"{sc['any_f1']:.4f}; not counted: {sc['other_points']} points on {sc['other_levels']} roof levels mostly outside F")
    return sc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(_data.DATA))
    args = ap.parse_args()
    data = Path(args.data)
    delft = data / "3dfier_delft_ahn3_bgt"
    report("Delft AHN3 (inside BGT area - 2 m)",
           [str(delft / "ahn3_cropped_1.laz"), str(delft / "ahn3_cropped_2.laz")], "EPSG:28992", bgt_area(delft))
    ign = sorted(glob.glob(str(data / "ign_montpellier_lidarhd_bdortho" / "*.laz")))
    report("Montpellier IGN LiDAR HD (6 tiles, all points)", ign, None)
    city3d = data / "city3d_ahn3_single_buildings"
    if (city3d / "scene001" / "001.ply").exists():
        report_city3d(city3d)


if __name__ == "__main__":
    main()
