"""Roof-outline benchmark: alpha strategies, outward correction, snapping and peers.

    .venv/bin/python benchmarks/bench_outline.py city3d      # 50 AHN3 single buildings vs footprints
    .venv/bin/python benchmarks/bench_outline.py delft       # AHN3 class 6 of both tiles vs BGT pand
    .venv/bin/python benchmarks/bench_outline.py synthetic   # curved shapes with exact truth
    .venv/bin/python benchmarks/bench_outline.py speed       # 1,000-point building, outline time

Prints one line per method: mean PoLiS (m) and mean area F-score (per
building for City3D; one overlay of all polygons for Delft) and run time.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from rooftrace.contour.alpha_shape import mean_spacing as cloud_spacing  # noqa: E402
from rooftrace.contour.outline import OutlineOptions, outline_buildings, trace_outline  # noqa: E402
from rooftrace.evaluate.metrics import area_scores, polis  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
CITY3D = DATA / "city3d_ahn3_single_buildings" / "instances_002"
DELFT = DATA / "3dfier_delft_ahn3_bgt"


THESIS = dict(scale=1.0, t_dist=0.6, offset_factor=0.0, snap=False, test="global", split=False,
              points_per_degree=1, max_overshoot=1e9)


def _variants():
    for strategy in ("global", "building", "point"):
        yield (f"thesis    {strategy:8s} (alpha x1, T_dist 0.6, F-test global)",
               OutlineOptions.from_config({}, strategy=strategy, **THESIS))
        for offset in (0.0, 0.3):
            for snap in (False, True):
                yield (f"rooftrace {strategy:8s} offset={offset:.1f} snap={int(snap)}",
                       OutlineOptions.from_config({}, strategy=strategy, offset_factor=offset, snap=snap))


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


def city3d() -> None:
    import json

    from plyfile import PlyData

    feats = json.loads((CITY3D / "002_footprint.geojson").read_text())["features"]
    clouds, truths = [], []
    for f in feats:
        v = PlyData.read(str(CITY3D / f["properties"]["instance_ply"]))["vertex"]
        clouds.append(np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64))
        truths.append(shapely.geometry.shape(f["geometry"]))
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
        times = []
        for _ in range(20):
            t0 = time.perf_counter()
            trace_outline(xyz, options, mean_spacing=s)
            times.append(time.perf_counter() - t0)
        print(f"{len(xyz)} points, strategy {strategy:8s}: median {np.median(times) * 1000:.1f} ms, max {max(times) * 1000:.1f} ms")


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "city3d"
    {"city3d": city3d, "speed": speed}[what]()
