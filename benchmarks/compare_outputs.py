"""Dump the outputs of a fixed set of runs, and compare two dumps at tolerance 0.

A refactor that must not change behaviour is checked by dumping before and
after and comparing::

    .venv/bin/python benchmarks/compare_outputs.py dump /tmp/before     # on the old commit
    .venv/bin/python benchmarks/compare_outputs.py dump /tmp/after      # on the new one
    .venv/bin/python benchmarks/compare_outputs.py compare /tmp/before /tmp/after

or dump the sources of another commit without checking it out
(``git archive main src | tar -x -C /tmp/main`` then ``--src /tmp/main/src``).

The runs: the demo scene (simulate, run with the image, evaluate), AHN3 Delft
(``run`` untiled with the 3D models and the classified points, tiled, with
the BGT footprints as input, and ``evaluate`` against the BGT footprints),
one IGN LiDAR HD tile (``run`` with the orthophoto and ``detect``) and ten
City3D single buildings (``outline --single-building``).  Every layer of every GeoPackage is compared
feature by feature (geometry as WKB, every attribute), every CityJSONSeq
line by line, every LAS/LAZ point by point (all dimensions), every JSON file
key by key after dropping timings.  Exit code 1 when anything differs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
DELFT = DATA / "3dfier_delft_ahn3_bgt"
IGN = DATA / "ign_montpellier_lidarhd_bdortho"
CITY3D = DATA / "city3d_ahn3_single_buildings" / "instances_002"

#: keys of a JSON summary that measure the machine, not the method
VOLATILE = {"timings", "stage_seconds", "seconds", "time_s", "elapsed", "date", "created", "output", "path"}


def _runs(out: Path) -> dict[str, list[str]]:
    ign_laz = IGN / "test_data_77055_627760_LA93_IGN69.laz"
    return {
        "demo": ["demo", "-o", str(out / "demo"), "--overwrite", "--quiet"],
        "delft": ["run", str(DELFT / "ahn3_cropped_1.laz"), "--crs", "EPSG:28992", "-o", str(out / "delft.gpkg"),
                  "-o", str(out / "delft.city.jsonl"), "--classified", str(out / "delft.laz"), "--json", "--quiet"],
        "delft_footprints": ["run", str(DELFT / "ahn3_cropped_1.laz"), "--crs", "EPSG:28992",
                             "--footprints", str(DELFT / "bgt_pand.sqlite"), "-o", str(out / "delft_fp.gpkg"),
                             "-o", str(out / "delft_fp.city.jsonl"), "--json", "--quiet"],
        "delft_tiled": ["run", str(DELFT / "ahn3_cropped_1.laz"), "--crs", "EPSG:28992",
                        "-o", str(out / "delft_tiled.gpkg"), "--tile-size", "150", "--json", "--quiet"],
        "delft_eval": ["evaluate", str(out / "delft.gpkg"), str(DELFT / "bgt_pand.geojson"),
                       "-o", str(out / "delft_eval"), "--json", "--quiet"],
        "ign": ["run", str(ign_laz), "--image", str(IGN / "test_data_rgb.tif"), "--camera", str(out / "ortho.json"),
                "-o", str(out / "ign.gpkg"), "--json", "--quiet"],
        "ign_detect": ["detect", str(ign_laz), "-o", str(out / "ign_detect.laz"), "--json", "--quiet"],
        "city3d": ["outline", "--single-building", *[str(CITY3D / f"{i}.ply") for i in range(10)],
                   "--crs", "EPSG:28992", "-o", str(out / "city3d.gpkg"), "--json", "--quiet"],
    }


def dump(out: Path, only: list[str] | None, src: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    (out / "ortho.json").write_text(json.dumps({"type": "orthophoto"}))
    env = {**os.environ, "PYTHONPATH": str(src)}
    status = 0
    for name, args in _runs(out).items():
        if only and name not in only:
            continue
        proc = subprocess.run([sys.executable, "-c", "from rooftrace.cli.main import main; main()", *args],
                              env=env, capture_output=True, text=True)
        (out / f"{name}.stdout").write_text(proc.stdout)
        (out / f"{name}.stderr").write_text(proc.stderr)
        (out / f"{name}.rc").write_text(f"{proc.returncode}\n")
        print(f"{name}: exit {proc.returncode}", flush=True)
        status |= proc.returncode != 0
    return int(status)


def _strip(obj, root: str = ""):
    """The JSON without what measures the machine, and with the dump's own folder spelled the same in both."""
    if isinstance(obj, dict):
        return {k: _strip(v, root) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [_strip(v, root) for v in obj]
    if isinstance(obj, str) and root:
        return obj.replace(root, "<dump>")
    return obj


def _compare_json(a: Path, b: Path, root_a: Path, root_b: Path) -> list[str]:
    def load(p: Path, root: Path):
        text = p.read_text().strip()
        if p.suffix != ".json":
            return [_strip(json.loads(line), str(root)) for line in text.splitlines()]
        return _strip(json.loads(text), str(root))

    try:
        da, db = load(a, root_a), load(b, root_b)
    except json.JSONDecodeError:
        same = a.read_text().replace(str(root_a), "<dump>") == b.read_text().replace(str(root_b), "<dump>")
        return [] if same else [f"{a.name}: text differs"]
    return [] if da == db else [f"{a.name}: JSON differs"]


def _compare_lines(a: Path, b: Path, rel: Path) -> list[str]:
    """A CityJSONSeq line by line (header, then one building per line)."""
    la, lb = a.read_text().splitlines(), b.read_text().splitlines()
    if len(la) != len(lb):
        return [f"{rel}: {len(la)} lines vs {len(lb)}"]
    return [f"{rel}: line {k + 1} differs" for k, (x, y) in enumerate(zip(la, lb)) if x != y][:5]


def _compare_gpkg(a: Path, b: Path) -> list[str]:
    import pyogrio

    diffs = []
    la = [n for n, _ in pyogrio.list_layers(a)]
    lb = [n for n, _ in pyogrio.list_layers(b)]
    if la != lb:
        return [f"{a.name}: layers {la} != {lb}"]
    for layer in la:
        ma, fa, ga, fields_a = _read_layer(a, layer)
        mb, fb, gb, fields_b = _read_layer(b, layer)
        if fields_a != fields_b or ma != mb:
            diffs.append(f"{a.name}:{layer}: schema differs")
            continue
        if ga != gb:
            diffs.append(f"{a.name}:{layer}: geometries differ")
        for name, col_a, col_b in zip(fields_a, fa, fb):
            if not _same_array(col_a, col_b):
                diffs.append(f"{a.name}:{layer}: attribute {name} differs")
    return diffs


def _read_layer(path: Path, layer: str):
    import pyogrio

    meta, _, geometry, field_data = pyogrio.raw.read(path, layer=layer)
    return ((meta["crs"], meta["geometry_type"], list(meta["dtypes"])), field_data,
            [bytes(g) if g is not None else None for g in geometry], list(meta["fields"]))


def _same_array(x, y) -> bool:
    x, y = np.asarray(x), np.asarray(y)
    if x.shape != y.shape or x.dtype != y.dtype:
        return False
    if x.dtype.kind == "f":
        return bool(np.array_equal(x, y, equal_nan=True))
    return bool(np.array_equal(x, y))


def _compare_las(a: Path, b: Path) -> list[str]:
    import laspy

    pa, pb = laspy.read(a), laspy.read(b)
    if list(pa.point_format.dimension_names) != list(pb.point_format.dimension_names):
        return [f"{a.name}: point formats differ"]
    diffs = [f"{a.name}: dimension {d} differs" for d in pa.point_format.dimension_names
             if not _same_array(pa[d], pb[d])]
    if pa.header.point_count != pb.header.point_count:
        diffs.append(f"{a.name}: point counts differ")
    return diffs


def compare(a: Path, b: Path) -> int:
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    diffs = []
    if files_a != files_b:
        diffs.append(f"file lists differ: {sorted(set(files_a) ^ set(files_b))}")
    checked = 0
    for rel in sorted(set(files_a) & set(files_b)):
        pa, pb = a / rel, b / rel
        suffix = pa.suffix.lower()
        if suffix == ".gpkg":
            diffs += _compare_gpkg(pa, pb)
        elif suffix in (".las", ".laz"):
            diffs += _compare_las(pa, pb)
        elif suffix == ".jsonl":
            diffs += _compare_lines(pa, pb, rel)
        elif suffix in (".json", ".stdout") or suffix == ".rc":
            diffs += _compare_json(pa, pb, a, b) if suffix != ".rc" else ([] if pa.read_text() == pb.read_text()
                                                                      else [f"{rel}: exit codes differ"])
        elif suffix == ".tif":
            import rasterio

            with rasterio.open(pa) as ra, rasterio.open(pb) as rb:
                if not _same_array(ra.read(), rb.read()):
                    diffs.append(f"{rel}: raster differs")
        else:
            continue  # stderr (log wording), html and png reports: not outputs of the method
        checked += 1
    for d in diffs:
        print("DIFF", d)
    print(f"{checked} files compared, {len(diffs)} differences")
    return int(bool(diffs))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p_dump = sub.add_parser("dump", help="run every case into a folder")
    p_dump.add_argument("out", type=Path)
    p_dump.add_argument("--only", nargs="*", help="names of the runs to do (default: all)")
    p_dump.add_argument("--src", type=Path, default=ROOT / "src",
                        help="the rooftrace sources to run (default: this checkout's; e.g. an export of main)")
    p_cmp = sub.add_parser("compare", help="compare two dumps at tolerance 0")
    p_cmp.add_argument("a", type=Path)
    p_cmp.add_argument("b", type=Path)
    args = parser.parse_args(argv)
    if args.cmd == "dump":
        return dump(args.out, args.only, args.src.resolve())
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
