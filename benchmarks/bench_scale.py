"""City-scale benchmark (issue 9): tiled runs against one piece, workers, throughput, memory, decode floor.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_scale.py delft [--data ../shared/data]
    .venv/bin/python benchmarks/bench_scale.py block --block /tmp/rooftrace-block [--tile-size 250] [--workers 2]

``delft`` runs the two Delft AHN3 tiles as one piece and as 2 x 2 tiles of
250 m (60 m buffer) with 1 and 2 workers, and checks that the three outputs
hold the same buildings (count, outlines within 1e-6 m, attributes).
``block`` runs every ``points.laz`` under ``--block`` tiled: a synthetic
block of 3 x 3 scenes made with ``rooftrace simulate`` on first use (about
11 M points; keep it outside the repository).

Every run is a ``rooftrace run --json`` subprocess; its peak memory is the
largest sum of the resident set sizes of the process and all its children
(Dask workers included), polled every 0.1 s.  The floor is the time laspy
with the lazrs backend needs to decode the same files (best of three).
Stage throughput is points of the input per second of the stage, summed
over tiles (tiles also process their buffers, so this is the cost per
input point, not the speed of the stage on a tile).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import laspy
import numpy as np
import psutil
import shapely

import _data

ROOT = Path(__file__).resolve().parents[1]
RT = str(Path(sys.executable).with_name("rooftrace"))


def decode_seconds(files: list[Path], repeat: int = 3) -> tuple[float, int]:
    """Best-of time for laspy + lazrs to decode ``files`` (the floor), and their point count."""
    backend = laspy.LazBackend.LazrsParallel if laspy.LazBackend.LazrsParallel.is_available() else None
    best, n = np.inf, 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = sum(len(laspy.read(f, laz_backend=backend).points) for f in files)
        best = min(best, time.perf_counter() - t0)
    return best, n


def run(args: list[str]) -> tuple[dict, float, float]:
    """Run ``rooftrace`` with ``args``; returns its JSON summary, wall seconds and peak tree RSS (bytes).

    The summary gains ``cpu_seconds``: user + system time of the run and of
    every process it started (Dask workers included), which unlike the wall
    time does not grow with the load of other users of the machine.
    """
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen([RT, *args, "--json", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = [0]

    def poll() -> None:
        p = psutil.Process(proc.pid)
        while proc.poll() is None:
            try:
                rss = sum(c.memory_info().rss for c in [p, *p.children(recursive=True)])
            except psutil.Error:
                rss = 0
            peak[0] = max(peak[0], rss)
            time.sleep(0.1)

    th = threading.Thread(target=poll, daemon=True)
    th.start()
    out, err = proc.communicate()
    th.join()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"rooftrace {' '.join(args)} failed:\n{err[-3000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = json.loads(out.strip().splitlines()[-1])
    summary["cpu_seconds"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return summary, wall, peak[0]


def same_buildings(a: Path, b: Path, tol: float = 1e-6) -> str:
    """'identical', or what differs between two run outputs."""
    from rooftrace.io.vector import read_layer

    for name in ("roof_outlines", "ridges", "roof_faces"):
        la, lb = read_layer(a, name), read_layer(b, name)
        if len(la) != len(lb):
            return f"{name}: {len(la)} vs {len(lb)} features"
        for i, (ga, gb) in enumerate(zip(la.geometries, lb.geometries)):
            if not ((ga is None and gb is None) or shapely.equals_exact(ga, gb, tolerance=tol)):
                return f"{name}: feature {i} differs"
        for key in la.attributes:
            va, vb = np.asarray(la.attributes[key]), np.asarray(lb.attributes[key])
            same = np.array_equal(va, vb, equal_nan=True) if va.dtype.kind == "f" else va.tolist() == vb.tolist()
            if not same:
                return f"{name}.{key} differs"
    return "identical"


HEADER = ("| run | points | wall s | points/s | / decode | CPU s (user + sys) | peak GiB (all processes) | buildings |\n"
          "|---|---|---|---|---|---|---|---|")


def row(name: str, n: int, wall: float, peak: float, floor: float, summary: dict) -> str:
    return (f"| {name} | {n:,} | {wall:.1f} | {n / wall:,.0f} | {wall / floor:.0f}x | {summary['cpu_seconds']:.0f} | "
            f"{peak / 2**30:.2f} | {summary['buildings']} |")


def load() -> str:
    """The machine's load averages (1, 5, 15 min) and core count: wall times depend on them."""
    return f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores"


def stage_table(n: int, summary: dict) -> str:
    stages = summary.get("stage_seconds") or summary.get("timings", {})
    extra = summary.get("timings", {}) if "stage_seconds" in summary else {}
    lines = ["| stage | seconds | input points/s |", "|---|---|---|"]
    for k, v in {**extra, **stages}.items():
        if k == "tiles":
            continue
        # a stage that rounds to 0.0 s has no meaningful rate
        lines.append(f"| {k} | {v:.1f} | {n / v:,.0f} |" if v >= 0.05 else f"| {k} | {v:.1f} | – |")
    return "\n".join(lines)


def delft(data: Path) -> None:
    files = [data / "3dfier_delft_ahn3_bgt" / f"ahn3_cropped_{i}.laz" for i in (1, 2)]
    print(load())
    floor, n = decode_seconds(files)
    print(f"decode floor: {floor:.2f} s for {n:,} points ({n / floor:,.0f} points/s)")
    rows, outs, sums = [], {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        cases = {
            "one piece": [],
            "4 tiles, 1 worker": ["--tile-size", "250", "--buffer", "60"],
            "4 tiles, 2 workers": ["--tile-size", "250", "--buffer", "60", "--workers", "2"],
        }
        for name, extra in cases.items():
            out = Path(tmp) / f"{len(outs)}.gpkg"
            summary, wall, peak = run(["run", *map(str, files), "--crs", "EPSG:28992", "-o", str(out), *extra])
            rows.append(row(name, n, wall, peak, floor, summary))
            outs[name], sums[name] = out, summary
        print(HEADER)
        print("\n".join(rows))
        print(load())
        for name in list(cases)[1:]:
            print(f"{name} vs one piece: {same_buildings(outs['one piece'], outs[name])}")
        for name in cases:
            print(f"\nstages, {name}:\n{stage_table(n, sums[name])}")


def make_block(folder: Path, side: int = 3, size: float = 310.0, density: float = 12.0) -> None:
    """``side`` x ``side`` scenes of ``rooftrace simulate`` side by side (3 x 3 x 310 m at 12 pts/m²: 10.9 M points)."""
    folder.mkdir(parents=True, exist_ok=True)
    jobs = []
    for k in range(side * side):
        i, j = divmod(k, side)
        if (folder / f"s{k}" / "points.laz").exists():
            continue
        cfg = folder / f"s{k}.toml"
        cfg.write_text(f"[simulate]\norigin = [{85000 + size * i}, {447000 + size * j}]\n")
        jobs.append([RT, "simulate", "-o", str(folder / f"s{k}"), "--size", str(size), "--density", str(density),
                     "--seed", f"1{k}", "--no-image", "--config", str(cfg), "--overwrite", "-q"])
    for start in range(0, len(jobs), 2):  # two at a time: this machine has two cores
        procs = [subprocess.Popen(cmd) for cmd in jobs[start:start + 2]]
        if any(p.wait() for p in procs):
            raise SystemExit("rooftrace simulate failed")


def block(folder: Path, tile_size: float | None, workers: int, buffer: float) -> None:
    make_block(folder)
    files = sorted(folder.glob("*/points.laz"))
    print(load())
    floor, n = decode_seconds(files)
    print(f"{len(files)} files, decode floor: {floor:.2f} s for {n:,} points ({n / floor:,.0f} points/s)")
    out = folder / "roofs.gpkg"
    size = [] if tile_size is None else ["--tile-size", str(tile_size)]
    summary, wall, peak = run(["run", *map(str, files), "-o", str(out), "--overwrite", *size,
                               "--buffer", str(buffer), "--workers", str(workers)])
    print(HEADER)
    derived = " (derived)" if tile_size is None else ""
    print(row(f"{summary['tiles']} tiles of {summary['tile_size']:g} m{derived}, {workers} workers", n, wall, peak,
              floor, summary))
    print(load())
    print(f"\nstages:\n{stage_table(n, summary)}")
    print(f"\ntile points (with buffers): {summary['tile_points']:,}; parameter sample: {summary['sample_points']:,} "
          f"points; buildings reaching a buffer edge: {summary['edge_buildings']}")
    print(json.dumps(summary["parameters"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    d = sub.add_parser("delft")
    d.add_argument("--data", type=Path, default=_data.DATA)
    b = sub.add_parser("block")
    b.add_argument("--block", type=Path, default=Path("/tmp/rooftrace-block"))
    b.add_argument("--tile-size", type=float, default=None, help="default: derived from the density, as run's")
    b.add_argument("--buffer", type=float, default=60.0)
    b.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    if a.what == "delft":
        delft(a.data)
    else:
        block(a.block, a.tile_size, a.workers, a.buffer)


if __name__ == "__main__":
    main()
