"""Where a Delft outline differs from BGT `pand`, and what a wall-line reference costs a roof outline.

    .venv/bin/python benchmarks/bench_delft_reference.py OUT.gpkg [MORE.gpkg ...]
    .venv/bin/python benchmarks/bench_delft_reference.py --record NAME OUT.gpkg   # and record its figures
    .venv/bin/python benchmarks/bench_delft_reference.py --objects OUT.gpkg       # what the FP and FN are

For each GeoPackage of ``rooftrace run`` or ``rooftrace outline`` on the two
Delft tiles (layer ``roof_outlines``), inside the area the BGT layers cover:

- area F-score, FN and FP (m²) against ``bgt_pand``, as ``rooftrace evaluate``;
- FP by distance to the nearest BGT wall line (< 0.5 m, 0.5-1 m, beyond) and,
  beyond 1 m, by the BGT layer it lies on;
- the same F-score after every outline is moved inwards by 0.05-0.4 m
  (mitred): BGT is the wall line, a roof outline the eaves, so this bounds
  what any correction of overhangs alone could win.

``--objects`` runs the detection of ``rooftrace run`` on the two tiles again
(deterministic, so these are the output's buildings) and prints

- every FP part beyond 1 m of a BGT wall and every FN part larger than
  2 m²: its area, the points in it, their height above ground (median, 90th
  percentile), the share of non-last returns, planarity and eigen-entropy of
  the points taken together, the BGT layer under it, the points' classes in
  the detection and in AHN, and the sides of its smallest enclosing rectangle;
- the outline's offset from the free BGT walls (the boundary of the union of
  ``pand``; a sample every 0.5 m, at least 3 m inside the BGT area), beside
  the outermost building point and the outermost one at roof height, by
  the roof behind the wall (a plane through the building points 0.3-2.5 m
  inside): flat (both slopes < 0.1), eaves (rising inwards > 0.25), gable
  ends (level across, sloped along) and the rest.  These figures are recorded
  as ``outline / delft_walls``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import shapely

import _data

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from rooftrace.io.vector import read_layer  # noqa: E402

DELFT = _data.DATA / "3dfier_delft_ahn3_bgt"
SHIFTS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4)


def _union(path: Path) -> shapely.Geometry:
    return shapely.union_all(read_layer(path).geometries)


def _scores(extracted: shapely.Geometry, reference: shapely.Geometry) -> tuple[float, float, float]:
    tp = extracted.intersection(reference).area
    fp, fn = extracted.area - tp, reference.area - tp
    return 2 * tp / (2 * tp + fp + fn), fn, fp


def _parts_table(title: str, geom, xyz, hag, returns, ours, ahn, layers: dict) -> None:
    """One line per part > 2 m² of ``geom``: area, points, heights, returns, shape, BGT layer, classes."""
    parts = sorted((g for g in shapely.get_parts(geom) if g.area > 2.0), key=lambda g: -g.area)
    print(f"{title}: {len(parts)} parts > 2 m², {sum(g.area for g in parts):.0f} of {geom.area:.0f} m²")
    print("  area m²  pts  HAG p50  p90  non-last  planar  entropy  BGT layer              "
          "ours 6/5/2/1       AHN 6/1/2/26       rectangle (m)")
    inside = shapely.points(xyz[:, :2])
    for g in parts:
        idx = np.flatnonzero(shapely.contains(g, inside))
        planar = entropy = np.nan
        if len(idx) >= 4:
            ev = np.sort(np.linalg.eigvalsh(np.cov(xyz[idx].T)))[::-1]
            ev = np.maximum(ev, 1e-12)
            lps = np.array([(ev[0] - ev[1]) / ev[0], (ev[1] - ev[2]) / ev[0], ev[2] / ev[0]])
            planar, entropy = lps[1], float(-np.sum(lps[lps > 0] * np.log(lps[lps > 0])))
        cover = {k: g.intersection(v).area for k, v in layers.items()}
        under = max(cover, key=cover.get)
        under = under if cover[under] > 0.2 * g.area else "-"
        ring = np.asarray(shapely.minimum_rotated_rectangle(g).exterior.coords)
        sides = sorted(np.hypot(*np.diff(ring[:3], axis=0).T)) if len(ring) >= 4 else [0.0, 0.0]
        h = np.percentile(hag[idx], [50, 90]) if len(idx) else [np.nan, np.nan]
        ours_count = "/".join(str(int((ours[idx] == k).sum())) for k in (6, 5, 2, 1))
        ahn_count = "/".join(str(int((ahn[idx] == k).sum())) for k in (6, 1, 2, 26))
        split = np.mean(returns[idx]) if len(idx) else np.nan
        print(f"  {g.area:7.1f} {len(idx):4d} {h[0]:8.2f} {h[1]:5.2f} {split:8.2f}"
              f" {planar:7.2f} {entropy:8.2f}  {under:22s} {ours_count:18s} "
              f"{ahn_count:18s} {sides[0]:.1f} x {sides[1]:.1f}")


def _wall_offsets(pand, aoi, outlines, xyz, building) -> dict[str, np.ndarray]:
    """Per 0.5 m sample of the free BGT walls: outline offset, outermost building point (all, at roof height)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(xyz[:, :2])
    boundary = shapely.union_all(outlines).boundary
    inner = aoi.buffer(-3.0)
    rows, kinds = [], []
    for poly in shapely.get_parts(pand):
        for hole, ring in [(False, poly.exterior)] + [(True, r) for r in poly.interiors]:
            c = np.asarray(ring.coords)[:, :2]
            turn = (1.0 if shapely.is_ccw(ring) else -1.0) * (-1.0 if hole else 1.0)
            for a, b in zip(c[:-1], c[1:]):
                length = float(np.hypot(*(b - a)))
                if length < 1.5:
                    continue
                t = (b - a) / length
                n = turn * np.array([t[1], -t[0]])  # outward from the building
                for p in a + np.arange(0.5, length - 0.5, 0.5)[:, None] * t:
                    if not inner.contains(shapely.Point(p)):
                        continue
                    idx = np.asarray(tree.query_ball_point(p, 3.0), dtype=np.int64)
                    rel = xyz[idx, :2] - p
                    out, along = rel @ n, rel @ t
                    band = building[idx] & (np.abs(along) < 0.5)
                    roof = band & (out < -0.3) & (out > -2.5)
                    if roof.sum() < 5:
                        continue
                    design = np.column_stack([-out[roof], along[roof], np.ones(roof.sum())])
                    (rise, slope_along, level), *_ = np.linalg.lstsq(design, xyz[idx[roof], 2], rcond=None)
                    near = band & (np.abs(out) < 1.5)
                    at_roof = near & (np.abs(xyz[idx, 2] - level) < 0.3)
                    probe = shapely.LineString([p - 2 * n, p + 2 * n]).intersection(boundary)
                    cross = np.array([q.coords[0][:2] for q in shapely.get_parts(probe) if q.geom_type == "Point"])
                    offset = np.nan
                    if len(cross):
                        d = (cross - p) @ n
                        offset = d[np.argmin(np.abs(d))]
                    rows.append((offset, out[near].max() if near.any() else np.nan,
                                 out[at_roof].max() if at_roof.any() else np.nan))
                    flat_along = abs(slope_along) < 0.1
                    kinds.append("flat" if abs(rise) < 0.1 and flat_along else "eave" if rise > 0.25 else
                                 "gable end" if abs(rise) < 0.1 and abs(slope_along) > 0.25 else "other")
    rows, kinds = np.array(rows), np.array(kinds)
    return {k: rows[kinds == k] for k in ("flat", "eave", "gable end", "other")}


def objects(path: str) -> None:
    """What the FP beyond 1 m of a wall and the FN are, and the outline's offset from the free walls."""
    import pyproj

    from _results import record
    from rooftrace.io.points import read_points
    from rooftrace.lidar.detect import detect_buildings

    layers = sorted(DELFT.glob("bgt_*.sqlite"))
    aoi = shapely.union_all([_union(p) for p in layers])
    pand = _union(DELFT / "bgt_pand.sqlite").intersection(aoi)
    others = {p.stem.removeprefix("bgt_"): _union(p).intersection(aoi) for p in layers if p.stem != "bgt_pand"}
    cloud = read_points([DELFT / "ahn3_cropped_1.laz", DELFT / "ahn3_cropped_2.laz"], pyproj.CRS("EPSG:28992"))
    detection = detect_buildings(cloud)
    f = cloud.fields
    returns = (f["return_number"] < f["number_of_returns"]).astype(float)
    outlines = shapely.force_2d(np.asarray(read_layer(path, "roof_outlines").geometries))
    extracted = shapely.union_all(outlines).intersection(aoi)
    args = (cloud.xyz, detection.hag, returns, detection.classification, f["classification"])
    _parts_table("FP beyond 1 m of a BGT wall", extracted.difference(pand).difference(pand.boundary.buffer(1.0)),
                 *args, others)
    _parts_table("FN", pand.difference(extracted), *args, {"pand": pand})
    walls = _wall_offsets(pand, aoi, outlines, cloud.xyz, detection.classification == 6)
    print("free BGT walls, outward offsets (m, median [quartiles]): outline | outermost building point | "
          "outermost at roof height")
    rows = []
    for kind, r in walls.items():
        q = [np.nanpercentile(r[:, j], [25, 50, 75]) for j in range(3)]
        print(f"  {kind:9s} {len(r):5d} samples  " + " | ".join(f"{v[1]:+.3f} [{v[0]:+.2f}, {v[2]:+.2f}]" for v in q))
        rows += [dict(method=f"rooftrace run, {kind} roofs", metric=m, value=v[1], unit="m")
                 for m, v in zip(("outline_offset_median", "outermost_point_median", "outermost_roof_point_median"), q)]
        rows.append(dict(method=f"rooftrace run, {kind} roofs", metric="samples", value=len(r)))
    record("outline", "delft_walls", rows, command=(
        "rooftrace run ahn3_cropped_1.laz ahn3_cropped_2.laz --crs EPSG:28992 -o delft.gpkg; .venv/bin/python "
        "benchmarks/bench_delft_reference.py --objects delft.gpkg"))


def main(paths: list[str], name: str | None = None) -> None:
    layers = sorted(DELFT.glob("bgt_*.sqlite"))
    aoi = shapely.union_all([_union(p) for p in layers])
    pand = _union(DELFT / "bgt_pand.sqlite").intersection(aoi)
    others = {p.stem.removeprefix("bgt_"): _union(p).intersection(aoi) for p in layers if p.stem != "bgt_pand"}
    walls = pand.boundary
    near, far = walls.buffer(0.5), walls.buffer(1.0)
    rows = []
    for path in paths:
        outlines = shapely.force_2d(np.asarray(read_layer(path, "roof_outlines").geometries))
        extracted = shapely.union_all(outlines).intersection(aoi)
        f, fn, fp = _scores(extracted, pand)
        false = extracted.difference(pand)
        a, b = false.intersection(near).area, false.intersection(far).area
        beyond = false.difference(far)
        print(f"{path}: F {f:.4f}, FN {fn:.0f} m², FP {fp:.0f} m²")
        rows += [dict(method=name, metric="f_score", value=f, target=">= 0.93"),
                 dict(method=name, metric="fn_area", value=fn, unit="m²"),
                 dict(method=name, metric="fp_area", value=fp, unit="m²"),
                 dict(method=name, metric="fp_area_within_1m_of_wall", value=b, unit="m²")]
        print(f"  FP by distance to a BGT wall: < 0.5 m {a:.0f}, 0.5-1 m {b - a:.0f}, beyond {beyond.area:.0f} m²; "
              "beyond, on: " + ", ".join(f"{k} {beyond.intersection(v).area:.0f}" for k, v in others.items()))
        for d in SHIFTS[1:]:
            moved = shapely.union_all(shapely.buffer(outlines, -d, join_style="mitre")).intersection(aoi)
            f, fn, fp = _scores(moved, pand)
            print(f"  moved {d:.2f} m inwards: F {f:.4f}, FN {fn:.0f}, FP {fp:.0f} m²")
    if name is not None:
        from _results import record

        record("outline", "delft_run", rows, command=(
            "rooftrace run ahn3_cropped_1.laz ahn3_cropped_2.laz --crs EPSG:28992 -o delft.gpkg; .venv/bin/python "
            f"benchmarks/bench_delft_reference.py --record '{name}' delft.gpkg"))


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["--objects"]:
        if len(args) != 2:
            sys.exit(__doc__)
        objects(args[1])
        sys.exit()
    label = None
    if args[:1] == ["--record"]:
        if len(args) != 3:
            sys.exit(__doc__)
        label, args = args[1], args[2:]
    if not args:
        sys.exit(__doc__)
    main(args, label)
