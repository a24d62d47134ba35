"""``rooftrace info``: what is in a point cloud (count, bounds, CRS, density, classes)."""

from __future__ import annotations

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json
from rooftrace.io.points import read_points


@app.command()
def info(inputs: opt.Inputs, crs: opt.Crs = None, json_: opt.Json = False) -> None:
    """Summarise point clouds: points, bounds, CRS, planimetric density and classes."""
    cloud = read_points(inputs, crs, require_points=False)
    lo = cloud.xyz.min(axis=0) if len(cloud) else np.zeros(3)
    hi = cloud.xyz.max(axis=0) if len(cloud) else np.zeros(3)
    area = float(np.prod(hi[:2] - lo[:2]))
    summary = {
        "points": len(cloud),
        "crs": cloud.crs.to_string() if cloud.crs is not None else None,
        "bounds": [*lo.tolist(), *hi.tolist()],
        "density_bbox": len(cloud) / area if area > 0 else None,
        "dimensions": sorted(cloud.fields),
    }
    if "classification" in cloud.fields:
        values, counts = np.unique(cloud.fields["classification"], return_counts=True)
        summary["classes"] = {int(v): int(c) for v, c in zip(values, counts)}
    if json_:
        emit_json(summary)
        return
    for key, value in summary.items():
        typer.echo(f"{key:>13}: {value}")
