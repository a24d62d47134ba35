"""Shape quality of roof outlines: corner scores of ``rooftrace evaluate`` beside PoLiS.

    .venv/bin/python benchmarks/bench_shape.py city3d   # 50 AHN3 single buildings vs their footprints
    .venv/bin/python benchmarks/bench_shape.py demo     # the demo scene: LiDAR-only and refined vs truth
    .venv/bin/python benchmarks/bench_shape.py delft OUT.gpkg   # `rooftrace run` on both Delft tiles vs BGT pand

Prints, per method, the mean PoLiS, the median corner count ratio to the
reference, the share of buildings within 1.5x, corner completeness and
correctness within 0.5 m and the mean corner offset (as
:func:`rooftrace.evaluate.evaluate` computes them), and records them with
``benchmarks/_results.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _results import record  # noqa: E402
from bench_outline import _peer_concave, _regularise, city3d_instances  # noqa: E402
from rooftrace.contour.outline import OutlineOptions, outline_buildings  # noqa: E402
from rooftrace.contour.spacing import building_mean_spacing as cloud_spacing  # noqa: E402
from rooftrace.evaluate import evaluate  # noqa: E402

# (key, header, unit, target on City3D)
KEYS = (("polis_mean", "PoLiS m", "m", "<= 0.10"),
        ("corner_ratio_median", "ratio med", "", "<= 1.3"),
        ("corner_ratio_within_1_5", "in 1.5x", "", ">= 0.70"),
        ("corner_completeness", "c.compl", "", None),
        ("corner_correctness", "c.corr", "", None),
        ("corner_offset_mean", "offset m", "m", None))


def _line(name: str, m: dict) -> str:
    return f"{name:42s} " + " ".join(f"{m[k]:9.3f}" if m[k] is not None else f"{'-':>9s}" for k, *_ in KEYS)


def _rows(name: str, m: dict, targets: bool) -> list[dict]:
    return [{"method": name, "metric": k, "value": m[k], "unit": u, "target": t if targets else None}
            for k, _, u, t in KEYS]


def _header(title: str) -> None:
    print(title)
    print(f"{'method':42s} " + " ".join(f"{h:>9s}" for _, h, *_ in KEYS))


def city3d() -> None:
    clouds, truths = city3d_instances()
    xyz = np.concatenate(clouds)
    ids = np.repeat(np.arange(1, len(clouds) + 1), [len(c) for c in clouds])
    spacing = float(np.median([cloud_spacing(c[:, :2]) for c in clouds]))
    ref = evaluate(truths, truths)
    _header(f"City3D instances_002: {len(clouds)} buildings, {ref['n_corners_reference']} footprint corners "
            f"(median {np.median([b['n_corners_reference'] for b in ref['buildings']]):.0f} per building)")
    rows = []
    default = [o.polygon for o in outline_buildings(xyz, ids, OutlineOptions(), mean_spacing=spacing)]
    methods = {"rooftrace default": default}
    for strategy in ("global", "building"):
        options = OutlineOptions.from_config({}, strategy=strategy)
        methods[f"rooftrace --alpha {strategy}"] = [o.polygon for o in outline_buildings(xyz, ids, options,
                                                                                         mean_spacing=spacing)]
    concave = [_peer_concave(c[:, :2], 0.1) for c in clouds]
    methods["shapely.concave_hull ratio=0.1"] = concave
    methods["  + buildingregulariser"] = _regularise(concave)
    methods["rooftrace default + buildingregulariser"] = _regularise(default)
    for name, polys in methods.items():
        m = evaluate(polys, truths, merge_blocks=False)
        print(_line(name, m))
        rows += _rows(name, m, name == "rooftrace default")
    record("shape", "city3d", rows)


def demo() -> None:
    from rooftrace.pipeline import run_pipeline
    from rooftrace.synth import SceneOptions, simulate_scene

    # the scene and run of `rooftrace demo` (seed 1, 160 m, 12 pts/m², with the image)
    scene = simulate_scene(SceneOptions(seed=1, size=160.0, density=12.0, image=True))
    grey = scene.image.astype(np.float64).mean(axis=0) / 255.0
    result = run_pipeline(scene.cloud, image=grey, camera=scene.camera, seed=1)
    truth = list(scene.truth["roof_outlines"].geometries)
    _header(f"demo scene (seed 1): {len(truth)} reference buildings")
    rows = []
    for name, polys in (("LiDAR only", [o.polygon for o in result.outlines]),
                        ("refined (LiDAR + image)", list(result.layers["roof_outlines"].geometries))):
        m = evaluate(polys, truth)
        print(_line(name, m))
        rows += _rows(name, m, False)
    record("shape", "demo", rows)


def delft() -> None:
    import _data
    from rooftrace.io.vector import read_layer

    if len(sys.argv) < 3:
        sys.exit("usage: bench_shape.py delft OUT.gpkg [MORE.gpkg ...] (outputs of rooftrace run on both tiles)")
    bgt = _data.DATA / "3dfier_delft_ahn3_bgt"
    # the area the BGT layers cover, as in bench_outline.py delft: outside it BGT says nothing
    aoi = shapely.union_all([g for p in sorted(bgt.glob("bgt_*.sqlite")) for g in read_layer(p).geometries])
    reference = list(read_layer(bgt / "bgt_pand.sqlite").geometries)
    ref = evaluate(reference, reference, aoi=aoi)
    _header(f"Delft, BGT pand inside the BGT area: {ref['n_reference']} buildings, "
            f"{ref['n_corners_reference']} corners")
    rows = []
    for path in sys.argv[2:]:
        m = evaluate(list(read_layer(path, "roof_outlines").geometries), reference, aoi=aoi)
        name = Path(path).name
        print(_line(name, m) + f"   ({m['n_matched']} units, {m['n_matched_merged']} merged blocks)")
        rows += _rows(name, m, False)
    record("shape", "delft", rows)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "city3d"
    {"city3d": city3d, "demo": demo, "delft": delft}[what]()
