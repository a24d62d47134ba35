"""Cost of the roof-face boundary rules (``[planes] face_boundaries``) on AHN3 Delft.

For each rule (``each``: every shared boundary by its own rule, the
default; ``held``: one held-back tolerance per roof; ``free``: one tolerance
of 5 cells) the whole run (both Delft tiles, EPSG:28992, LiDAR only or with
``--footprints``) is repeated in one process, the rules alternating after a
warm-up run (compiled kernels, caches), and the CPU seconds of the run and of
its roof, parts and model steps are taken (the pipeline's step timers read
with ``time.process_time``; the pipeline limits the thread pools, so this is
one core's work, little disturbed by other processes on the machine), best
of ``--repeats``.  Sizes: vertices of the roof faces and of the LoD 2.2
solids' rings.  The accuracy of each rule (RMSE, validity) is
``bench_models.py --face-boundaries``.

Usage::

    .venv/bin/python benchmarks/bench_faces.py
    .venv/bin/python benchmarks/bench_faces.py --footprints ../shared/data/3dfier_delft_ahn3_bgt/bgt_pand.sqlite

Recorded as dataset ``delft`` or ``delft_footprints``.
"""

from __future__ import annotations

import argparse
import sys
import time
import types
from pathlib import Path

import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _data import DATA
from _results import record
from rooftrace import pipeline
from rooftrace.io.footprints import read_footprints
from rooftrace.io.points import read_points

RULES = ("each", "held", "free")
STEPS = ("roof_planes", "parts", "models")


def _sizes(result) -> tuple[int, int]:
    """Roof face vertices and LoD 2.2 ring vertices (closing vertices not counted)."""
    faces = sum(len(shapely.get_coordinates(f)) - 1 - len(f.interiors) for st in result.structures for f in st.faces)
    rings = sum(len(r) for m in result.models for p in m.parts if "2.2" in p.lods for s in p.lods["2.2"].surfaces
                for r in s.rings)
    return faces, rings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--footprints", type=Path, default=None, help="footprints of the run (e.g. bgt_pand.sqlite)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per rule (best of)")
    args = ap.parse_args()
    files = [DATA / "3dfier_delft_ahn3_bgt" / f"ahn3_cropped_{i}.laz" for i in (1, 2)]
    cloud = read_points(files, "EPSG:28992")
    footprints = read_footprints(args.footprints, cloud.crs) if args.footprints else None
    # the pipeline's step timers, read in CPU seconds
    pipeline.time = types.SimpleNamespace(perf_counter=time.process_time)
    pipeline.run_pipeline(cloud, footprints=footprints)  # warm-up
    best = {r: {} for r in RULES}
    sizes = {}
    for _ in range(args.repeats):
        for rule in RULES:
            c0 = time.process_time()
            result = pipeline.run_pipeline(cloud, footprints=footprints,
                                           config={"planes": {"face_boundaries": rule}})
            cpu = {"run": time.process_time() - c0, **{s: result.timings.get(s, 0.0) for s in STEPS}}
            best[rule] = {k: min(v, best[rule].get(k, v)) for k, v in cpu.items()}
            sizes[rule] = _sizes(result)
            print(f"{rule}: CPU run {cpu['run']:.1f} s, " + ", ".join(f"{s} {cpu[s]:.1f} s" for s in STEPS)
                  + f"; face vertices {sizes[rule][0]}, LoD 2.2 ring vertices {sizes[rule][1]}", flush=True)
    rows = []
    for rule in RULES:
        method = f"face_boundaries={rule}"
        for k, v in best[rule].items():
            rows.append({"method": method, "metric": f"cpu_{k}_s", "value": v, "unit": "s", "target": None})
        rows.append({"method": method, "metric": "roof_face_vertices", "value": sizes[rule][0], "unit": ""})
        rows.append({"method": method, "metric": "lod22_ring_vertices", "value": sizes[rule][1], "unit": ""})
        if rule != "free":
            rows.append({"method": method, "metric": "run_cpu_vs_free", "unit": "",
                         "value": best[rule]["run"] / best["free"]["run"], "target": "<= 1.10"})
            rows.append({"method": method, "metric": "ring_vertices_vs_free", "unit": "",
                         "value": sizes[rule][1] / sizes["free"][1], "target": "<= 1.5"})
        print(f"{rule}: best CPU " + ", ".join(f"{k} {v:.1f} s" for k, v in best[rule].items()))
    print(record("faces", "delft" if footprints is None else "delft_footprints", rows))


if __name__ == "__main__":
    main()
