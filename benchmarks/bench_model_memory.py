"""Memory of the 3D models of a tiled run against the number of buildings: streamed from the tiles, or held.

Two simulated blocks (``rooftrace simulate``), the second with twice the
side (about four times the buildings), each run in tiles of the same size
(``run_tiled`` with a run folder, in-process).  Then the models are written
to a CityJSONSeq and a CityJSON file twice, and the peak of the Python
allocations (tracemalloc) of each write is measured:

- **streamed**: from ``TiledRunResult.models`` as the run gives it, a
  :class:`rooftrace.tiling.models.ModelStream` that reads each tile's
  models from its file one at a time in building order;
- **held**: the same models first gathered in one list, as every tile's
  models were held until the end before the stream.

The streamed peak should not grow with the buildings; the held one grows
with them.  The merged 2D layers (outlines, faces, ridges, the GeoPackage's
LoD layers) are still held whole by the run; their pickled size is
reported too.

Usage::

    .venv/bin/python benchmarks/bench_model_memory.py [--size 100] [--tile-size 50]

Recorded as dataset ``simulated_blocks`` of benchmark ``model_memory``.
"""

from __future__ import annotations

import argparse
import pickle
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import record
from rooftrace.io.las import write_las
from rooftrace.io.models import write_models
from rooftrace.synth import SceneOptions, simulate_scene
from rooftrace.tiling import TileOptions, run_tiled


def _peak_mib(write, *args, **kwargs) -> float:
    """Peak Python memory (MiB) of one call ``write(*args, **kwargs)`` above what was held before it."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    write(*args, **kwargs)
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    return peak / 2**20


def _write_held(out, models, crs) -> None:
    """Write the models after holding all of them in a list, as before they were streamed."""
    write_models(out, list(models), crs, overwrite=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=float, default=100.0, help="side of the small block (m); the large one is twice")
    ap.add_argument("--tile-size", type=float, default=50.0)
    ap.add_argument("--density", type=float, default=5.0)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="rooftrace-model-memory-"))
    rows = []
    try:
        for scale in (1, 2):
            size = args.size * scale
            scene = simulate_scene(SceneOptions(seed=7, size=size, density=args.density, image=False))
            las = write_las(tmp / f"block{scale}.laz", scene.cloud)
            del scene
            run_dir = tmp / f"run{scale}"
            t0 = time.perf_counter()
            result = run_tiled([las], tiling=TileOptions(tile_size=args.tile_size, buffer=30.0), run_dir=run_dir)
            layers_mib = len(pickle.dumps(result.layers)) / 2**20
            run_s = time.perf_counter() - t0
            out = [tmp / f"b{scale}.city.jsonl", tmp / f"b{scale}.city.json"]
            streamed = _peak_mib(write_models, out, result.models, result.crs, overwrite=True)
            n = sum(1 for _ in result.models)
            held_size = sum(len(pickle.dumps(m)) for m in result.models) / 2**20
            held = _peak_mib(_write_held, out, result.models, result.crs)
            tag = f"x{scale * scale}"
            print(f"block {size:.0f} m ({result.tiles} tiles, {run_s:.0f} s): {n} buildings, models "
                  f"{held_size:.1f} MiB pickled; write peak streamed {streamed:.1f} MiB, held {held:.1f} MiB; "
                  f"merged layers {layers_mib:.1f} MiB pickled")
            rows += [
                {"method": "rooftrace", "metric": f"buildings_{tag}", "value": n, "unit": ""},
                {"method": "streamed", "metric": f"write_peak_mib_{tag}", "value": streamed, "unit": "MiB"},
                {"method": "held", "metric": f"write_peak_mib_{tag}", "value": held, "unit": "MiB"},
                {"method": "rooftrace", "metric": f"models_pickled_mib_{tag}", "value": held_size, "unit": "MiB"},
                {"method": "rooftrace", "metric": f"layers_pickled_mib_{tag}", "value": layers_mib, "unit": "MiB"},
            ]
            shutil.rmtree(run_dir, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(record("model_memory", "simulated_blocks", rows))


if __name__ == "__main__":
    main()
