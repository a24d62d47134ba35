"""CPU seconds of the roof-plane and ridge step on AHN3 Delft (LiDAR only), and of its parts.

The step is :func:`rooftrace.roof.structure.roof_structure` for every
outlined building, as ``rooftrace run`` calls it (``roof_planes`` in the
run's timings).  Both Delft tiles are detected and outlined once; the step
then runs ``--repeat`` times after a warm-up run (numba's caches), one BLAS
thread as in the pipeline, and the best CPU time is reported with the share
of each part (the module functions of :mod:`rooftrace.roof.structure`
wrapped with ``time.process_time``; the rest is the step's own glue).  Every
run must give the same roof structures as the first (planes, labels, faces,
ridges, compared exactly).

Usage (from the repository root)::

    PYTHONPATH=src .venv/bin/python benchmarks/bench_roof_step.py [--repeat 3] [--no-record]

Another source tree is measured by pointing ``PYTHONPATH`` at its ``src``
(with ``--no-record``).  Recorded as bench ``roof_step``, dataset ``delft``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import shapely
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _data import DATA
from _results import record
from rooftrace.config import RunOptions
from rooftrace.contour.outline import outline_buildings
from rooftrace.io.points import read_points
from rooftrace.lidar.detect import detect_buildings
from rooftrace.pipeline import points_by_building
from rooftrace.roof import structure

#: the parts of the step, as named in rooftrace.roof.structure
PARTS = ("_edge_percentile", "point_neighbourhoods", "segment_planes", "detail_planes", "plane_adjacency",
         "intersection_lines", "partition_outline", "snap_to_lines", "merge_close_vertices", "step_edges")


def _clock_parts(spent: dict[str, float]) -> None:
    """Wrap the step's parts in rooftrace.roof.structure so that their CPU seconds add up in ``spent``."""
    for name in PARTS:
        f = getattr(structure, name, None)
        if f is None:  # a tree without this part
            continue

        def clocked(*args, _f=f, _name=name, **kwargs):
            c0 = time.process_time()
            try:
                return _f(*args, **kwargs)
            finally:
                spent[_name] = spent.get(_name, 0.0) + time.process_time() - c0

        setattr(structure, name, clocked)


def _fingerprint(st) -> tuple:
    """Everything a roof structure outputs, comparable exactly."""
    return (st.building_id, st.status, st.planes.tobytes(), st.labels.tobytes(), st.plane_detail.tobytes(),
            tuple(shapely.to_wkb(g) for g in st.faces), tuple(st.face_plane),
            tuple(shapely.to_wkb(g) for g in st.ridges), tuple(st.ridge_kind), tuple(st.ridge_planes))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-record", action="store_true", help="print only")
    a = ap.parse_args(argv)
    tiles = [DATA / "3dfier_delft_ahn3_bgt" / f"ahn3_cropped_{i}.laz" for i in (1, 2)]
    cloud = read_points(tiles, "EPSG:28992")
    options = RunOptions.from_config(None)
    det = detect_buildings(cloud, options.detect)
    members = points_by_building(det.building_id)
    around = (det.building_id <= 0) & (det.classification != 7)
    outlines = [o for o in outline_buildings(cloud.xyz, det.building_id, options.outline,
                                             mean_spacing=det.mean_spacing, context_xy=cloud.xyz[around])
                if o.polygon is not None and not o.polygon.is_empty and o.building_id in members]
    spent: dict[str, float] = {}
    _clock_parts(spent)

    def step() -> list:
        with threadpool_limits(limits=1, user_api="blas"):
            return [structure.roof_structure(cloud.xyz[members[o.building_id]], o.polygon, options.roof,
                                             mean_spacing=det.mean_spacing, building_id=o.building_id)
                    for o in outlines]

    first = [_fingerprint(st) for st in step()]  # warm-up: numba's caches
    best, best_parts = np.inf, {}
    for k in range(a.repeat):
        spent.clear()
        c0 = time.process_time()
        got = step()
        cpu = time.process_time() - c0
        if [_fingerprint(st) for st in got] != first:
            raise SystemExit(f"run {k + 1} gave other roof structures than the warm-up run")
        print(f"run {k + 1}: {cpu:.2f} s CPU; " + ", ".join(f"{n} {v:.2f}" for n, v in spent.items()), flush=True)
        if cpu < best:
            best, best_parts = cpu, dict(spent)
    points = sum(len(members[o.building_id]) for o in outlines)
    print(f"roof step: {best:.2f} s CPU (best of {a.repeat}), {len(outlines)} buildings, {points} points")
    if not a.no_record:
        rows = [{"method": "roof_structure", "metric": "cpu_roof_step_s", "value": round(best, 3), "unit": "s",
                 "target": "<= 6.5"},
                *({"method": "roof_structure", "metric": f"cpu_{n.lstrip('_')}_s", "value": round(v, 3), "unit": "s"}
                  for n, v in best_parts.items()),
                {"method": "roof_structure", "metric": "cpu_glue_s", "value": round(best - sum(best_parts.values()), 3),
                 "unit": "s"},
                {"method": "roof_structure", "metric": "buildings", "value": len(outlines)},
                {"method": "roof_structure", "metric": "points", "value": points}]
        print(record("roof_step", "delft", rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
