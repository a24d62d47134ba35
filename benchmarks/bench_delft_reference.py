"""Where a Delft outline differs from BGT `pand`, and what a wall-line reference costs a roof outline.

    .venv/bin/python benchmarks/bench_delft_reference.py OUT.gpkg [MORE.gpkg ...]
    .venv/bin/python benchmarks/bench_delft_reference.py --record NAME OUT.gpkg   # and record its figures

For each GeoPackage of ``rooftrace run`` or ``rooftrace outline`` on the two
Delft tiles (layer ``roof_outlines``), inside the area the BGT layers cover:

- area F-score, FN and FP (m²) against ``bgt_pand``, as ``rooftrace evaluate``;
- FP by distance to the nearest BGT wall line (< 0.5 m, 0.5-1 m, beyond) and,
  beyond 1 m, by the BGT layer it lies on;
- the same F-score after every outline is moved inwards by 0.05-0.4 m
  (mitred): BGT is the wall line, a roof outline the eaves, so this bounds
  what any correction of overhangs alone could win.
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
    label = None
    if args[:1] == ["--record"]:
        if len(args) != 3:
            sys.exit(__doc__)
        label, args = args[1], args[2:]
    if not args:
        sys.exit(__doc__)
    main(args, label)
