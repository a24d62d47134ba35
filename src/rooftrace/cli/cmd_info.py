"""``rooftrace info``: what is in a point cloud (count, bounds, CRS, density, classes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json


@app.command()
def info(inputs: opt.Inputs, crs: opt.Crs = None, json_: opt.Json = False) -> None:
    """Summarise point clouds: points, bounds, CRS, planimetric density, classes, and how `run` would go."""
    from rooftrace.io.las import LAS_SUFFIXES
    from rooftrace.io.points import read_points, summarise_las
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
    for line in describe(summary, file_crs):
        typer.echo(line)


def describe(summary: dict, crs=None) -> list[str]:
    """The lines ``info`` prints: rounded numbers with their units.

    Coordinates in the CRS's unit (metres for a projected CRS) to the
    millimetre, the density to 0.01 pts/m².
    """
    from rooftrace.io.checks import horizontal_crs

    unit = ""  # without a CRS the unit is unknown
    h = horizontal_crs(crs)
    if h is not None and h.axis_info:
        unit = {"metre": "m", "degree": "°", "US survey foot": "US ft", "foot": "ft"}.get(
            h.axis_info[0].unit_name, h.axis_info[0].unit_name)
    z_unit = "m"
    if crs is not None and crs.is_compound and crs.sub_crs_list[-1].axis_info:
        z_unit = {"metre": "m"}.get(crs.sub_crs_list[-1].axis_info[0].unit_name, crs.sub_crs_list[-1].axis_info[0].unit_name)
    b = summary["bounds"]
    name = f" ({crs.name})" if crs is not None and crs.name and crs.name != summary["crs"] else ""
    density = summary["density_bbox"]
    classes = summary.get("classes")
    rows = [
        ("points", str(summary["points"])),
        ("crs", f"{summary['crs'] or 'none (assign one with --crs)'}{name}"),
        ("bounds", f"x {b[0]:.3f} to {b[3]:.3f}{' ' * bool(unit)}{unit}, y {b[1]:.3f} to {b[4]:.3f}"
                   f"{' ' * bool(unit)}{unit}, z {b[2]:.3f} to {b[5]:.3f}{' ' * bool(unit)}{z_unit if unit else ''}"),
        ("density_bbox", "none (no area)" if density is None else
         f"{density:.2f} pts/{unit}² (over the bounding box)" if unit else
         f"{density:.2f} points per square unit of the coordinates (over the bounding box; no CRS)"),
        ("dimensions", ", ".join(summary["dimensions"])),
    ]
    if classes is not None:
        rows.append(("classes", ", ".join(f"{k}: {v}" for k, v in classes.items())))
    run = summary["run"]
    how = "in tiles" if run["tiled"] else "in one piece"
    rows.append(("run", f"{how} (about {run['memory_one_piece_gib']:.2f} GiB in one piece; "
                        f"{run['memory_available_gib']:.2f} GiB available)"))
    return [f"{key:>13}: {value}" for key, value in rows]
