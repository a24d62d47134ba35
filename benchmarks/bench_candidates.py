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

Variants: the grey image with the seed 003 rule; Canny only
(``selection='canny'``); the rule's Steger lines added to every Canny line
(``selection='both'``, the default); and the colour image (Canny on Di Zenzo's colour
gradient), which finds roof edges whose two sides differ in colour but not
in brightness.  Times are CPU times of one process.

Usage::

    .venv/bin/python benchmarks/bench_candidates.py --seeds 1 2 --shift 0.4
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

import _data
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
            t1 = time.process_time()  # CPU time: the machine is shared
            out = extract_candidates(rgb if use_rgb else grey, cam, moved, kinds, points_xyz=xyz[near],
                                     building_xyz=xyz[bid == b], options=opt)
            st = stats[name]
            st["ms"].append(1e3 * (time.process_time() - t1))
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


IGN = _data.DATA / "ign_montpellier_lidarhd_bdortho"


def ign_buildings(xyz: np.ndarray, n: int = 4, min_points: int = 300):
    """Rough 3D outlines of the largest class-6 clusters: concave hull, simplified, at eave height."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(xyz[:, :2]).query_pairs(0.8, output_type="ndarray")
    import scipy.sparse as sp

    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xyz), len(xyz)))
    _, label = connected_components(graph, directed=False)
    counts = np.bincount(label)
    out = []
    for lab in np.argsort(-counts)[:n]:
        if counts[lab] < min_points:
            break
        pts = xyz[label == lab]
        hull = shapely.concave_hull(shapely.MultiPoint(pts[:, :2]), ratio=0.1).simplify(1.0)
        if not isinstance(hull, Polygon):
            continue
        ring = shapely.get_coordinates(hull.exterior)
        eave = float(np.percentile(pts[:, 2], 10))
        segs = np.array([[[*ring[i], eave], [*ring[i + 1], eave]] for i in range(len(ring) - 1)])
        out.append((segs, pts))
    return out


def ign_figure(path: Path) -> dict:
    """Candidates for the largest buildings of the IGN tile on the IGN orthophoto, drawn to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import rasterio

    from rooftrace.io.camera import camera_from_dict
    from rooftrace.io.points import read_points

    tif, laz = IGN / "test_data_rgb.tif", IGN / "test_data_77055_627760_LA93_IGN69.laz"
    cam = camera_from_dict({"type": "orthophoto"}, "ign", image=tif)
    with rasterio.open(tif) as ds:
        rgb = np.moveaxis(ds.read()[:3], 0, -1).astype(float) / 255.0
    cloud = read_points(laz)
    cls = np.asarray(cloud.fields["classification"])
    xyz = cloud.xyz
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    ax.imshow(rgb, extent=(-0.5, rgb.shape[1] - 0.5, rgb.shape[0] - 0.5, -0.5))
    summary = {"buildings": 0, "lines": 0, "projected_only": 0, "ms": []}
    for segs, pts in ign_buildings(xyz[cls == 6]):
        t0 = time.process_time()
        out = extract_candidates(rgb, cam, segs, ["outline"] * len(segs), points_xyz=xyz, building_xyz=pts)
        summary["ms"].append(round(1e3 * (time.process_time() - t0), 1))
        summary["buildings"] += 1
        summary["lines"] += len(out)
        summary["projected_only"] += sum(c.projected_only for c in out)
        for c in out:
            w = np.vstack([c.window, c.window[:1]])
            ax.plot(w[:, 0], w[:, 1], "c-", lw=0.5, alpha=0.8)
            ax.plot(c.reference[:, 0], c.reference[:, 1], "y--", lw=1.0)
            for seg, src in zip(c.candidates, c.source):
                if src != "projected":
                    ax.plot(seg[:, 0], seg[:, 1], "-", color="red" if src != "steger" else "magenta", lw=1.4)
    ax.set_xlim(-0.5, rgb.shape[1] - 0.5)
    ax.set_ylim(rgb.shape[0] - 0.5, -0.5)
    ax.set_title("IGN ortho 0.2 m + LiDAR HD class 6: windows (cyan), LiDAR sides (yellow), candidates (red)",
                 fontsize=8)
    ax.set_axis_off()
    fig.tight_layout()
    import io

    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=80)
    plt.close(fig)
    buf.seek(0)
    # a 128-colour palette keeps the figure small enough for the repository
    Image.open(buf).convert("RGB").quantize(128).save(path, optimize=True)
    return summary


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--shift", type=float, default=0.4, help="planimetric offset of the input lines (m)")
    ap.add_argument("--density", type=float, default=12.0)
    ap.add_argument("--ign-figure", type=Path, help="draw the IGN real-data candidates to this PNG and stop")
    args = ap.parse_args(argv)
    if args.ign_figure:
        print(json.dumps(ign_figure(args.ign_figure)))
        return
    variants = {"grey_seed003": (CandidateOptions(selection="seed003"), False),
                "grey_canny": (CandidateOptions(selection="canny"), False),
                "grey_both": (CandidateOptions(selection="both"), False),
                "colour_seed003": (CandidateOptions(selection="seed003"), True),
                "colour_both": (CandidateOptions(selection="both"), True)}
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
