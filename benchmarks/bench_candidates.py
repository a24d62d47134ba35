"""Benchmark of the image line candidates (issue 7 part A) on simulated scenes.

For every building of a ``rooftrace.synth`` scene (frame image, 0.2 m GSD,
the true camera) the TRUE roof outline sides and ridges are shifted by a
random planimetric offset (a LiDAR outline error, ``--shift`` metres) and
handed to :func:`rooftrace.image.candidates.extract_candidates` with the
scene's LiDAR points (terrain-line filter).  Scores, per line kind:

* recall: the fraction of true sides / ridges (projected length >= 10 px)
  whose candidates include one within 1 px and 1 deg of the true projection
  (both candidate ends within 1 px of the true line, its middle over the
  true segment);
* baseline: the same test applied to the shifted projection itself;
* projected-only: lines left with their projection as the only candidate;
* candidates per line, and milliseconds per building and per line.

Variants: the grey image with the seed 003 rule (default); the grey image
with Canny only (Steger never selected), which shows what the selection
rule buys on ridges; and the colour image (Canny on Di Zenzo's colour
gradient), which finds roof edges whose two sides differ in colour but not
in brightness.

Usage::

    .venv/bin/python benchmarks/bench_candidates.py --seeds 1 2 --shift 0.4
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from rooftrace.image.candidates import CandidateOptions, extract_candidates
from rooftrace.synth import SceneOptions, simulate_scene

MIN_PX = 10.0


def _lines(outline, ridges, centre=None):
    """3D segments (M, 2, 3), kinds, and per outline side whether its wall faces the camera."""
    segs, kinds, wall = [], [], []
    outline = orient(outline, 1.0)  # exterior CCW, holes CW: the outside is on the right
    for ring in [outline.exterior, *outline.interiors]:
        xyz = shapely.get_coordinates(ring, include_z=True)
        for i in range(len(xyz) - 1):
            a, b = xyz[i], xyz[i + 1]
            out = np.array([b[1] - a[1], a[0] - b[0]])
            wall.append(bool(centre is not None and (centre[:2] - 0.5 * (a[:2] + b[:2])) @ out > 0))
        segs += [xyz[i:i + 2] for i in range(len(xyz) - 1)]
        kinds += ["outline"] * (len(xyz) - 1)
    for r in ridges:
        xyz = shapely.get_coordinates(r, include_z=True)
        segs += [xyz[i:i + 2] for i in range(len(xyz) - 1)]
        kinds += ["ridge"] * (len(xyz) - 1)
        wall += [False] * (len(xyz) - 1)
    return np.array(segs, float).reshape(-1, 2, 3), kinds, wall


def matches(candidates: np.ndarray, truth: np.ndarray, px: float = 1.0, deg: float = 1.0) -> bool:
    """Some candidate lies within ``px`` and ``deg`` of the true segment (2, 2)."""
    t0, t1 = truth
    d = t1 - t0
    length = np.hypot(*d)
    u = d / length
    n = np.array([-u[1], u[0]])
    for c in np.asarray(candidates, float).reshape(-1, 2, 2):
        e = c[1] - c[0]
        if np.hypot(*e) < 1e-9:
            continue
        ang = np.degrees(np.arccos(min(1.0, abs(e @ u) / np.hypot(*e))))
        off = np.abs((c - t0) @ n).max()
        mid = (c.mean(0) - t0) @ u
        if ang <= deg and off <= px and -px <= mid <= length + px:
            return True
    return False


def run_scene(seed: int, shift: float, variants: dict, density: float) -> dict:
    t0 = time.perf_counter()
    scene = simulate_scene(SceneOptions(seed=seed, density=density))
    t_sim = time.perf_counter() - t0
    grey = scene.image.astype(float).mean(axis=0) / 255.0
    rgb = np.moveaxis(scene.image, 0, -1).astype(float) / 255.0
    cam = scene.camera
    xyz = scene.cloud.xyz
    bid = np.asarray(scene.cloud.fields["truth_building_id"])
    outlines = scene.truth["roof_outlines"]
    ridges = scene.truth["ridges"]
    rng = np.random.default_rng(seed)
    stats = {name: {"outline": [], "ridge": [], "wall": [], "base": {"outline": [], "ridge": []}, "ms": [], "n_lines": [],
                    "projected_only": 0, "n_cand": 0, "n_total": 0} for name in variants}
    for geom, b in zip(outlines.geometries, outlines.attributes["building_id"]):
        mine = [g for g, rb in zip(ridges.geometries, ridges.attributes["building_id"]) if rb == b]
        lines, kinds, wall = _lines(geom if isinstance(geom, Polygon) else geom.geoms[0], mine, cam.center)
        truth_px = cam.project(lines.reshape(-1, 3)).reshape(-1, 2, 2)
        angle = rng.uniform(0, 2 * np.pi)
        moved = lines + np.array([shift * np.cos(angle), shift * np.sin(angle), 0.0])
        lo, hi = lines[..., :2].reshape(-1, 2).min(0) - 15, lines[..., :2].reshape(-1, 2).max(0) + 15
        near = np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1)
        for name, (opt, use_rgb) in variants.items():
            t1 = time.perf_counter()
            out = extract_candidates(rgb if use_rgb else grey, cam, moved, kinds, points_xyz=xyz[near],
                                     building_xyz=xyz[bid == b], options=opt)
            st = stats[name]
            st["ms"].append(1e3 * (time.perf_counter() - t1))
            st["n_lines"].append(len(out))
            for c, tr, k, w in zip(out, truth_px, kinds, wall):
                st["n_total"] += 1
                st["n_cand"] += len(c.candidates)
                st["projected_only"] += c.projected_only
                if np.hypot(*(tr[1] - tr[0])) < MIN_PX:
                    continue
                st[k].append(matches(c.candidates, tr))
                if k == "outline":
                    st["wall"].append(w)
                st["base"][k].append(matches(c.reference[None], tr))
    result = {"seed": seed, "simulate_s": round(t_sim, 1), "buildings": len(outlines)}
    for name, st in stats.items():
        ms = np.array(st["ms"])
        nl = np.array(st["n_lines"])
        hit, wall = np.array(st["outline"]), np.array(st["wall"])
        result[name] = {
            "recall_outline": float(np.mean(st["outline"])), "n_outline": len(st["outline"]),
            "recall_outline_wall_hidden": float(hit[~wall].mean()), "n_wall_hidden": int((~wall).sum()),
            "recall_outline_wall_visible": float(hit[wall].mean()) if wall.any() else None,
            "recall_ridge": float(np.mean(st["ridge"])) if st["ridge"] else None, "n_ridge": len(st["ridge"]),
            "baseline_outline": float(np.mean(st["base"]["outline"])),
            "baseline_ridge": float(np.mean(st["base"]["ridge"])) if st["base"]["ridge"] else None,
            "projected_only": st["projected_only"] / st["n_total"],
            "candidates_per_line": st["n_cand"] / st["n_total"],
            "ms_per_building": float(ms.mean()), "ms_per_line": float(ms.sum() / nl.sum()),
            "ms_8_12_lines": float(ms[(nl >= 8) & (nl <= 12)].mean()) if ((nl >= 8) & (nl <= 12)).any() else None,
            "ms_max": float(ms.max()),
        }
    return result


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--shift", type=float, default=0.4, help="planimetric offset of the input lines (m)")
    ap.add_argument("--density", type=float, default=12.0)
    args = ap.parse_args(argv)
    variants = {"grey": (CandidateOptions(), False), "grey_canny_only": (CandidateOptions(select_separation=0.0), False),
                "colour": (CandidateOptions(), True)}
    # warm the numba caches so timings measure the steady state
    extract_candidates(np.zeros((50, 50)), *_warm())
    for seed in args.seeds:
        print(json.dumps(run_scene(seed, args.shift, variants, args.density)))


def _warm():
    from rooftrace.image.camera import FrameCamera

    cam = FrameCamera((50, 50), 0.01, 100.0, np.array([0, 0, 1000.0, 0, 0, 0]))
    return cam, np.array([[[0, 0, 0], [1, 0, 0.0]]]), ["outline"]


if __name__ == "__main__":
    main()
