"""``rooftrace info``: what is in a point cloud (count, bounds, CRS, density, classes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json
from rooftrace.io.las import LAS_SUFFIXES
from rooftrace.io.points import read_points, summarise_las


@app.command()
def info(inputs: opt.Inputs, crs: opt.Crs = None, json_: opt.Json = False) -> None:
    """Summarise point clouds: points, bounds, CRS, planimetric density, classes, and how `run` would go."""
    from rooftrace.tiling.memory import available_bytes, fits_in_memory, untiled_bytes

    if inputs and all(Path(p).suffix.lower() in LAS_SUFFIXES for p in inputs):
        # chunk by chunk: info must work on a file larger than memory
        s = summarise_las(inputs, crs)
        n, file_crs, bounds, dims, classes = s["points"], s["crs"], s["bounds"], s["dimensions"], s.get("classes")
    else:
        cloud = read_points(inputs, crs, require_points=False)
        n, file_crs = len(cloud), cloud.crs
        lo = cloud.xyz.min(axis=0) if n else np.zeros(3)
        hi = cloud.xyz.max(axis=0) if n else np.zeros(3)
        bounds, dims = [*lo.tolist(), *hi.tolist()], sorted(set(cloud.fields) - {"source_index"})
        classes = None
        if "classification" in cloud.fields:
            values, counts = np.unique(cloud.fields["classification"], return_counts=True)
            classes = {int(v): int(c) for v, c in zip(values, counts)}
    area = float((bounds[3] - bounds[0]) * (bounds[4] - bounds[1]))
    need, free = untiled_bytes(n), available_bytes()
    summary = {
        "points": n,
        "crs": file_crs.to_string() if file_crs is not None else None,
        "bounds": bounds,
        "density_bbox": n / area if area > 0 else None,
        "dimensions": dims,
    }
    if classes is not None:
        summary["classes"] = classes
    summary["run"] = {"tiled": not fits_in_memory(n, free), "memory_one_piece_gib": round(need / 2**30, 2),
                      "memory_available_gib": round(free / 2**30, 2)}
    if json_:
        emit_json(summary)
        return
    run = summary.pop("run")
    for key, value in summary.items():
        typer.echo(f"{key:>13}: {value}")
    how = "in tiles" if run["tiled"] else "in one piece"
    typer.echo(f"{'run':>13}: {how} (about {run['memory_one_piece_gib']:g} GiB in one piece; "
               f"{run['memory_available_gib']:g} GiB available)")
