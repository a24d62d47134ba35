"""Outline coverage: does every outline hold its building's points?  Alpha strategies and boundaries compared.

    .venv/bin/python benchmarks/bench_coverage.py [delft delft3 ign city3d blocks blocks-large poisson]
    .venv/bin/python benchmarks/bench_coverage.py cpu      # Delft outline stage CPU time, triangle vs edge

Per dataset and variant: buildings, how many outlines cover < 99 % of their
building's points (within the outline's alpha), the smallest coverage, how
many needed a fallback (the configured strategy's alpha shape lost points) or
kept the alpha-shape rings (the regularisation lost points), the area
F-score against the reference (Delft: BGT pand inside the BGT area; City3D:
footprints, with mean PoLiS; block scenes: the truth roof outlines) and the
outline time.  Buildings are class-6 components (tests/contour/realdata.py);
the block scenes' are the class-6 truth points in components (the blocks
joined by their garages, as a detection sees them).  Figures are recorded
with benchmarks/_results.py (bench "coverage").
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from tests.contour import realdata  # noqa: E402

from _results import record  # noqa: E402
from rooftrace.contour.coverage import MIN_COVERAGE, outline_coverage  # noqa: E402
from rooftrace.contour.outline import OutlineOptions, connected_buildings, outline_buildings  # noqa: E402
from rooftrace.contour.spacing import building_mean_spacing as mean_spacing  # noqa: E402
from rooftrace.evaluate.metrics import area_scores, polis  # noqa: E402

VARIANTS = {
    "point, triangle, alpha x1.5 (default)": {},
    "point, triangle, alpha x1.25": {"scale": 1.25},
    "point, edge, alpha x1.25 (former default)": {"boundary": "edge", "scale": 1.25},
    "building, triangle": {"strategy": "building"},
    "global, triangle": {"strategy": "global"},
    "point, triangle, alpha x1": {"scale": 1.0},
    "point, edge, alpha x1 (thesis)": {"boundary": "edge", "scale": 1.0},
}


def _datasets(names):
    for name in names:
        if name in ("delft", "delft3"):
            cloud = realdata.delft_cloud()
            if name == "delft3":
                cloud = realdata.thinned(cloud, 3.0, seed=0)
            xyz, ids, spacing = realdata.class6_buildings(cloud)
            yield name, xyz, ids, spacing, ("bgt", None)
        elif name == "ign":
            parts = [realdata.class6_buildings(t) for t in realdata.ign_tiles()]
            offset = np.cumsum([0] + [p[1].max() for p in parts])
            xyz = np.concatenate([p[0] for p in parts])
            ids = np.concatenate([np.where(p[1] > 0, p[1] + o, 0) for p, o in zip(parts, offset)])
            yield name, xyz, ids, float(np.median([p[2] for p in parts])), (None, None)
        elif name == "city3d":
            xyz, ids, spacing, truths = realdata.city3d_buildings()
            yield name, xyz, ids, spacing, ("footprints", truths)
        elif name in ("blocks", "blocks-large"):
            from rooftrace.synth import SceneOptions, simulate_scene

            size, density = (150.0, 3.0) if name == "blocks" else (400.0, 3.0)
            scene = simulate_scene(SceneOptions(scene="blocks", size=size, density=density, seed=1, image=False))
            sel = scene.cloud.fields["truth_class"] == 6
            xyz = scene.cloud.xyz[sel]
            spacing = mean_spacing(xyz[:, :2])
            truth = shapely.union_all([shapely.force_2d(g) for g in scene.truth["roof_outlines"].geometries])
            yield name, xyz, connected_buildings(xyz[:, :2], 2 * spacing, min_points=10), spacing, ("union", truth)
        elif name == "poisson":
            from tests.contour.shapes import courtyard_blocks, sample_random

            blocks = courtyard_blocks(1, 80.0)
            clouds = [sample_random(shapely.affinity.translate(blocks, 100.0 * k), 3.0, seed=k) for k in range(20)]
            ids = np.repeat(np.arange(1, 21), [len(c) for c in clouds])
            truth = [shapely.affinity.translate(blocks, 100.0 * k) for k in range(20)]
            yield name, np.concatenate(clouds), ids, None, ("footprints", truth)


def _reference_scores(kind, truth, outlines):
    polys = [o.polygon for o in outlines]
    if kind == "bgt":
        from rooftrace.io.vector import read_layer

        aoi = shapely.union_all([g for p in sorted(realdata.DELFT.glob("bgt_*.sqlite")) for g in read_layer(p).geometries])
        ref = shapely.union_all(read_layer(realdata.DELFT / "bgt_pand.sqlite").geometries)
        ext = shapely.intersection(shapely.union_all([shapely.force_2d(p) for p in polys if p is not None]), aoi)
        return area_scores(ext, shapely.intersection(ref, aoi))["f_score"], None
    if kind == "union":
        ext = shapely.union_all([shapely.force_2d(p) for p in polys if p is not None])
        return area_scores(ext, truth)["f_score"], None
    if kind == "footprints":
        f = [area_scores(p, t)["f_score"] if p is not None else 0.0 for p, t in zip(polys, truth)]
        d = [polis(p, t) for p, t in zip(polys, truth) if p is not None]
        return float(np.mean(f)), float(np.mean(d))
    return None, None


def main(names):
    print(f"{'dataset':13s} {'variant':42s} {'bldg':>5s} {'<99%':>5s} {'min cov':>8s} {'fallbk':>6s} {'unreg':>6s} "
          f"{'F':>7s} {'PoLiS':>6s} {'time s':>7s}")
    for name, xyz, ids, spacing, (kind, truth) in _datasets(names):
        rows = []
        for variant, kw in VARIANTS.items():
            t0 = time.perf_counter()
            outs = outline_buildings(xyz, ids, OutlineOptions.from_config({}, **kw), mean_spacing=spacing)
            dt = time.perf_counter() - t0
            cov = np.array([outline_coverage(o.polygon, xyz[ids == o.building_id], o.alpha) for o in outs])
            status = Counter(o.status for o in outs)
            f, d = _reference_scores(kind, truth, outs)
            low = int((cov < MIN_COVERAGE).sum())
            print(f"{name:13s} {variant:42s} {len(outs):5d} {low:5d} {cov.min():8.4f} {status['alpha_fallback']:6d} "
                  f"{status['unregularised']:6d} {f if f is not None else float('nan'):7.4f} "
                  f"{d if d is not None else float('nan'):6.3f} {dt:7.1f}", flush=True)
            rows += [{"method": variant, "metric": "buildings_below_99", "value": low, "target": "0"},
                     {"method": variant, "metric": "coverage_min", "value": float(cov.min()), "target": ">= 0.99"},
                     {"method": variant, "metric": "alpha_fallback", "value": status["alpha_fallback"]},
                     {"method": variant, "metric": "time_s", "value": dt, "unit": "s"}]
            if f is not None:
                rows.append({"method": variant, "metric": "f_score", "value": f,
                             "target": ">= 0.93" if kind == "bgt" else None})
            if d is not None:
                rows.append({"method": variant, "metric": "polis_mean", "value": d, "unit": "m"})
        record("coverage", name, rows)


def cpu(repeats: int = 3) -> None:
    """CPU seconds (process time, load-independent) of ``outline_buildings`` on Delft, the boundaries alternating."""
    xyz, ids, spacing = realdata.class6_buildings(realdata.delft_cloud())
    outline_buildings(xyz[ids == 1], ids[ids == 1], mean_spacing=spacing)  # numba compilation
    times: dict[str, list[float]] = {"point, triangle, alpha x1.5 (default)": [],
                                     "point, edge, alpha x1.25 (former default)": []}
    for _ in range(repeats):
        for variant in times:
            t0 = time.process_time()
            outline_buildings(xyz, ids, OutlineOptions.from_config({}, **VARIANTS[variant]), mean_spacing=spacing)
            times[variant].append(time.process_time() - t0)
    rows = []
    for variant, t in times.items():
        print(f"{variant:42s} CPU s {' '.join(f'{x:.2f}' for x in t)}  median {np.median(t):.2f}")
        rows.append({"method": variant, "metric": "outline_cpu_s_median", "value": float(np.median(t)), "unit": "s"})
    record("coverage", "delft-outline-cpu", rows)


if __name__ == "__main__":
    if sys.argv[1:] == ["cpu"]:
        cpu()
    else:
        main(sys.argv[1:] or ["delft", "delft3", "ign", "city3d", "blocks", "poisson"])
