"""CPU seconds of ``rooftrace run`` on Delft per step, LiDAR only and with the BGT footprints, against the decode floor.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_run_time.py [--repeat 3] [--no-record] [--only lidar|footprints]

Both AHN3 Delft tiles, written to a GeoPackage and a CityJSONSeq as in::

    rooftrace run ahn3_cropped_1.laz ahn3_cropped_2.laz --crs EPSG:28992 -o delft.gpkg -o delft.city.jsonl [--footprints bgt_pand.sqlite]

The command runs in this process (``rooftrace.cli.main.main``) so that the
pipeline's own clock (:attr:`rooftrace.pipeline.RunResult.cpu_seconds`:
process CPU per step, every thread counted) can be read; ``read + write``
is the rest of the command (decoding the LAZ, reading the footprints,
writing both files).  The start-up (importing the command line) is timed in
a fresh interpreter.  The machine is shared, so CPU time (which grows much
less with the load than wall time) is what is reported, the best of
``--repeat`` runs (numba's caches warm: the first run of a fresh source
tree compiles).  The floor is laspy + lazrs decoding the two tiles (CPU,
best of three).  Every run's outputs must be identical to the first one's.
"""

from __future__ import annotations

import argparse
import filecmp
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import laspy

import _data
from _results import record

DELFT = _data.DATA / "3dfier_delft_ahn3_bgt"
TILES = [DELFT / "ahn3_cropped_1.laz", DELFT / "ahn3_cropped_2.laz"]
FOOTPRINTS = DELFT / "bgt_pand.sqlite"
#: the pipeline's steps, in order (``detect`` holds the detection's own steps)
STEPS = ("detect", "footprints", "outline", "roof_planes", "parts", "models", "layers")
#: CPU target of the LiDAR-only run (seconds): the run as it was before the second plane pass
TARGET = 34.0


def decode_cpu(repeat: int = 3) -> float:
    """Best-of CPU seconds of laspy + lazrs decoding the two tiles (all threads)."""
    backend = laspy.LazBackend.LazrsParallel if laspy.LazBackend.LazrsParallel.is_available() else None
    best = float("inf")
    for _ in range(repeat):
        c0 = time.process_time()
        for f in TILES:
            laspy.read(f, laz_backend=backend)
        best = min(best, time.process_time() - c0)
    return best


def startup_cpu(repeat: int = 3) -> float:
    """Best-of CPU seconds of a fresh interpreter importing the command line."""
    best = float("inf")
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([sys.executable, "-c", "import rooftrace.cli.main"], check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        best = min(best, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return best


def run_once(out: Path, footprints: bool) -> dict[str, float]:
    """One ``rooftrace run`` in this process: CPU per step, ``read + write`` and ``total`` (s)."""
    import rooftrace.pipeline
    from rooftrace.cli.main import main

    seen = []
    original = rooftrace.pipeline.run_pipeline

    def clocked(*args, **kwargs):
        seen.append(original(*args, **kwargs))
        return seen[-1]

    args = ["run", *map(str, TILES), "--crs", "EPSG:28992", "-o", str(out / "delft.gpkg"),
            "-o", str(out / "delft.city.jsonl"), "--quiet", "--overwrite"]
    if footprints:
        args += ["--footprints", str(FOOTPRINTS)]
    rooftrace.pipeline.run_pipeline = clocked
    try:
        c0 = time.process_time()
        code = main(args)
        total = time.process_time() - c0
    finally:
        rooftrace.pipeline.run_pipeline = original
    if code != 0 or len(seen) != 1:
        raise SystemExit(f"rooftrace {' '.join(args)}: exit {code}")
    cpu = {step: seen[0].cpu_seconds.get(step, 0.0) for step in STEPS}
    cpu["read + write"] = total - sum(cpu.values())
    cpu["total"] = total
    return cpu


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-record", action="store_true", help="print only")
    ap.add_argument("--only", choices=("lidar", "footprints"), help="one of the two runs (implies --no-record)")
    a = ap.parse_args(argv)
    for path in [*TILES, FOOTPRINTS]:
        if not path.exists():
            raise SystemExit(f"missing {path}")
    floor = decode_cpu()
    start = startup_cpu()
    print(f"decode floor (laspy + lazrs, CPU): {floor:.2f} s; start-up: {start:.2f} s", flush=True)
    rows = [{"method": "laspy decode (floor)", "metric": "cpu_s", "value": round(floor, 3), "unit": "s"},
            {"method": "rooftrace (start-up)", "metric": "cpu_s", "value": round(start, 3), "unit": "s"}]
    with tempfile.TemporaryDirectory(prefix="bench_run_time_") as tmp:
        for footprints, method in ((False, "rooftrace run (LiDAR only)"), (True, "rooftrace run --footprints")):
            if a.only and a.only != ("footprints" if footprints else "lidar"):
                continue
            best, first = None, None
            for k in range(a.repeat):
                out = Path(tmp) / f"{int(footprints)}_{k}"
                out.mkdir()
                cpu = run_once(out, footprints)
                if first is None:
                    first = out
                elif not filecmp.cmp(first / "delft.city.jsonl", out / "delft.city.jsonl", shallow=False):
                    raise SystemExit(f"{method}: run {k + 1} wrote another CityJSONSeq than run 1")
                print(f"{method} run {k + 1}: " + ", ".join(f"{s} {v:.2f}" for s, v in cpu.items()), flush=True)
                best = cpu if best is None or cpu["total"] < best["total"] else best
            total = best["total"] + start
            rows += [{"method": method, "metric": f"cpu_{step.replace(' + ', '_').replace(' ', '_')}_s",
                      "value": round(v, 3), "unit": "s"} for step, v in best.items() if step != "total"]
            rows.append({"method": method, "metric": "cpu_total_s", "value": round(total, 3), "unit": "s",
                         "target": f"<= {TARGET:g}" if not footprints else None})
            rows.append({"method": method, "metric": "times_decode_floor", "value": round(total / floor, 2)})
            print(f"{method}: {total:.2f} s CPU with the start-up ({total / floor:.1f} x the decode floor)")
    if not (a.no_record or a.only):
        print(record("run_time", "delft_ahn3_both_tiles", rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
