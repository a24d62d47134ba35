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

It also compares the ground stage alone with a baseline a user might script
(lowest point per 25 m cell + 0.5 m height threshold).
"""

from __future__ import annotations

import argparse
import glob
import os
import time
from pathlib import Path

import numpy as np
import pyogrio
import shapely

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    args = ap.parse_args()
    data = Path(args.data)
    delft = data / "3dfier_delft_ahn3_bgt"
    report("Delft AHN3 (inside BGT area - 2 m)",
           [str(delft / "ahn3_cropped_1.laz"), str(delft / "ahn3_cropped_2.laz")], "EPSG:28992", bgt_area(delft))
    ign = sorted(glob.glob(str(data / "ign_montpellier_lidarhd_bdortho" / "*.laz")))
    report("Montpellier IGN LiDAR HD (6 tiles, all points)", ign, None)


if __name__ == "__main__":
    main()
