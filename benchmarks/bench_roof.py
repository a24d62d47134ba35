"""Benchmark of the roof stage (planes, ridges) on constructed roofs with exact truth.

Scenes: gable, hip, L-shaped hip and flat roof with a lower annex (the
issue-6 targets), gable and hip with a chimney, each in ``--repeats`` random
orientations and positions, sampled at ``--density`` pts/m² on a jittered
grid with ``--noise`` m of height noise.  Ridges are scored with
``rooftrace.evaluate.metrics.ridge_scores`` (the ridge metrics of
``rooftrace evaluate``): completeness and correctness of length within a
0.5 m buffer, mean planimetric position error of the matched part.  Plane
slopes are compared with the truth face that holds most of each plane's
points.

Usage::

    .venv/bin/python benchmarks/bench_roof.py --density 12 --noise 0.04 --repeats 10
    .venv/bin/python benchmarks/bench_roof.py --no-outline   # outline from the points
    .venv/bin/python benchmarks/bench_roof.py --synth 1 2 3 4 5   # rooftrace.synth scenes (ray-cast ALS)
    .venv/bin/python benchmarks/bench_roof.py --pipeline 1 2 3   # end to end through rooftrace.pipeline
    .venv/bin/python benchmarks/bench_roof.py --real         # Delft AHN3 + IGN LiDAR HD
    .venv/bin/python benchmarks/bench_roof.py --figure docs/images/roof_delft.png --building 7
    .venv/bin/python benchmarks/bench_roof.py --figure docs/images/roof_ign.png --dataset ign --building 6

On the real clouds (no roof truth) the check is that pitched roofs get their
lines: a building counts as pitched when it has at least two planes steeper
than 15° of at least 10 m² each, and as found when at least one ridge, hip or
valley line was extracted.  Delft buildings are the class-6 AHN3 points inside
each BGT footprint grown by 0.5 m (roof overhangs), with that polygon as the
outline; IGN buildings are plan-connected components (1 m) of class-6 points,
outlined from the points.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import shapely

import _data
from rooftrace.evaluate.metrics import ridge_scores
from rooftrace.roof import RoofOptions, models, roof_structure

TARGETS = {"completeness": 0.95, "correctness": 0.95, "position_error": 0.15, "slope_error": 1.5}


def _kind_agreement(roof, model) -> tuple[int, int]:
    """Extracted lines whose kind equals that of the nearest truth line."""
    ok = n = 0
    for g, k in zip(roof.ridges, roof.ridge_kind):
        g2 = shapely.force_2d(g)
        d = [shapely.hausdorff_distance(g2, shapely.force_2d(t)) for t in model.ridges]
        if d and min(d) < 1.0:
            n += 1
            ok += model.ridge_kind[int(np.argmin(d))] == k
    return ok, n


def run_scene(name: str, seed: int, density: float, noise: float, use_outline: bool, options: RoofOptions):
    rng = np.random.default_rng(seed)
    model = models.BENCHMARK_MODELS[name](angle=float(rng.uniform(0, 180)), offset=tuple(rng.uniform(-500, 500, 2) + [85000, 447000]))
    xyz, face = models.sample_roof(model, density=density, noise=noise, seed=seed)
    t = time.perf_counter()
    roof = roof_structure(xyz, model.outline if use_outline else None, options)
    dt = time.perf_counter() - t
    sc = ridge_scores(roof.ridges, model.ridges, 0.5)
    slope_err = []
    for k in range(len(roof.planes)):
        f = face[(roof.labels == k) & (face >= 0)]
        if len(f):
            slope_err.append(abs(roof.slope_deg[k] - model.slopes_deg[np.bincount(f).argmax()]))
    ok, n = _kind_agreement(roof, model)
    return {
        "scene": name, "seed": seed, "n_points": len(xyz), "time_s": dt, "status": roof.status,
        # the truth lists chimneys apart from its planes: the second pass's planes (superstructures) are counted apart
        "n_planes": int((~roof.plane_detail).sum()), "n_true_planes": len(model.planes),
        "n_detail": int(roof.plane_detail.sum()), "n_chimneys": len(model._chimneys),
        "ref_len": sum(g.length for g in model.ridges), "ext_len": sum(shapely.force_2d(g).length for g in roof.ridges),
        "completeness": sc["ridge_completeness"], "correctness": sc["ridge_correctness"],
        "position_error": sc["ridge_position_error"], "slope_error_max": max(slope_err) if slope_err else np.nan,
        "slope_error_mean": float(np.mean(slope_err)) if slope_err else np.nan, "kind_ok": ok, "kind_n": n,
    }


def summarise(rows: list[dict]) -> dict:
    """Length-weighted completeness/correctness, mean position error, slope errors."""
    ref = np.array([r["ref_len"] for r in rows])
    ext = np.array([r["ext_len"] for r in rows])
    comp = np.array([r["completeness"] for r in rows])
    corr = np.array([r["correctness"] for r in rows])
    has_ref, has_ext = ref > 0, ext > 0
    pos = np.array([r["position_error"] for r in rows])
    se_max = np.array([r["slope_error_max"] for r in rows], dtype=float)
    se_mean = np.array([r["slope_error_mean"] for r in rows], dtype=float)
    fin = np.isfinite(pos)
    return {
        "scenes": len(rows),
        # NaN when there is nothing to score (no true / no extracted lines).
        "completeness": float(np.sum(np.nan_to_num(comp[has_ref]) * ref[has_ref]) / ref[has_ref].sum()) if has_ref.any() else np.nan,
        "correctness": float(np.sum(np.nan_to_num(corr[has_ext]) * ext[has_ext]) / ext[has_ext].sum()) if has_ext.any() else np.nan,
        "position_error": float(np.sum(pos[fin] * ext[fin]) / ext[fin].sum()) if fin.any() and ext[fin].sum() > 0 else np.nan,
        "slope_error_max": float(np.nanmax(se_max)) if np.isfinite(se_max).any() else np.nan,
        "slope_error_mean": float(np.nanmean(se_mean)) if np.isfinite(se_mean).any() else np.nan,
        "planes_ok": int(sum(r["n_planes"] == r["n_true_planes"] for r in rows)),
        "detail_planes": int(sum(r.get("n_detail", 0) for r in rows)),
        "chimneys": int(sum(r.get("n_chimneys", 0) for r in rows)),
        "kind_agreement": sum(r["kind_ok"] for r in rows) / max(sum(r["kind_n"] for r in rows), 1),
        "time_s_mean": float(np.mean([r["time_s"] for r in rows])),
    }


DATA = _data.DATA
DELFT = DATA / "3dfier_delft_ahn3_bgt"
IGN = DATA / "ign_montpellier_lidarhd_bdortho"


def delft_buildings():
    """(id, xyz, outline) of the Delft buildings with a BGT footprint."""
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import read_layer

    pc = read_points(sorted(DELFT.glob("ahn3_cropped_*.laz")), crs="EPSG:28992")
    b = pc.xyz[pc.fields["classification"] == 6]
    for i, g in enumerate(read_layer(DELFT / "bgt_pand.geojson").geometries):
        o = shapely.force_2d(g).buffer(0.5, join_style="mitre")
        yield i, b[shapely.contains_xy(o, b[:, 0], b[:, 1])], o


def ign_buildings(min_points: int = 200):
    """(id, xyz, None) of plan-connected class-6 clusters of the IGN tiles."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from rooftrace.io.points import read_points

    pc = read_points(sorted(IGN.glob("*.laz")))
    b = pc.xyz[pc.fields["classification"] == 6]
    ij = cKDTree(b[:, :2]).query_pairs(1.0, output_type="ndarray")
    _, comp = connected_components(coo_matrix((np.ones(len(ij)), (ij[:, 0], ij[:, 1])), shape=(len(b),) * 2), directed=False)
    sizes = np.bincount(comp)
    for i, c in enumerate(np.flatnonzero(sizes >= min_points)):
        yield i, b[comp == c], None


def run_real(options: RoofOptions) -> dict:
    out = {}
    for name, source, path in (("Delft AHN3 (BGT footprints)", delft_buildings, DELFT), ("IGN LiDAR HD Montpellier", ign_buildings, IGN)):
        if not path.exists():
            print(f"{name}: data not found at {path}")
            continue
        n = pitched = found = planes = 0
        kinds, rmse, times = {}, [], []
        for bid, xyz, outline in source():
            t = time.perf_counter()
            roof = roof_structure(xyz, outline, options, building_id=bid)
            times.append(time.perf_counter() - t)
            n += 1
            planes += len(roof.planes)
            rmse.extend(roof.plane_sigma.tolist())
            for k in roof.ridge_kind:
                kinds[k] = kinds.get(k, 0) + 1
            area = roof.plane_n * roof.spacing**2
            if np.sum((roof.slope_deg > 15) & (area >= 10)) >= 2:
                pitched += 1
                found += any(k != "step" for k in roof.ridge_kind)
        out[name] = {"buildings": n, "pitched": pitched, "pitched_with_lines": found, "planes": planes,
                     "median_rmse": float(np.median(rmse)) if rmse else np.nan, "lines": kinds,
                     "time_s_total": float(np.sum(times)), "time_s_max": float(np.max(times)) if times else np.nan}
        r = out[name]
        print(f"| {name} | {n} | {pitched} | {found} ({100 * found / max(pitched, 1):.0f} %) | {planes} | "
              f"{r['median_rmse']:.3f} | {', '.join(f'{k} {v}' for k, v in sorted(kinds.items()))} | "
              f"{r['time_s_total']:.1f} / {r['time_s_max']:.2f} |")
    return out


def render(path: str, building: int, options: RoofOptions, dataset: str = "delft") -> None:
    """Plan view (faces coloured by plane, lines by kind) and 3D view of one real building."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    source = delft_buildings if dataset == "delft" else ign_buildings
    bid, xyz, outline = next(b for b in source() if b[0] == building)
    roof = roof_structure(xyz, outline, options, building_id=bid)
    outline = roof.outline
    o = np.asarray(outline.bounds[:2])
    cmap = plt.get_cmap("Set3")
    colours = {"ridge": "red", "hip": "darkorange", "valley": "blue", "step": "black"}
    fig = plt.figure(figsize=(10, 4.4), dpi=90)
    ax = fig.add_subplot(1, 2, 1)
    for f, k in zip(roof.faces, roof.face_plane):
        c = np.asarray(f.exterior.coords)[:, :2] - o
        ax.fill(c[:, 0], c[:, 1], color=cmap(k % 12), alpha=0.45, lw=0.5, ec="grey")
    lab = roof.labels
    ax.scatter(xyz[:, 0] - o[0], xyz[:, 1] - o[1], s=2, c=[cmap(k % 12) if k >= 0 else (0.5, 0.5, 0.5) for k in lab])
    for g, kind in zip(roof.ridges, roof.ridge_kind):
        c = np.asarray(g.coords)[:, :2] - o
        ax.plot(c[:, 0], c[:, 1], color=colours[kind], lw=2.2, label=kind)
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles))
    ax.legend(uniq.values(), uniq.keys(), loc="upper right", fontsize=8)
    ax.set_aspect("equal")
    name = f"Delft BGT building {bid}" if dataset == "delft" else f"IGN LiDAR HD cluster {bid}"
    ax.set_title(f"{name}: {len(roof.planes)} planes, {len(roof.ridges)} lines", fontsize=9)
    ax.set_xlabel("m")
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    polys = [np.asarray(f.exterior.coords) - [*o, 0] for f in roof.faces]
    ax3.add_collection3d(Poly3DCollection(polys, facecolors=[cmap(k % 12) for k in roof.face_plane], alpha=0.6, edgecolor="grey", lw=0.3))
    for g, kind in zip(roof.ridges, roof.ridge_kind):
        c = np.asarray(g.coords) - [*o, 0]
        ax3.plot(c[:, 0], c[:, 1], c[:, 2], color=colours[kind], lw=2)
    allc = np.concatenate(polys)
    ax3.set_xlim(allc[:, 0].min(), allc[:, 0].max())
    ax3.set_ylim(allc[:, 1].min(), allc[:, 1].max())
    ax3.set_zlim(allc[:, 2].min() - 1, allc[:, 2].max() + 1)
    ax3.set_box_aspect(np.ptp(allc, axis=0) + [0, 0, 2])
    ax3.view_init(elev=40, azim=-115)
    ax3.set_title("roof faces and lines (3D)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    print(f"wrote {path}")


def run_synth(seeds: list[int], density: float, use_outline: bool, options: RoofOptions) -> dict:
    """Simulated scenes (``rooftrace.synth``): every building's class-6 truth
    points, its true roof outline (or none), scored against the truth ridges."""
    from rooftrace.synth.scene import SceneOptions
    from rooftrace.synth.simulate import simulate_scene

    rows = []
    for seed in seeds:
        sc = simulate_scene(SceneOptions(seed=seed, density=density, image=False))
        cl, truth = sc.cloud, sc.truth
        tb, tc = cl.fields["truth_building_id"], cl.fields["truth_class"]
        R, O, F = truth["ridges"], truth["roof_outlines"], truth["roof_faces"]  # noqa: E741
        rb, fb = np.asarray(R.attributes["building_id"]), np.asarray(F.attributes["building_id"])
        for g, bid, kind in zip(O.geometries, O.attributes["building_id"], O.attributes["kind"]):
            xyz = cl.xyz[(tb == bid) & (tc == 6)]
            t = time.perf_counter()
            roof = roof_structure(xyz, g if use_outline else None, options, building_id=int(bid))
            dt = time.perf_counter() - t
            ref = [R.geometries[i] for i in np.flatnonzero(rb == bid)]
            sc_ = ridge_scores(roof.ridges, ref, 0.5) if (ref or roof.ridges) else {}
            fi = np.flatnonzero(fb == bid)
            faces = [(F.geometries[i], F.attributes["slope_deg"][i]) for i in fi]
            # Truth faces split coplanar roof parts: count distinct planes.
            keys = set()
            for i in fi:  # truth planes are z = a x + b y + c
                a, b, c = (float(F.attributes[f"plane_{k}"][i]) for k in "abc")
                keys.add((round(a, 3), round(b, 3), round(c / 0.05)))
            err = []
            for k, c in enumerate(roof.plane_centre):
                hit = [sl for f, sl in faces if shapely.contains_xy(shapely.force_2d(f), c[0], c[1])]
                if hit:
                    err.append(abs(roof.slope_deg[k] - hit[0]))
            rows.append({
                "scene": kind, "seed": seed, "n_points": len(xyz), "time_s": dt, "status": roof.status,
                "n_planes": int((~roof.plane_detail).sum()), "n_true_planes": len(keys),
                "n_detail": int(roof.plane_detail.sum()), "n_chimneys": 0,
                "ref_len": sum(shapely.force_2d(r).length for r in ref),
                "ext_len": sum(shapely.force_2d(r).length for r in roof.ridges),
                "completeness": sc_.get("ridge_completeness", np.nan), "correctness": sc_.get("ridge_correctness", np.nan),
                "position_error": sc_.get("ridge_position_error", np.nan),
                "slope_error_max": max(err) if err else np.nan, "slope_error_mean": float(np.mean(err)) if err else np.nan,
                "kind_ok": 0, "kind_n": 0,
            })
    return rows


def run_pipeline_scenes(seeds: list[int], density: float) -> None:
    """End to end: simulated cloud -> ``rooftrace.pipeline.run_pipeline``
    (detection, outlines, roof planes) -> ridges scored against the truth."""
    from rooftrace.pipeline import run_pipeline
    from rooftrace.synth.scene import SceneOptions
    from rooftrace.synth.simulate import simulate_scene

    print("| seed | buildings found / true | completeness | correctness | position error (m) | lines | roof stage (s) |")
    print("|" + "---|" * 7)
    acc = []
    for seed in seeds:
        sc = simulate_scene(SceneOptions(seed=seed, density=density, image=False))
        res = run_pipeline(sc.cloud, seed=seed)
        ext = [g for st in res.structures for g in st.ridges]
        ref = list(sc.truth["ridges"].geometries)
        r = ridge_scores(ext, ref, 0.5)
        kinds = {}
        for st in res.structures:
            for k in st.ridge_kind:
                kinds[k] = kinds.get(k, 0) + 1
        print(f"| {seed} | {len(res.structures)} / {len(sc.truth['roof_outlines'])} | {_pct(r['ridge_completeness'])} | "
              f"{_pct(r['ridge_correctness'])} | {_num(r['ridge_position_error'])} | "
              f"{', '.join(f'{k} {v}' for k, v in sorted(kinds.items()))} | {res.timings.get('roof_planes', np.nan):.1f} |")
        le = sum(shapely.force_2d(g).length for g in ext)
        lr = sum(shapely.force_2d(g).length for g in ref)
        acc.append((r["ridge_completeness"] * lr, lr, r["ridge_correctness"] * le, le, r["ridge_position_error"] * le))
    # Scenes share their origin: weight per scene, never pool their lines.
    a = np.nansum(np.array(acc, dtype=float), axis=0)
    print(f"| **all** | | {_pct(a[0] / a[1])} | {_pct(a[2] / a[3])} | {_num(a[4] / a[3])} | | |")


def _pct(v: float) -> str:
    return "–" if not np.isfinite(v) else f"{100 * v:.1f} %"


def _num(v: float, fmt: str = ".3f") -> str:
    return "–" if not np.isfinite(v) else format(v, fmt)


def _print_table(per_scene: dict, total: dict) -> None:
    print("| scene | completeness | correctness | position error (m) | slope error mean / max (°) | planes right | time (s) |")
    print("|" + "---|" * 7)
    for name, s in list(per_scene.items()) + [("**all**", total)]:
        print(f"| {name} | {_pct(s['completeness'])} | {_pct(s['correctness'])} | {_num(s['position_error'])} | "
              f"{_num(s['slope_error_mean'], '.2f')} / {_num(s['slope_error_max'], '.2f')} | {s['planes_ok']}/{s['scenes']} | "
              f"{s['time_s_mean']:.3f} |")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--density", type=float, default=12.0, help="points per m²")
    ap.add_argument("--noise", type=float, default=0.04, help="height noise, m")
    ap.add_argument("--repeats", type=int, default=10, help="random placements per scene")
    ap.add_argument("--no-outline", action="store_true", help="outline from the points instead of the true one")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    ap.add_argument("--real", action="store_true", help="run on the real clouds in ../shared/data")
    ap.add_argument("--synth", type=int, nargs="+", metavar="SEED", help="run on rooftrace.synth scenes of these seeds")
    ap.add_argument("--pipeline", type=int, nargs="+", metavar="SEED",
                    help="end to end: simulated scenes through rooftrace.pipeline.run_pipeline")
    ap.add_argument("--figure", help="render one Delft building to this PNG")
    ap.add_argument("--building", type=int, default=7, help="building index for --figure (BGT feature / IGN cluster)")
    ap.add_argument("--dataset", choices=["delft", "ign"], default="delft", help="real data set for --figure")
    args = ap.parse_args(argv)
    options = RoofOptions()
    if args.figure:
        render(args.figure, args.building, options, args.dataset)
        return {}
    if args.pipeline:
        run_pipeline_scenes(args.pipeline, args.density)
        return {}
    if args.synth:
        rows = run_synth(args.synth, args.density, not args.no_outline, options)
        kinds = sorted({r["scene"] for r in rows})
        per_scene = {k: summarise([r for r in rows if r["scene"] == k]) for k in kinds}
        total = summarise(rows)
        print(f"rooftrace.synth seeds {args.synth}, {args.density} pts/m², {len(rows)} buildings, "
              f"outline: {'points' if args.no_outline else 'true'}")
        _print_table(per_scene, total)
        return total
    if args.real:
        print("| data | buildings | pitched | pitched with lines | planes | median plane RMSE (m) | lines | time total / max (s) |")
        print("|" + "---|" * 8)
        return run_real(options)
    rows = [
        run_scene(name, 1000 * i + rep, args.density, args.noise, not args.no_outline, options)
        for i, name in enumerate(models.BENCHMARK_MODELS)
        for rep in range(args.repeats)
    ]
    per_scene = {name: summarise([r for r in rows if r["scene"] == name]) for name in models.BENCHMARK_MODELS}
    total = summarise(rows)
    if args.json:
        print(json.dumps({"overall": total, "scenes": per_scene}, indent=1))
        return total
    print(f"density {args.density} pts/m², noise {args.noise} m, {args.repeats} placements per scene, "
          f"outline: {'points' if args.no_outline else 'true'}")
    hdr = ("| scene | completeness | correctness | position error (m) | slope error mean / max (°) | planes right "
           "| superstructure planes / chimneys | kinds right | time (s) |")
    print(hdr)
    print("|" + "---|" * 9)
    for name, s in list(per_scene.items()) + [("**all**", total)]:
        print(f"| {name} | {100 * s['completeness']:.1f} % | {100 * s['correctness']:.1f} % | {s['position_error']:.3f} | "
              f"{s['slope_error_mean']:.2f} / {s['slope_error_max']:.2f} | {s['planes_ok']}/{s['scenes']} | "
              f"{s['detail_planes']} / {s['chimneys']} | {100 * s['kind_agreement']:.0f} % | {s['time_s_mean']:.3f} |")
    print(f"targets: completeness >= {TARGETS['completeness']:.0%}, spurious <= 5 %, position error <= "
          f"{TARGETS['position_error']} m, slope error <= {TARGETS['slope_error']}°")
    return total


if __name__ == "__main__":
    main()
