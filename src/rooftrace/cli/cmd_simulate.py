"""``rooftrace simulate``: a synthetic scene with exact ground truth (LAZ, image, camera, truth GeoPackage)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import STATE, app, emit_json, reporter_for, setup_logging
from rooftrace.errors import InputError, OutputExistsError

Density = Annotated[float | None, typer.Option("--density", help="Mean ALS pulse density (pts/m²). [default: 12]")]
Size = Annotated[float | None, typer.Option("--size", help="Side of the square scene (m). [default: 160]")]
Gsd = Annotated[float | None, typer.Option("--gsd", help="Image ground sample distance (m/pixel). [default: 0.2]")]
SeedOpt = Annotated[int | None, typer.Option("--seed", min=0, help="Seed of everything random (>= 0). [default: 1]")]
Ortho = Annotated[bool, typer.Option("--orthophoto", help="Render a true orthophoto GeoTIFF instead of a frame image.")]
Perturb = Annotated[float | None, typer.Option(
    "--perturb-camera", min=0.01, help="Also write camera_perturbed.json, off by about this many pixels.")]
SceneKind = Annotated[str | None, typer.Option(
    "--scene", help="Buildings: 'default' (the house mix) or 'blocks' (city blocks around courtyards). [default: default]")]
NoImage = Annotated[bool, typer.Option("--no-image", help="Skip the image (LiDAR and truth only).")]
PowerLine = Annotated[bool, typer.Option("--power-line", help="Add a power line (ASPRS class 14 in the truth).")]


@app.command("simulate")
def simulate(
    output: opt.OutputDir,
    seed: SeedOpt = None,
    density: Density = None,
    size: Size = None,
    gsd: Gsd = None,
    orthophoto: Ortho = False,
    perturb_camera: Perturb = None,
    no_image: NoImage = False,
    power_line: PowerLine = False,
    scene_kind: SceneKind = None,
    config: opt.Config = None,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Simulate a scene: points.laz, image.tif, camera.json and truth.gpkg (roof_outlines, ridges, footprints, roof_faces).

    The cloud is raw (class 1); the truth is in the extra dimensions
    truth_class and truth_building_id.  Options also come from the
    [simulate] table of --config.
    """
    from rooftrace.config import load_config
    from rooftrace.options import make_options
    from rooftrace.synth import SceneOptions, simulate_scene, write_scene
    from rooftrace.synth.simulate import SCENE_FILES

    setup_logging(quiet, STATE["verbose"])
    cfg = load_config(config)
    options = make_options(SceneOptions, cfg, seed=seed, density=density, size=size, gsd=gsd,
                           orthophoto=True if orthophoto else None, image=False if no_image else None,
                           power_line=True if power_line else None, scene=scene_kind)
    if perturb_camera is not None and (options.orthophoto or not options.image):
        raise InputError("--perturb-camera needs a frame image (not with --orthophoto or --no-image)")
    out = Path(output)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a folder")
    if out.is_dir() and not overwrite:
        clash = [n for n in SCENE_FILES.values() if (out / n).exists()]
        if clash:
            raise OutputExistsError(f"{out} already holds {', '.join(clash)}; pass {{overwrite}} to replace", "overwrite")
    reporter = reporter_for(quiet or json_)
    try:
        with reporter.stage("simulate"):
            scene = simulate_scene(options)
        with reporter.stage("write"):
            paths = write_scene(out, scene, overwrite=overwrite, perturbed_camera_px=perturb_camera)
    finally:
        reporter.close()
    summary = _summary(scene, paths)
    if json_:
        emit_json(summary)
        return
    for key in ("points", "buildings", "roof_density", "image_size", "seconds"):
        typer.echo(f"{key:>13}: {summary[key]}")
    for key, path in summary["files"].items():
        typer.echo(f"{key:>13}: {path}")


def _summary(scene, paths) -> dict:
    from rooftrace.synth.checks import roof_density

    cloud = scene.cloud
    classes, counts = np.unique(cloud.fields["truth_class"], return_counts=True)
    return {
        "points": len(cloud),
        "buildings": len(scene.buildings),
        "ridges": len(scene.ridges),
        "roof_density": round(roof_density(scene), 2) if scene.buildings else None,
        "roof_density_with_walls": round(roof_density(scene, walls=True), 2) if scene.buildings else None,
        "truth_classes": {int(c): int(n) for c, n in zip(classes, counts)},
        "image_size": list(scene.image.shape[2:0:-1]) if scene.image is not None else None,
        "seed": scene.options.seed,
        "crs": scene.crs.to_string(),
        "seconds": round(scene.info["seconds"]["total"], 2),
        "files": {k: str(v) for k, v in paths.items()},
    }
