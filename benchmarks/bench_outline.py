"""Roof-outline benchmark: regularisation methods, alpha strategies, outward correction and peers.

    .venv/bin/python benchmarks/bench_outline.py city3d      # 50 AHN3 single buildings vs footprints
    .venv/bin/python benchmarks/bench_outline.py shapes      # lines vs cdspline vs peers, with corner measures
    .venv/bin/python benchmarks/bench_outline.py simulator   # simulated scenes at 12 pts/m² vs true roof outlines
    .venv/bin/python benchmarks/bench_outline.py simulator-check  # the default on other seeds, densities, scan patterns
    .venv/bin/python benchmarks/bench_outline.py delft       # AHN3 class 6 of both tiles vs BGT pand
    .venv/bin/python benchmarks/bench_outline.py synthetic   # curved shapes with exact truth
    .venv/bin/python benchmarks/bench_outline.py speed       # 1,000-point building, outline time
    .venv/bin/python benchmarks/bench_outline.py stage-cpu [--repeat 3]  # the run's outline step on Delft, CPU

Prints one line per method: mean PoLiS (m) and mean area F-score (per
building for City3D; one overlay of all polygons for Delft) and run time;
``shapes`` and ``simulator`` add the corner measures of ``rooftrace evaluate`` and
record their figures with ``_results.record``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import shapely

import _data

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from rooftrace.contour.outline import OutlineOptions, outline_buildings, trace_outline  # noqa: E402
from rooftrace.contour.spacing import building_mean_spacing as cloud_spacing  # noqa: E402
from rooftrace.evaluate.metrics import area_scores, polis  # noqa: E402

DATA = _data.DATA
CITY3D = DATA / "city3d_ahn3_single_buildings" / "instances_002"
DELFT = DATA / "3dfier_delft_ahn3_bgt"


THESIS = dict(enabled=False, scale=1.0, t_dist=0.6, offset_factor=0.0, snap=False, test="global", split=False,
              points_per_degree=1, max_overshoot=1e9, method="cdspline")
#: the regularisations compared by ``shapes`` and ``simulator``: (name, options overrides)
METHODS = (("rooftrace lines (default)", {}), ("rooftrace cdspline", dict(method="cdspline")),
           ("thesis cdspline (S3)", THESIS))


def _variants():
    """(name, options): the thesis's settings and ours, per alpha strategy."""
    for strategy in ("global", "building", "point"):
        yield (f"thesis    {strategy:8s} (alpha x1, T_dist 0.6, F-test global)",
               OutlineOptions.from_config({}, strategy=strategy, **THESIS))
        yield f"rooftrace {strategy:8s} lines (default)", OutlineOptions.from_config({}, strategy=strategy)
        for offset in (0.0, 0.1, 0.2, 0.3):
            for snap in (False, True):
                yield (f"rooftrace {strategy:8s} cdspline offset={offset:.1f} snap={int(snap)}",
                       OutlineOptions.from_config({}, strategy=strategy, offset_factor=offset, snap=snap,
                                                  method="cdspline"))


def _peer_concave(xy, ratio):
    return shapely.concave_hull(shapely.MultiPoint(xy), ratio=ratio)


def _regularise(polys):
    import geopandas as gpd
    from buildingregulariser import regularize_geodataframe

    gdf = gpd.GeoDataFrame(geometry=[shapely.force_2d(p) if p is not None else shapely.Polygon() for p in polys],
                           crs="EPSG:28992")
    out = regularize_geodataframe(gdf, num_cores=1)
    return list(out.geometry)


def _score(polys, truths):
    pol = [polis(p, t) if p is not None and not p.is_empty else np.nan for p, t in zip(polys, truths)]
    f = [area_scores(p if p is not None and not p.is_empty else None, t)["f_score"] for p, t in zip(polys, truths)]
    return float(np.nanmean(pol)), float(np.mean(np.nan_to_num(f))), int(np.isnan(pol).sum())


def city3d_instances() -> tuple[list[np.ndarray], list]:
    """The City3D single-building clouds (x, y, z) and their footprints, in the footprint file's order."""
    import json

    from plyfile import PlyData

    feats = json.loads((CITY3D / "002_footprint.geojson").read_text())["features"]
    clouds, truths = [], []
    for f in feats:
        v = PlyData.read(str(CITY3D / f["properties"]["instance_ply"]))["vertex"]
        clouds.append(np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64))
        truths.append(shapely.geometry.shape(f["geometry"]))
    return clouds, truths


def city3d() -> None:
    clouds, truths = city3d_instances()
    xyz = np.concatenate(clouds)
    ids = np.repeat(np.arange(1, len(clouds) + 1), [len(c) for c in clouds])
    spacing = float(np.median([cloud_spacing(c[:, :2]) for c in clouds]))
    print(f"City3D instances_002: {len(clouds)} buildings, {len(xyz)} points, median s_avg {spacing:.3f} m")
    print(f"{'method':45s} {'PoLiS m':>8s} {'F-score':>8s} {'failed':>6s} {'time s':>7s}")
    for name, options in _variants():
        t0 = time.perf_counter()
        outs = outline_buildings(xyz, ids, options, mean_spacing=spacing)
        dt = time.perf_counter() - t0
        polys = [o.polygon for o in outs]
        p, f, bad = _score(polys, truths)
        print(f"{name:45s} {p:8.3f} {f:8.4f} {bad:6d} {dt:7.2f}")
    best = None
    for ratio in (0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5):
        polys = [_peer_concave(c[:, :2], ratio) for c in clouds]
        p, f, bad = _score(polys, truths)
        print(f"{'shapely.concave_hull ratio=' + str(ratio):45s} {p:8.3f} {f:8.4f} {bad:6d}")
        if best is None or p < best[0]:
            best = (p, ratio, polys)
    p, f, bad = _score(_regularise(best[2]), truths)
    print(f"{'  + buildingregulariser (best ratio)':45s} {p:8.3f} {f:8.4f} {bad:6d}")
    import concave_hull

    for concavity in (1.0, 2.0, 3.0):
        polys = [shapely.Polygon(concave_hull.concave_hull(c[:, :2], concavity=concavity)) for c in clouds]
        p, f, bad = _score(polys, truths)
        print(f"{'concave_hull pkg concavity=' + str(concavity):45s} {p:8.3f} {f:8.4f} {bad:6d}")
    name, options = "rooftrace default", OutlineOptions()
    outs = outline_buildings(xyz, ids, options, mean_spacing=spacing)
    p, f, bad = _score(_regularise([o.polygon for o in outs]), truths)
    print(f"{'rooftrace default + buildingregulariser':45s} {p:8.3f} {f:8.4f} {bad:6d}")


def delft() -> None:
    from rooftrace.contour.outline import connected_buildings
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import read_layer

    cloud = read_points(sorted(DELFT.glob("ahn3_cropped_*.laz")), "EPSG:28992")
    cls = cloud.fields["classification"]
    sel = cls == 6
    xyz = cloud.xyz[sel]
    context = cloud.xyz[~sel & ~np.isin(cls, (7, 18))]  # as `rooftrace run` passes them
    aoi = shapely.union_all([g for p in sorted(DELFT.glob("bgt_*.sqlite")) for g in read_layer(p).geometries])
    ref = shapely.union_all(read_layer(DELFT / "bgt_pand.sqlite").geometries)
    t0 = time.perf_counter()
    spacing = cloud_spacing(xyz[:, :2])
    ids = connected_buildings(xyz[:, :2], 2.0 * spacing, min_points=10)
    t_ids = time.perf_counter() - t0
    print(f"Delft AHN3 class 6: {len(xyz)} points, s_avg {spacing:.3f} m, {ids.max()} components "
          f"({t_ids:.1f} s); BGT area {aoi.area:.0f} m², bgt_pand {ref.area:.0f} m² inside")
    print(f"{'method':45s} {'compl':>7s} {'corr':>7s} {'F-score':>8s} {'time s':>7s}")

    def report(name, polys, dt=float("nan")):
        ext = shapely.intersection(shapely.union_all([shapely.force_2d(p) for p in polys if p is not None]), aoi)
        s = area_scores(ext, shapely.intersection(ref, aoi))
        print(f"{name:45s} {s['completeness']:7.4f} {s['correctness']:7.4f} {s['f_score']:8.4f} {dt:7.2f}")

    variants = dict(_variants())
    which = sys.argv[2:] or [n for n in variants if "snap=0" not in n]
    for name in which:
        t0 = time.perf_counter()
        outs = outline_buildings(xyz, ids, variants[name], mean_spacing=spacing, context_xy=context)
        report(name, [o.polygon for o in outs], time.perf_counter() - t0)
    groups = [xyz[ids == i, :2] for i in range(1, ids.max() + 1)]
    for ratio in (0.02, 0.05, 0.1, 0.2):
        report(f"shapely.concave_hull ratio={ratio}", [_peer_concave(g, ratio) for g in groups if len(g) >= 3])


def synthetic() -> None:
    sys.path.insert(0, str(ROOT))
    from tests.contour.shapes import CIRCLE, COURTYARD, L_SHAPE, RECT, STADIUM, sample

    shapes = {"rectangle": RECT, "L": L_SHAPE, "courtyard": COURTYARD, "round (r 8 m)": CIRCLE,
              "semicircular end": STADIUM}
    print(f"{'shape':18s} {'density':>7s} {'PoLiS m':>8s} {'F-score':>8s}  degrees (outer ring, 5 seeds)")
    for density in (5.0, 10.0):
        for name, truth in shapes.items():
            p, f, degs = [], [], []
            for seed in range(5):
                out = trace_outline(sample(truth, density, seed=seed))
                p.append(polis(out.polygon, truth))
                f.append(area_scores(out.polygon, truth)["f_score"])
                degs.append("".join(map(str, out.degrees[0])))
            print(f"{name:18s} {density:7.1f} {np.mean(p):8.3f} {np.mean(f):8.4f}  {' '.join(degs)}")


def speed() -> None:
    rng = np.random.default_rng(0)
    poly = shapely.Polygon([(0, 0), (14, 0), (14, 5), (8, 5), (8, 9), (0, 9)])
    s = 1 / np.sqrt(10)
    g = np.mgrid[0:14:s, 0:9:s].reshape(2, -1).T + rng.uniform(-0.3 * s, 0.3 * s, (1, 2))
    g = g[shapely.contains_xy(poly, *g.T)][:1000]
    xyz = np.column_stack([g, np.full(len(g), 7.0)])
    for strategy in ("global", "building", "point"):
        options = OutlineOptions.from_config({}, strategy=strategy)
        trace_outline(xyz, options, mean_spacing=s)  # warm-up (numba cache, imports)
        times, cpu = [], []
        for _ in range(20):
            t0, c0 = time.perf_counter(), time.process_time()
            trace_outline(xyz, options, mean_spacing=s)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        print(f"{len(xyz)} points, strategy {strategy:8s}: wall median {np.median(times) * 1000:.1f} ms "
              f"(max {max(times) * 1000:.1f}), CPU median {np.median(cpu) * 1000:.1f} ms")


def stage_cpu() -> None:
    """CPU seconds of the outline step of ``rooftrace run`` on both Delft tiles (LiDAR only), best of ``--repeat``.

    The step as the pipeline calls it (:func:`outline_buildings` with the
    detection's building ids, spacing and the points around the buildings),
    timed alone: the whole run's steps are ``bench_run_time.py``'s.  Process
    CPU (all threads), the best of the repeats after a warm-up run (numba's
    caches, imports), since the machine is shared.
    """
    from _results import record
    from rooftrace.io.points import read_points
    from rooftrace.lidar.detect import detect_buildings

    repeat = int(sys.argv[sys.argv.index("--repeat") + 1]) if "--repeat" in sys.argv else 3
    cloud = read_points(sorted(DELFT.glob("ahn3_cropped_*.laz")), "EPSG:28992")
    det = detect_buildings(cloud)
    around = (det.building_id <= 0) & (det.classification != 7)  # as pipeline.run_pipeline passes them

    def once() -> float:
        c0 = time.process_time()
        outline_buildings(cloud.xyz, det.building_id, OutlineOptions(), mean_spacing=det.mean_spacing,
                          context_xy=cloud.xyz[around])
        return time.process_time() - c0

    once()
    best = min(once() for _ in range(repeat))
    print(f"outline step, Delft both tiles, {det.building_id.max()} buildings: {best:.2f} s CPU (best of {repeat})")
    record("outline", "delft_stage_cpu", [dict(method="outline_buildings (LiDAR only, default)", metric="cpu_s",
                                               value=round(best, 2), unit="s", target="<= 4.0")])


def _shape_rows(name: str, polys, truths, seconds: float | None = None, curved=None) -> list[dict]:
    """Mean PoLiS, F, corner measures (and time) of one method's outlines as result rows; prints one line."""
    from rooftrace.evaluate.metrics import corner_metrics

    pol = np.array([polis(p, t) if p is not None and not p.is_empty else np.nan for p, t in zip(polys, truths)])
    f = np.array([area_scores(p if p is not None and not p.is_empty else None, t)["f_score"]
                  for p, t in zip(polys, truths)])
    cs = [corner_metrics(p, t) for p, t in zip(polys, truths)]
    ratio = np.array([c["corner_ratio"] for c in cs])
    within = np.maximum(ratio, 1 / ratio) <= 1.5
    rows = [("polis_mean", np.nanmean(pol), "m"), ("f_score", np.mean(np.nan_to_num(f)), ""),
            ("corner_ratio_median", np.nanmedian(ratio), ""), ("corner_ratio_within_1.5", np.mean(within), ""),
            ("corner_ratio_at_most_1.5", np.mean(ratio <= 1.5), ""),
            ("corner_completeness", np.nanmean([c["corner_completeness"] for c in cs]), ""),
            ("corner_correctness", np.nanmean([c["corner_correctness"] for c in cs]), ""),
            ("corner_offset_mean", np.nanmean([c["corner_offset"] for c in cs]), "m"), ("failed", np.isnan(pol).sum(), "")]
    if curved is not None:
        curved = np.asarray(curved)
        right = np.array([c["n_corners"] == c["n_corners_reference"] for c in cs])
        rows += [("polis_mean_straight", np.nanmean(pol[~curved]), "m"), ("right_corners_straight", right[~curved].mean(), ""),
                 ("polis_mean_curved", np.nanmean(pol[curved]), "m")]
    if seconds is not None:
        rows.append(("time_s", seconds, "s"))
    values = {m: v for m, v, _ in rows}
    print(f"{name:42s} " + " ".join(f"{v:7.3f}" for v in values.values()))
    return [dict(method=name, metric=m, value=float(v), unit=u) for m, v, u in rows]


def _peer_rows(clouds, truths, curved=None) -> list[dict]:
    """shapely.concave_hull (best ratio), the concave-hull package (best concavity), buildingregulariser on the first."""
    import concave_hull

    best = None
    for ratio in (0.05, 0.1, 0.2, 0.3, 0.5):
        polys = [_peer_concave(c[:, :2], ratio) for c in clouds]
        p = np.nanmean([polis(a, t) for a, t in zip(polys, truths)])
        if best is None or p < best[0]:
            best = (p, ratio, polys)
    rows = _shape_rows(f"shapely.concave_hull ratio={best[1]}", best[2], truths, curved=curved)
    rows += _shape_rows("  + buildingregulariser", _regularise(best[2]), truths, curved=curved)
    best = None
    for concavity in (1.0, 2.0, 3.0):
        polys = [shapely.Polygon(concave_hull.concave_hull(c[:, :2], concavity=concavity)) for c in clouds]
        p = np.nanmean([polis(a, t) for a, t in zip(polys, truths)])
        if best is None or p < best[0]:
            best = (p, concavity, polys)
    rows += _shape_rows(f"concave-hull concavity={best[1]}", best[2], truths, curved=curved)
    return rows


_HEADER = ("PoLiS F cratio_med within1.5 ratio<=1.5 c_compl c_corr c_offset failed")


def shapes() -> None:
    """City3D: lines (default), CD-spline and the thesis beside the peers, with corner measures."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _results import record

    clouds, truths = city3d_instances()
    xyz = np.concatenate(clouds)
    ids = np.repeat(np.arange(1, len(clouds) + 1), [len(c) for c in clouds])
    spacing = float(np.median([cloud_spacing(c[:, :2]) for c in clouds]))
    print(f"City3D instances_002: {len(clouds)} buildings; columns: {_HEADER} time_s")
    rows = []
    for name, kw in METHODS:
        t0 = time.perf_counter()
        outs = outline_buildings(xyz, ids, OutlineOptions.from_config({}, **kw), mean_spacing=spacing)
        rows += _shape_rows(name, [o.polygon for o in outs], truths, time.perf_counter() - t0)
        if kw == {}:
            rows += _shape_rows("rooftrace lines + buildingregulariser", _regularise([o.polygon for o in outs]), truths)
    rows += _peer_rows(clouds, truths)
    for row in rows:
        row["target"] = {"polis_mean": "<= 0.10", "corner_ratio_median": "<= 1.3",
                         "corner_ratio_within_1.5": ">= 0.70"}.get(row["metric"]) if "default" in row["method"] else None
    record("outline", "city3d_shapes", rows)


#: simulated building kinds with curved walls
CURVED_KINDS = ("round", "stadium", "arc")


def _simulated_buildings(seeds, density: float = 12.0, scan_pattern: str = "zigzag"):
    """Per simulated building: its class-6 truth points, the other points near it, its true outline, curved or not."""
    from rooftrace.synth import SceneOptions, simulate_scene

    out = []
    for seed in seeds:
        scene = simulate_scene(SceneOptions(seed=seed, density=density, image=False, scan_pattern=scan_pattern))
        xyz = scene.cloud.xyz
        cls = np.asarray(scene.cloud.fields["truth_class"])
        bid = np.asarray(scene.cloud.fields["truth_building_id"])
        kinds = {b.building_id: b.kind for b in scene.buildings}
        truth = scene.truth["roof_outlines"]
        for t, b in zip(truth.geometries, truth.attributes["building_id"]):
            own = (bid == b) & (cls == 6)
            if own.sum() < 10:
                continue
            centre = xyz[own, :2].mean(axis=0)
            near = ~own & (cls != 7) & (np.abs(xyz[:, :2] - centre).max(axis=1) < 40.0)
            out.append((xyz[own], xyz[near], t, kinds[b] in CURVED_KINDS))
    return out


def simulator() -> None:
    """Simulated scenes (seeds 1-3, 12 pts/m², default building mix): every building against its true roof outline."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _results import record

    seeds = [int(a) for a in sys.argv[2:]] or [1, 2, 3]
    buildings = _simulated_buildings(seeds)
    truths = [b[2] for b in buildings]
    curved = [b[3] for b in buildings]
    print(f"simulator seeds {seeds}: {len(buildings)} buildings ({sum(curved)} curved); columns: {_HEADER} "
          "PoLiS_straight right_corners_straight PoLiS_curved time_s")
    rows = []
    for name, kw in (*METHODS, ("rooftrace lines, no context points", {})):
        options = OutlineOptions.from_config({}, **kw)
        use_context = "no context" not in name
        t0 = time.perf_counter()
        outs = [trace_outline(xyz, options, context_xy=ctx if use_context else None) for xyz, ctx, _, _ in buildings]
        polys = [o.polygon for o in outs]
        rows += _shape_rows(name, polys, truths, time.perf_counter() - t0, curved=curved)
        deg = [max(max(d) for d in o.degrees) for o, c in zip(outs, curved) if c]
        rows.append(dict(method=name, metric="curved_degree_at_least_2", value=float(np.mean(np.array(deg) >= 2))))
        print(f"{'':42s} curved buildings with a segment of degree >= 2: {np.mean(np.array(deg) >= 2):.2f}")
    rows += _peer_rows([b[0] for b in buildings], truths, curved=curved)
    targets = {"polis_mean_straight": "<= 0.06", "right_corners_straight": ">= 0.90", "polis_mean": "<= 0.08",
               "curved_degree_at_least_2": ">= 1.0"}
    for row in rows:
        row["target"] = targets.get(row["metric"]) if "default" in row["method"] else None
    record("outline", "simulator_12ppm", rows)


#: scenes the method was not tuned on: (seeds, pts/m², scan pattern)
INDEPENDENT = (((4, 5, 6), 12.0, "zigzag"), ((1, 2), 8.0, "zigzag"), ((1, 2), 20.0, "zigzag"),
               ((1, 2), 12.0, "parallel"), ((1, 2), 12.0, "random"))


def simulator_check() -> None:
    """The default on simulated scenes other than the tuning set: other seeds, densities and scan patterns."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _results import record

    options = OutlineOptions.from_config({})
    rows = []
    print(f"columns: {_HEADER} PoLiS_straight right_corners_straight PoLiS_curved time_s")
    for seeds, density, pattern in INDEPENDENT:
        buildings = _simulated_buildings(seeds, density, pattern)
        name = f"lines (default), seeds {'-'.join(map(str, seeds))}, {density:g} pts/m², {pattern}"
        curved = [b[3] for b in buildings]
        t0 = time.perf_counter()
        outs = [trace_outline(xyz, options, context_xy=ctx) for xyz, ctx, _, _ in buildings]
        rows += _shape_rows(name, [o.polygon for o in outs], [b[2] for b in buildings], time.perf_counter() - t0,
                            curved=curved)
        deg = np.array([max(max(d) for d in o.degrees) >= 2 for o, c in zip(outs, curved) if c])
        rows += [dict(method=name, metric="curved_degree_at_least_2", value=float(deg.mean())),
                 dict(method=name, metric="buildings", value=len(buildings)),
                 dict(method=name, metric="curved_buildings", value=int(sum(curved)))]
        print(f"{'':42s} curved buildings with a segment of degree >= 2: {deg.sum()} of {len(deg)}")
    record("outline", "simulator_independent", rows)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "city3d"
    {"city3d": city3d, "shapes": shapes, "simulator": simulator, "delft": delft, "synthetic": synthetic,
     "speed": speed, "simulator-check": simulator_check, "stage-cpu": stage_cpu}[what]()
