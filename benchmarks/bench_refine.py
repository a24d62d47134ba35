"""Benchmark of the image refinement (issue 7 part B) on simulated scenes.

For each scene (``rooftrace.synth``, 0.2 m GSD) and LiDAR density:

1. LiDAR-only roofs: the pipeline without the image (outlines, planes, ridges);
2. refinement with the TRUE camera -> object-space scores: mean PoLiS of the
   outlines to the truth (LiDAR-only vs refined) and ridge position error;
3. refinement with a camera perturbed by ~3 px (``write_scene``'s
   ``camera_perturbed.json``) -> image-space scores: PoLiS (px) between the
   refined outline in the image and the truth projected with the true
   camera, and line-grouping correctness / completeness per side;
4. GA vs exact minimum on every building, and seconds per building.

Usage::

    .venv/bin/python benchmarks/bench_refine.py --seeds 1 2 --densities 2 12
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from rooftrace.evaluate.matching import match_buildings
from rooftrace.evaluate.metrics import polis
from rooftrace.image.candidates import CandidateOptions
from rooftrace.io.camera import read_camera
from rooftrace.pipeline import run_pipeline
from rooftrace.refine import RefineOptions, refine_buildings
from rooftrace.synth import SceneOptions, simulate_scene, write_scene

PAPER = RefineOptions(terrain_filter=True, fuse=False, ridges_on_planes=False, derive_sigma=False, wall_penalty=0.0,
                      register=False, grow=False, orientation=False,
                      candidates=CandidateOptions(refit=False, wall_lines=False))
SIDE_TOL_PX = 1.5  # a selected line is right when its ends and middle lie this close to the true line


def _grey(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image, float)
    if img.ndim == 3:
        img = img.mean(axis=0)
    return img / 255.0


def _segments_px(camera, geoms) -> np.ndarray:
    """Projected segments (S, 2, 2) of the rings / lines of geoms."""
    segs = []
    for g in geoms:
        parts = [g.exterior, *g.interiors] if isinstance(g, Polygon) else [g]
        for part in parts:
            xyz = shapely.get_coordinates(part, include_z=True)
            px = camera.project(xyz)
            segs.append(np.stack([px[:-1], px[1:]], axis=1))
    return np.concatenate(segs) if segs else np.zeros((0, 2, 2))


def _dist_to_segments(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Distance of points (N, 2) to the nearest of segments (S, 2, 2), and that segment's index."""
    a, b = segs[:, 0][None], segs[:, 1][None]
    ab = b - a
    t = np.einsum("nsk,nsk->ns", p[:, None] - a, ab) / np.maximum(np.einsum("nsk,nsk->ns", ab, ab), 1e-12)
    t = np.clip(t, 0, 1)
    d = np.linalg.norm(a + t[..., None] * ab - p[:, None], axis=2)
    return d.min(axis=1), d.argmin(axis=1)


def _line_correct(line: np.ndarray, segs: np.ndarray) -> bool:
    """Both ends within SIDE_TOL_PX of the infinite true line nearest to the segment's middle."""
    if not len(segs):
        return False
    _, idx = _dist_to_segments(line.mean(axis=0, keepdims=True), segs)
    a, b = segs[idx[0]]
    u = (b - a) / max(np.linalg.norm(b - a), 1e-12)
    n = np.array([-u[1], u[0]])
    return bool(np.abs((line - a) @ n).max() <= SIDE_TOL_PX)


def _ridge_errors(extracted: list, truth: list) -> list[float]:
    """Plan distance of extracted ridge end points to their true ridge line (horizontal ridges matched by midpoint)."""
    out = []
    for t in truth:
        txy = np.asarray(t.coords)[:, :2]
        if np.ptp(np.asarray(t.coords)[:, 2]) > 0.3:  # hips, valleys: only horizontal ridges
            continue
        u = (txy[-1] - txy[0]) / np.linalg.norm(txy[-1] - txy[0])
        best = None
        for e in extracted:
            exy = np.asarray(e.coords)[:, :2]
            v = exy[-1] - exy[0]
            if np.linalg.norm(v) < 1e-6 or abs(u @ v) / np.linalg.norm(v) < np.cos(np.radians(15)):
                continue
            d = LineString(txy).distance(shapely.Point(exy.mean(axis=0)))
            if d < 1.5 and (best is None or d < best[0]):
                n = np.array([-u[1], u[0]])
                best = (d, float(np.mean(np.abs((exy[[0, -1]] - txy[0]) @ n))))
        if best is not None:
            out.append(best[1])
    return out


def emulated_roofs(scene, seed: int):
    """Truth topology with LiDAR-sized errors; planes and ridges from the LiDAR points.

    With s = 1/sqrt(density) the mean point spacing, each outline is shrunk
    by s/2 (boundary points lie inside the true edge, half a spacing on
    average) and every vertex gets N(0, (0.35 s)^2) in x and y; Z is the
    truth's plus N(0, 0.1^2).  Roof planes and ridges come from
    ``roof_structure`` on the building's own LiDAR points.
    """
    from rooftrace.roof import roof_structure

    rng = np.random.default_rng([seed, 7])
    s = 1.0 / np.sqrt(scene.options.density)
    xyz = scene.cloud.xyz
    bid = np.where(scene.cloud.fields["truth_class"] == 6, scene.cloud.fields["truth_building_id"], 0)
    polys, ids, planes, ridges, ridge_ids = [], [], [], [], []
    layer = scene.truth["roof_outlines"]
    for geom, b in zip(layer.geometries, layer.attributes["building_id"]):
        flat = shapely.force_2d(geom).buffer(-0.5 * s, join_style="mitre")
        if flat.geom_type != "Polygon" or flat.is_empty:
            continue
        tz = shapely.get_coordinates(geom, include_z=True)

        def ring(r, tz=tz):
            xy = np.asarray(r.coords)[:-1]
            z = tz[np.argmin(np.linalg.norm(tz[None, :, :2] - xy[:, None], axis=2), axis=1), 2]
            xy = xy + rng.normal(0, 0.35 * s, xy.shape)
            out = np.column_stack([xy, z + rng.normal(0, 0.1, len(z))])
            return np.vstack([out, out[:1]])

        poly = Polygon(ring(flat.exterior), [ring(h) for h in flat.interiors])
        if not poly.is_valid:
            continue
        polys.append(poly)
        ids.append(int(b))
        roof = roof_structure(xyz[bid == b], poly, building_id=int(b))
        planes.append(roof.planes if len(roof.planes) else None)
        ridges += list(roof.ridges)
        ridge_ids += [int(b)] * len(roof.ridges)
    return polys, ids, planes, ridges, ridge_ids


def lidar_roofs(scene, mode: str, seed: int):
    """LiDAR-only roofs: outlines, ids, planes per outline, ridges, ridge ids.

    ``'pipeline'``: the whole LiDAR method (detection included).
    ``'known'``: the outline and roof stages on each true building's own
    points (detection assumed right), i.e. seed 000's premise that the LiDAR
    roof is topologically right and only inaccurate.
    """
    if mode == "pipeline":
        lidar = run_pipeline(scene.cloud, seed=seed)
        outlines = [o for o in lidar.outlines if o.polygon is not None and not o.polygon.is_empty]
        structures = lidar.structures
    elif mode == "emulated":
        return emulated_roofs(scene, seed)
    else:
        from rooftrace.contour.outline import outline_buildings
        from rooftrace.roof import roof_structure

        xyz = scene.cloud.xyz
        bid = np.where(scene.cloud.fields["truth_class"] == 6, scene.cloud.fields["truth_building_id"], 0)
        outlines = [o for o in outline_buildings(xyz, bid) if o.polygon is not None and not o.polygon.is_empty]
        structures = []
        for o in outlines:
            pts = xyz[bid == o.building_id]
            try:
                structures.append(roof_structure(pts, o.polygon, building_id=o.building_id))
            except Exception:  # a failed roof only loses its planes
                pass
    polys = [o.polygon for o in outlines]
    ids = [o.building_id for o in outlines]
    planes_by = {s.building_id: s.planes for s in structures}
    ridges = [r for s in structures for r in s.ridges]
    ridge_ids = [s.building_id for s in structures for _ in s.ridges]
    return polys, ids, [planes_by.get(i) for i in ids], ridges, ridge_ids


def run_case(seed: int, density: float, perturb_px: float = 3.0, options: RefineOptions | None = None,
             mode: str = "emulated") -> dict:
    t0 = time.perf_counter()
    scene = simulate_scene(SceneOptions(seed=seed, density=density, gsd=0.2))
    grey = _grey(scene.image)
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_scene(tmp, scene, perturbed_camera_px=perturb_px)
        cam_perturbed = read_camera(paths["camera_perturbed"])
    polys, ids, planes, ridges, ridge_ids = lidar_roofs(scene, mode, seed)
    kw = dict(points_xyz=scene.cloud.xyz, planes=planes, building_ids=ids,
              ridge_building_ids=ridge_ids, options=options, seed=seed)
    t1 = time.perf_counter()
    true_run = refine_buildings(polys, ridges, grey, scene.camera, **kw)
    t_refine = time.perf_counter() - t1
    t2, c2 = time.perf_counter(), time.process_time()
    pert_run = refine_buildings(polys, ridges, grey, cam_perturbed, **kw)
    # both passes and the orientation correction when it runs; CPU time too (the machine is shared)
    t_pert, c_pert = time.perf_counter() - t2, time.process_time() - c2

    truth = scene.truth["roof_outlines"].geometries
    truth_ids = scene.truth["roof_outlines"].attributes["building_id"]
    truth_ridges = scene.truth["ridges"]
    match = match_buildings([shapely.force_2d(p) for p in polys], [shapely.force_2d(t) for t in truth],
                            merge_blocks=False)
    rows = []
    for e_idx, r_idx in match.units:
        if len(e_idx) != 1 or len(r_idx) != 1:
            continue
        e, r = e_idx[0], r_idx[0]
        tb = truth_ids[r]
        t_ridges = [g for g, b in zip(truth_ridges.geometries, truth_ridges.attributes["building_id"]) if b == tb]
        my_ridges = [i for i, b in enumerate(ridge_ids) if b == ids[e]]
        bt, bp = true_run.buildings[e], pert_run.buildings[e]
        row = {"building": ids[e], "sides": len(bt.refined_sides), "status": bt.status,
               "polis_lidar": polis(polys[e], truth[r]), "polis_refined": polis(true_run.outlines[e], truth[r]),
               "polis_refined_perturbed": polis(pert_run.outlines[e], truth[r]),
               "ridge_err_lidar": _ridge_errors([ridges[i] for i in my_ridges], t_ridges),
               "ridge_err_refined": _ridge_errors([true_run.ridges[i] for i in my_ridges], t_ridges),
               "gap": [bt.ga_exact_gap, bp.ga_exact_gap], "seconds": bt.seconds}
        if bp.status == "refined" and bp.image_outline is not None:
            sizes = np.cumsum((0,) + tuple(bp.ring_sizes))
            ring = Polygon(bp.image_outline[:sizes[1]], [bp.image_outline[a:b] for a, b in zip(sizes[1:-1], sizes[2:])])
            t = truth[r]
            true_px = Polygon(scene.camera.project(shapely.get_coordinates(t.exterior, include_z=True)),
                              [scene.camera.project(shapely.get_coordinates(h, include_z=True)) for h in t.interiors])
            row["polis_px"] = polis(ring, true_px) if ring.is_valid else None
            segs_out = _segments_px(scene.camera, [truth[r]])
            segs_ridge = _segments_px(scene.camera, t_ridges)
            correct = chosen = has_correct = total = 0
            for s, kind in enumerate(bp.kinds):
                segs = segs_out if kind == "outline" else segs_ridge
                total += 1
                # the projected line is no image candidate (short sides have only it)
                cand_ok = [_line_correct(c, segs) for c in bp.candidate_sets[s] if not np.allclose(c, bp.references[s])]
                has_correct += any(cand_ok)
                is_image = bool(not np.allclose(bp.selected[s], bp.references[s]))
                chosen += is_image
                correct += is_image and _line_correct(bp.selected[s], segs)
            row.update(lines=total, lines_image=chosen, lines_correct=correct, lines_with_correct=has_correct)
        rows.append(row)
    # the camera: mean displacement (px) of the true roof vertices, perturbed / corrected vs true
    tv = np.vstack([shapely.get_coordinates(g, include_z=True) for g in truth])
    base = scene.camera.project(tv)
    disp = {name: float(np.mean(np.hypot(*(cam.project(tv) - base).T)))
            for name, cam in (("perturbed", cam_perturbed), ("corrected", pert_run.camera),
                              ("true_corrected", true_run.camera))}
    eo_err = {name: (np.asarray(cam.exterior, float) - np.asarray(scene.camera.exterior, float)).tolist()
              for name, cam in (("perturbed", cam_perturbed), ("corrected", pert_run.camera))}
    corr = pert_run.orientation
    return {"seed": seed, "density": density, "mode": mode, "buildings": len(polys), "matched": len(rows),
            "camera_disp_px": disp, "eo_error": eo_err,
            "orientation": None if corr is None else {"parameters": list(corr.parameters), "lines": corr.n_lines,
                                                      "inliers": corr.n_inliers, "rms_px": corr.rms,
                                                      "std": corr.std().tolist()},
            "t_simulate_and_lidar": time.perf_counter() - t0 - t_refine, "t_refine": t_refine,
            "t_per_building": t_refine / max(len(polys), 1),
            "t_per_building_perturbed": t_pert / max(len(polys), 1),
            "cpu_per_building_perturbed": c_pert / max(len(polys), 1), "rows": rows}


def summarise(cases: list[dict]) -> dict:
    out = {}
    for density in sorted({c["density"] for c in cases}):
        rows = [r for c in cases if c["density"] == density for r in c["rows"]]
        ok = [r for r in rows if r["status"] == "refined"]
        img = [r for r in rows if "lines" in r]
        gaps = np.array([g for r in rows for g in r["gap"] if np.isfinite(g)])
        px = [r["polis_px"] for r in img if r.get("polis_px") is not None]
        sec = [(r["sides"], r["seconds"]) for r in rows if np.isfinite(r["seconds"])]
        s812 = [t for n, t in sec if 8 <= n <= 12]
        lines = sum(r["lines"] for r in img)
        before = np.array([r["polis_lidar"] for r in rows])
        after = np.array([r["polis_refined"] for r in rows])
        sane = before < 1.0  # a LiDAR outline off by metres is another building (merged blocks): no image can fix it
        out[density] = {
            "buildings": len(rows), "refined": len(ok),
            "polis_lidar": float(np.mean(before)),
            "polis_refined": float(np.mean(after)),
            "polis_refined_perturbed": float(np.mean([r["polis_refined_perturbed"] for r in rows])),
            "camera_disp_px": {k: float(np.mean([c["camera_disp_px"][k] for c in cases if c["density"] == density]))
                               for k in ("perturbed", "corrected", "true_corrected")},
            "polis_lidar_sane": float(np.mean(before[sane])), "polis_refined_sane": float(np.mean(after[sane])),
            "n_sane": int(sane.sum()), "improved": int((after < before).sum()), "worse": int((after > before).sum()),
            "ridge_err_lidar": float(np.mean([e for r in rows for e in r["ridge_err_lidar"]] or [np.nan])),
            "ridge_err_refined": float(np.mean([e for r in rows for e in r["ridge_err_refined"]] or [np.nan])),
            "polis_px_perturbed": float(np.mean(px)) if px else float("nan"),
            "correctness": sum(r["lines_correct"] for r in img) / max(sum(r["lines_image"] for r in img), 1),
            "completeness": sum(r["lines_correct"] for r in img) / max(sum(r["lines_with_correct"] for r in img), 1),
            "side_coverage": sum(r["lines_correct"] for r in img) / max(lines, 1),
            "ga_exact_rate": float(np.mean(gaps <= 1e-9)) if len(gaps) else float("nan"),
            "ga_exact_runs": int(len(gaps)),
            "sec_per_building": float(np.mean([t for _, t in sec])) if sec else float("nan"),
            "sec_8_12_sides_max": float(np.max(s812)) if s812 else float("nan"),
            "sec_8_12_sides_mean": float(np.mean(s812)) if s812 else float("nan"),
            "n_8_12": len(s812),
            "sec_per_building_perturbed_run": float(np.mean([c["t_per_building_perturbed"] for c in cases
                                                            if c["density"] == density])),
            "cpu_per_building_perturbed_run": float(np.mean([c.get("cpu_per_building_perturbed", np.nan)
                                                            for c in cases if c["density"] == density])),
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--densities", type=float, nargs="+", default=[2.0, 12.0])
    ap.add_argument("--mode", choices=["emulated", "known", "pipeline"], default="emulated",
                    help="LiDAR roofs: truth topology with LiDAR-sized errors (seed 000's premise), the outline "
                         "stage on true building points, or the whole pipeline")
    ap.add_argument("--terrain-filter", action="store_true", help="refine with seed 000's terrain-line filter")
    ap.add_argument("--paper", action="store_true",
                    help="seed 000 as written: terrain filter, image lines alone (no fusion, no common shift), "
                         "ridge points on one plane, fixed LiDAR precision 0.48 m, and none of the candidate "
                         "refit, visible-wall step or per-roof shift in the energy")
    ap.add_argument("--orientation", choices=["default", "on", "off"], default="default",
                    help="correct the exterior orientation from the matched lines (RefineOptions.orientation; "
                         "only the perturbed camera has a covariance, so only its run is corrected)")
    ap.add_argument("--orientation-rounds", type=int, default=None, help="RefineOptions.orientation_rounds")
    ap.add_argument("--perturb-px", type=float, default=3.0, help="mean error of the perturbed camera (px)")
    ap.add_argument("--json", type=Path, default=None, help="write all rows here")
    ap.add_argument("--summarise", type=Path, default=None, help="only summarise the cases of an earlier --json")
    args = ap.parse_args(argv)
    if args.summarise:
        print(json.dumps(summarise(json.loads(args.summarise.read_text())["cases"]), indent=2))
        return 0
    cases = []
    for density in args.densities:
        for seed in args.seeds:
            opts = PAPER if args.paper else RefineOptions(terrain_filter=args.terrain_filter)
            if args.orientation != "default":
                opts = dataclasses.replace(opts, orientation=args.orientation == "on")
            if args.orientation_rounds:
                opts = dataclasses.replace(opts, orientation_rounds=args.orientation_rounds)
            case = run_case(seed, density, perturb_px=args.perturb_px, mode=args.mode, options=opts)
            cases.append(case)
            print(f"seed {seed} density {density}: {case['buildings']} buildings, refine {case['t_refine']:.1f} s",
                  file=sys.stderr)
    summary = summarise(cases)
    print(json.dumps(summary, indent=2))
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "cases": cases}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
