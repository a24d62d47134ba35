"""Interrupts of a real run: SIGINT and SIGTERM at seeded random moments of ``rooftrace run`` on Delft.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_interrupt.py [--n 50] [--seed 21] [--parallel 2] [--data ../shared/data]

A first, uninterrupted run of the Delft AHN3 crop (``ahn3_cropped_2.laz``,
208 k points, ``--crs EPSG:28992 --classified``) gives the run's length T.
Then ``--n`` runs, half SIGINT and half SIGTERM, each get their signal at a
moment drawn uniformly from [0.3 s, 1.05 T] (``--seed``), sent to the
process group as a Ctrl-C in a terminal is; every fifth run is tiled on a
local Dask cluster (2 workers), and half of the runs replace an earlier
output.  A run passes when it exits 130 (SIGINT) or 143 (SIGTERM) with
exactly ``error: interrupted`` on stderr, or finished (exit 0) before its
signal; its folder holds no temporary file (a tiled run keeps
``OUTPUT.parts`` for ``--resume``); and each output is the earlier one, or
absent, or a whole new one (all layers, as many buildings as the reference),
the GeoPackage and the classified points both new or both old.
The latency is the time from the signal to the process's exit.
``tests/cli/test_interrupt.py`` is the same check, 8 interrupts of a small scene.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import _data  # the benchmarks' folder is on sys.path when a script runs
import _results

ROOT = Path(__file__).resolve().parents[1]
GOOD = b"an earlier result"
CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
LAYERS = {"roof_outlines", "ridges", "roof_faces"}


def command(src: Path, folder: Path, tiled: bool) -> list[str]:
    args = [sys.executable, "-m", "rooftrace", "run", str(src), "--crs", "EPSG:28992", "-o", str(folder / "roofs.gpkg"),
            "--classified", str(folder / "points.laz"), "-q", "--overwrite"]
    return args + (["--workers", "2", "--tile-size", "120"] if tiled else [])


def start(args: list[str]) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}  # warnings shown: one on stderr is a failure
    return subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)


def problems(code: int, err: str, signum: int, folder: Path, existing: bool, buildings: int) -> list[str]:
    """What is wrong with what a run left (empty: nothing)."""
    from rooftrace.io.vector import list_layers, read_layer

    found = []
    if code == 0:
        if err:
            found.append(f"finished with stderr {err!r}")
    elif code != CODES[signum] or err != "error: interrupted\n":
        found.append(f"exit {code}, stderr {err[-300:]!r}")
    outputs = [folder / "roofs.gpkg", folder / "points.laz"]
    for path in outputs:
        if path.exists() and path.read_bytes() != GOOD:
            if path.suffix == ".gpkg":
                if set(list_layers(path)) != LAYERS or len(read_layer(path, "roof_outlines")) != buildings:
                    found.append(f"{path.name} is not a whole result")
            else:
                import laspy

                if len(laspy.read(path).points) == 0:
                    found.append(f"{path.name} is empty")
        elif path.exists() != existing or (code == 0 and not path.exists()):
            found.append(f"{path.name}: {'missing' if existing else 'unexpected'}")
        elif code == 0 and path.read_bytes() == GOOD:
            found.append(f"{path.name} not replaced by a finished run")
    new = [path.exists() and path.read_bytes() != GOOD for path in outputs]
    if existing and new[0] != new[1]:  # renamed into place together (rooftrace.io.atomic.commit_together)
        found.append("one output replaced, the other not")
    left = {p.name for p in folder.iterdir()} - {p.name for p in outputs} - {"roofs.gpkg.parts"}
    if left:
        found.append(f"left {sorted(left)}")
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=_data.DATA)
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--parallel", type=int, default=2, help="runs at a time")
    args = ap.parse_args()
    src = args.data / "3dfier_delft_ahn3_bgt" / "ahn3_cropped_2.laz"
    if not src.exists():
        sys.exit(f"{src} not found; set ROOFTRACE_DATA or pass --data")
    from rooftrace.io.vector import read_layer

    with tempfile.TemporaryDirectory(prefix="bench-interrupt-") as tmp:
        tmp = Path(tmp)
        (tmp / "ref").mkdir()
        t0 = time.perf_counter()
        ref = start(command(src, tmp / "ref", tiled=False))
        assert ref.wait() == 0, ref.stderr.read().decode()
        length = time.perf_counter() - t0
        buildings = len(read_layer(tmp / "ref" / "roofs.gpkg", "roof_outlines"))
        print(f"reference run: {length:.1f} s, {buildings} buildings", flush=True)

        rng = np.random.default_rng(args.seed)
        plan = [((signal.SIGINT, signal.SIGTERM)[i % 2], float(rng.uniform(0.3, 1.05 * length)),
                 bool(rng.random() < 0.5), i % 5 == 4) for i in range(args.n)]
        rows, running, queue = [], [], list(enumerate(plan))
        while queue or running:
            while queue and len(running) < args.parallel:
                i, (signum, moment, existing, tiled) = queue.pop(0)
                folder = tmp / f"r{i:02d}"
                folder.mkdir()
                if existing:
                    for name in ("roofs.gpkg", "points.laz"):
                        (folder / name).write_bytes(GOOD)
                running.append([i, start(command(src, folder, tiled)), time.perf_counter(), None])
            time.sleep(0.02)
            for item in list(running):
                i, proc, started, sent = item
                signum, moment, existing, tiled = plan[i]
                if sent is None and time.perf_counter() - started >= moment:
                    if proc.poll() is None:
                        os.killpg(proc.pid, signum)
                    item[3] = sent = time.perf_counter()
                if proc.poll() is not None and sent is not None:
                    ended = time.perf_counter()
                    err = proc.stderr.read().decode()
                    found = problems(proc.returncode, err, signum, tmp / f"r{i:02d}", existing, buildings)
                    latency = ended - sent if proc.returncode != 0 else None
                    rows.append((i, signum, moment, existing, tiled, proc.returncode, latency, found))
                    print(f"{i:2d} {signal.Signals(signum).name:7s} at {moment:5.1f} s "
                          f"{'tiled' if tiled else 'one piece':9s} {'existing' if existing else 'new':8s} "
                          f"exit {proc.returncode:3d} latency {'-' if latency is None else f'{latency:.2f} s'} "
                          f"{'; '.join(found) or 'ok'}", flush=True)
                    running.remove(item)

    interrupted = [r for r in rows if r[5] != 0]
    failed = [r for r in rows if r[7]]
    latencies = np.array([r[6] for r in interrupted])
    print(f"\n{len(rows)} runs: {len(interrupted)} interrupted ({sum(r[1] == signal.SIGINT for r in interrupted)} "
          f"SIGINT, {sum(r[1] == signal.SIGTERM for r in interrupted)} SIGTERM; "
          f"{sum(r[4] for r in interrupted)} tiled on Dask), {len(rows) - len(interrupted)} finished first, "
          f"{len(failed)} failed; latency median {np.median(latencies):.2f} s, max {latencies.max():.2f} s")
    _results.record("bench_interrupt", "delft_ahn3_cropped_2", [
        {"method": "rooftrace run", "metric": "runs", "value": len(rows)},
        {"method": "rooftrace run", "metric": "interrupted", "value": len(interrupted)},
        {"method": "rooftrace run", "metric": "failed", "value": len(failed), "target": "== 0"},
        {"method": "rooftrace run", "metric": "latency_median_s", "value": float(np.median(latencies)), "unit": "s"},
        {"method": "rooftrace run", "metric": "latency_max_s", "value": float(latencies.max()), "unit": "s"},
        {"method": "rooftrace run", "metric": "reference_run_s", "value": length, "unit": "s"},
    ])
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
