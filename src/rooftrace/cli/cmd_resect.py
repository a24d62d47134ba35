"""``rooftrace resect``: exterior orientation of a frame image from ground control points.

Reads the interior orientation (and a starting exterior orientation) from
``--camera-in``, the GCPs from a CSV with the columns ``id,X,Y,Z,col,row``
(docs/image.md), solves the space resection and writes the oriented
``camera.json`` with its 6 x 6 exterior covariance.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, setup_logging
from rooftrace.errors import GeometryError, InputError

__all__ = ["resect", "read_gcps"]

GCP_COLUMNS = ("id", "X", "Y", "Z", "col", "row")


def read_gcps(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """GCP ids, ground coordinates (N, 3) and pixels (N, 2) (col, row) from a CSV file."""
    if not path.is_file():
        raise InputError(f"{path}: no such GCP file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a UTF-8 text CSV file") from None
    reader = csv.DictReader(text.splitlines())
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in GCP_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)}; the header must be {','.join(GCP_COLUMNS)}")
    reader.fieldnames = header
    ids, values = [], []
    for line_no, row in enumerate(reader, start=2):
        if not any((v or "").strip() for v in row.values() if isinstance(v, str)):
            continue  # blank line
        nums = []
        for c in GCP_COLUMNS[1:]:
            raw = (row.get(c) or "").strip()
            try:
                v = float(raw)
            except ValueError:
                raise InputError(f"{path}, line {line_no}: {c} must be a number, got {raw!r}") from None
            if not math.isfinite(v):
                raise InputError(f"{path}, line {line_no}: {c} must be finite, got {raw!r}")
            nums.append(v)
        ids.append((row.get("id") or "").strip() or str(line_no))
        values.append(nums)
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InputError(f"{path}: duplicated GCP id(s) {', '.join(dup)}")
    if len(values) < 3:
        raise InputError(f"{path}: space resection needs at least 3 GCPs, found {len(values)}")
    arr = np.array(values, float)
    return ids, arr[:, :3], arr[:, 3:]


@app.command("resect")
def resect(
    gcps: Annotated[Path, typer.Argument(help="Ground control points: CSV with columns id,X,Y,Z,col,row "
                                         "(CRS units; pixel centres at integers).", show_default=False)],
    camera_in: Annotated[Path, typer.Option("--camera-in", help="camera.json with the interior orientation "
                                            "and a starting exterior orientation.", show_default=False)],
    output: opt.Output,
    sigma_px: Annotated[float | None, typer.Option("--sigma-px", min=0.0, help="A-priori precision of the "
                                                      "GCP image measurements (px), used with only 3 GCPs. [default: 1]")] = None,
    config: opt.Config = None,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Solve the exterior orientation (and its covariance) of a frame image from GCPs."""
    # the library is imported when a command runs, not for --help or another command
    from rooftrace.config import load_config
    from rooftrace.image.resection import ResectionOptions, space_resection
    from rooftrace.io.atomic import check_output
    from rooftrace.io.camera import read_camera, write_camera
    from rooftrace.options import make_options

    setup_logging(quiet)
    check_output(output, overwrite)
    options = make_options(ResectionOptions, load_config(config), sigma_px=sigma_px)
    camera = read_camera(camera_in)
    if getattr(camera, "kind", None) != "frame":
        raise InputError(f"{camera_in}: space resection needs a 'frame' camera, not {camera.kind!r}")
    if camera.crs is not None:  # X0, Y0, Z0 and the GCPs are metres
        from rooftrace.io.checks import require_metric_crs

        require_metric_crs(camera.crs, str(camera_in))
    ids, xyz, cr = read_gcps(gcps)
    try:
        result = space_resection(camera, xyz, cr, options=options)
    except GeometryError as exc:
        raise InputError(f"{gcps}: {exc}") from None
    write_camera(output, result.camera, overwrite=overwrite)
    eo = result.exterior
    summary = {
        "output": str(output),
        "gcps": len(ids),
        "iterations": result.iterations,
        "redundancy": result.redundancy,
        "rms_px": result.rms,
        "sigma0_px": result.sigma0,
        "exterior": {"X0": eo[0], "Y0": eo[1], "Z0": eo[2], "omega_deg": math.degrees(eo[3]),
                     "phi_deg": math.degrees(eo[4]), "kappa_deg": math.degrees(eo[5])},
        "std": {"X0": result.std[0], "Y0": result.std[1], "Z0": result.std[2],
                "omega_deg": math.degrees(result.std[3]), "phi_deg": math.degrees(result.std[4]),
                "kappa_deg": math.degrees(result.std[5])},
        "residuals_px": {i: [float(v) for v in r] for i, r in zip(ids, result.residuals)},
    }
    if json_:
        emit_json(summary)
        return
    typer.echo(f"{len(ids)} GCPs, {result.iterations} iterations, redundancy {result.redundancy}")
    typer.echo(f"residual RMS: {result.rms:.3f} px   sigma0: {result.sigma0:.3f} px")
    for key, value in summary["exterior"].items():
        typer.echo(f"{key:>10}: {value:14.4f}  +/- {summary['std'][key]:.4f}")
    typer.echo(f"wrote {output}")
