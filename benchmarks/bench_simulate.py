"""Benchmark of the scene simulator (issue 5): speed of the default scene and the truth checks.

For each seed: simulate the default scene (160 m, 12 pts/m², 0.2 m frame
image, trees, outliers) and time it, then measure what the issue asks:

- pulse density (first returns per m² of scene) and point density over
  roofs (building points per m² of truth roof outline, without and with
  wall hits) against the requested density (±20 %);
- the largest plan distance of a building-labelled point to its own truth
  roof outline (must be noise-sized);
- the edge check: mean Sobel gradient on the projected truth roof
  outlines over that of random pixels (≥ 3), for the frame image and,
  with ``--ortho``, the orthophoto;
- the time of ``write_scene`` and the file sizes.

Usage::

    .venv/bin/python benchmarks/bench_simulate.py                 # seeds 1 2 3, default scene
    .venv/bin/python benchmarks/bench_simulate.py --seeds 1 --density 4 --ortho
    .venv/bin/python benchmarks/bench_simulate.py --preview docs/images/scene_preview.png
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from rooftrace.synth import SceneOptions, simulate_scene, write_scene
from rooftrace.synth.checks import edge_gradient_ratio, outline_distances, roof_density


def run(seed: int, density: float, size: float, gsd: float, ortho: bool) -> dict:
    opts = SceneOptions(seed=seed, density=density, size=size, gsd=gsd, orthophoto=ortho)
    t0, c0 = time.perf_counter(), time.process_time()
    scene = simulate_scene(opts)
    t_sim, c_sim = time.perf_counter() - t0, time.process_time() - c0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        paths = write_scene(tmp, scene)
        t_write = time.perf_counter() - t0
        sizes = {k: os.path.getsize(p) for k, p in paths.items()}
    f = scene.cloud.fields
    return {
        "seed": seed, "mode": "orthophoto" if ortho else "frame", "density": density,
        "seconds": round(t_sim, 2), "cpu_seconds": round(c_sim, 2), "stages": {k: round(v, 2) for k, v in scene.info["seconds"].items()},
        "write_seconds": round(t_write, 2), "points": len(scene.cloud), "buildings": len(scene.buildings),
        "pulse_density": round(np.count_nonzero(f["return_number"] == 1) / size**2, 2),
        "roof_density": round(roof_density(scene), 2), "roof_density_walls": round(roof_density(scene, walls=True), 2),
        "max_outline_distance": round(float(outline_distances(scene).max()), 3),
        "edge_ratio": round(edge_gradient_ratio(scene.image, scene.camera, scene.truth["roof_outlines"].geometries), 2),
        "ridge_edge_ratio": round(edge_gradient_ratio(scene.image, scene.camera, scene.truth["ridges"].geometries), 2),
        "image_size": list(scene.image.shape[:0:-1]), "strips": scene.info["strips"],
        "mb": round(sum(sizes.values()) / 1e6, 1),
    }, scene


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--density", type=float, default=12.0)
    ap.add_argument("--size", type=float, default=160.0)
    ap.add_argument("--gsd", type=float, default=0.2)
    ap.add_argument("--ortho", action="store_true", help="also the orthophoto mode")
    ap.add_argument("--preview", type=Path, help="write the preview PNG of the first seed here")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    simulate_scene(SceneOptions(size=30.0, density=2.0, gsd=0.5))  # load the numba cache outside the timings
    rows = []
    for seed in args.seeds:
        for ortho in ([False, True] if args.ortho else [False]):
            row, scene = run(seed, args.density, args.size, args.gsd, ortho)
            rows.append(row)
            if args.preview is not None and len(rows) == 1:
                from rooftrace.synth.preview import save_preview

                save_preview(scene, args.preview)
    if args.json:
        print(json.dumps(rows, indent=2))
        return rows
    print(f"load average at start: {load:.1f} on {os.cpu_count()} cores")
    print("| seed | image | wall (s): total / ALS / image | CPU (s) | points | pulses/m² | roof pts/m² (with walls) "
          "| max dist. to outline (m) | edge ratio (outlines / ridges) | write (s) | files (MB) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        st = r["stages"]
        print(f"| {r['seed']} | {r['mode']} {r['image_size'][0]}×{r['image_size'][1]} | {r['seconds']:.1f} / "
              f"{st['als']:.1f} / {st['image']:.1f} | {r['cpu_seconds']:.1f} | {r['points']:,} | {r['pulse_density']:.2f} | "
              f"{r['roof_density']:.2f} ({r['roof_density_walls']:.2f}) | {r['max_outline_distance']:.3f} | "
              f"{r['edge_ratio']:.2f} / {r['ridge_edge_ratio']:.2f} | {r['write_seconds']:.1f} | {r['mb']:.1f} |")
    return rows


if __name__ == "__main__":
    main()
