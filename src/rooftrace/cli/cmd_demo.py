"""``rooftrace demo``: simulate → run (with the image) → evaluate → report, on the embedded default scene."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, reporter_for, setup_logging

log = logging.getLogger("rooftrace.cli")

#: the file that marks a folder as a demo's output (so that --overwrite may replace it)
MARKER = ".rooftrace-demo"


def looks_like_demo(folder: Path) -> bool:
    """True for a folder an earlier ``rooftrace demo`` wrote (its marker, or its four main files)."""
    return (folder / MARKER).is_file() or all(
        (folder / name).is_file() for name in ("report.html", "metrics.json", "truth.gpkg", "result.gpkg"))


@app.command("demo")
def demo(
    output: Annotated[Path, typer.Option("--output", "-o", help="Output folder.")] = Path("demo-output"),
    seed: opt.Seed = 1,
    density: Annotated[float, typer.Option("--density", min=0.5, help="LiDAR density, pts/m².")] = 12.0,
    size: Annotated[float, typer.Option("--size", min=40.0, help="Scene side, metres.")] = 160.0,
    no_image: Annotated[bool, typer.Option("--no-image", help="LiDAR only, skip the image refinement.")] = False,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Generate a synthetic scene with exact truth, run the whole method on it, evaluate, write a report."""
    import json

    import numpy as np

    from rooftrace.errors import InputError
    from rooftrace.evaluate import evaluate
    from rooftrace.evaluate.report import write_report
    from rooftrace.io.atomic import atomic_path, replace_folder, temporary_path
    from rooftrace.io.models import write_models
    from rooftrace.io.vector import read_layer, write_layers
    from rooftrace.pipeline import building_layers, run_pipeline
    from rooftrace.synth import SceneOptions, simulate_scene, write_scene

    setup_logging(quiet)
    output = Path(output)
    if output.exists() and not output.is_dir():
        raise InputError(f"{output}: exists and is not a folder")
    if output.exists() and any(output.iterdir()):
        if not overwrite:
            raise InputError(f"{output}: folder is not empty; pass --overwrite to replace its files")
        if not looks_like_demo(output):
            raise InputError(f"{output}: not the output of an earlier demo (no {MARKER}, report.html, metrics.json, "
                             "truth.gpkg and result.gpkg); --overwrite replaces only a demo folder, choose another "
                             "-o or empty it yourself")
    output.absolute().parent.mkdir(parents=True, exist_ok=True)
    # built in a hidden sibling and swapped in at the end: no file of an earlier run stays (the image
    # of a run with it beside a --no-image result), and a failure or an interrupt leaves the old folder
    # (the command line removes the unfinished one: rooftrace.io.atomic.remove_temporary)
    final, output = output, temporary_path(output, folder=True)
    (output / MARKER).write_text("written by rooftrace demo; 'rooftrace demo --overwrite' may replace this folder\n",
                                 encoding="utf-8")

    log.info("simulating a %.0f m scene at %.1f pts/m² (seed %d)", size, density, seed)
    scene = simulate_scene(SceneOptions(seed=seed, size=size, density=density, image=not no_image))
    files = write_scene(output, scene, overwrite=True)

    cloud = scene.cloud
    grey = None
    if not no_image:
        grey = scene.image.astype(np.float64).mean(axis=0) / 255.0
    reporter = reporter_for(quiet)
    try:
        result = run_pipeline(cloud, image=grey, camera=None if no_image else scene.camera, seed=seed,
                              reporter=reporter)
    finally:
        reporter.close()
    result_path = output / "result.gpkg"
    write_layers(result_path, result.layers, cloud.crs, overwrite=True)
    models_path = output / "result.city.jsonl"  # the 3D buildings beside the layers
    write_models([models_path], result.models, cloud.crs, overwrite=True)

    truth = read_layer(files["truth"], "roof_outlines")
    truth_ridges = read_layer(files["truth"], "ridges", missing_ok=True)
    reference_ridges = list(truth_ridges.geometries) if truth_ridges is not None else None
    outlines = list(result.layers["roof_outlines"].geometries)
    ridges = list(result.layers["ridges"].geometries)
    metrics = evaluate(outlines, list(truth.geometries), extracted_ridges=ridges, reference_ridges=reference_ridges)
    lidar_outlines = lidar_only = None
    if result.refined is not None:
        # what the image adds: the same scores for the LiDAR-only outlines of this run
        lidar_layers = building_layers(result.outlines, result.structures)
        lidar_outlines = list(lidar_layers["roof_outlines"].geometries)
        lidar_only = evaluate(lidar_outlines, list(truth.geometries),
                              extracted_ridges=list(lidar_layers["ridges"].geometries),
                              reference_ridges=reference_ridges)
        metrics["compare"] = {"label": "LiDAR only", **lidar_only}
    with atomic_path(output / "metrics.json", overwrite=True) as tmp:
        tmp.write_text(json.dumps(metrics, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    building = cloud.fields["truth_class"] == 6 if "truth_class" in cloud.fields else None
    report = write_report(output, metrics, outlines, list(truth.geometries),
                          points_xy=cloud.xyz[building, :2] if building is not None else None,
                          extracted_ridges=ridges, reference_ridges=reference_ridges,
                          compare=lidar_outlines, compare_metrics=lidar_only,
                          image=None if no_image else scene.image, camera=None if no_image else scene.camera,
                          labels=("refined (LiDAR + image)" if lidar_only is not None else "extracted", "LiDAR only"),
                          title=f"rooftrace demo — synthetic scene, seed {seed}", models=result.models)
    replace_folder(output, final)
    report = final / report.relative_to(output)
    models_path = final / models_path.relative_to(output)
    summary = {"output": str(final), "report": str(report), "models": str(models_path), **{k: metrics.get(k) for k in (
        "completeness", "correctness", "f_score", "quality", "polis_mean", "hausdorff_mean",
        "rmse_x", "rmse_y", "rmse_z", "n_reference", "n_extracted", "n_matched",
        "ridge_completeness", "ridge_correctness", "ridge_position_error")}}
    if lidar_only is not None:
        summary["polis_mean_lidar_only"] = lidar_only["polis_mean"]
        summary["f_score_lidar_only"] = lidar_only["f_score"]
    summary["run"] = result.summary()
    if json_:
        emit_json(summary)
    else:
        typer.echo(f"report: {report}")
        typer.echo(f"3D buildings: {models_path}")
        # lengths to the millimetre, scores to 0.001
        units = {"polis_mean": " m", "polis_mean_lidar_only": " m", "rmse_z": " m", "ridge_position_error": " m"}
        for key in ("f_score", "polis_mean", "polis_mean_lidar_only", "rmse_z", "ridge_position_error",
                    "n_reference", "n_matched"):
            if key in summary:
                value = summary[key]
                text = f"{value:.3f}{units.get(key, '')}" if isinstance(value, float) else str(value)
                typer.echo(f"{key:>22}: {text}")
