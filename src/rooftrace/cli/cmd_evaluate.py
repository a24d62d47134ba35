"""``rooftrace evaluate``: extracted outlines against a reference, metrics.json and an HTML report."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Annotated

import typer

from rooftrace.cli import options as opt
from rooftrace.cli.app import app, emit_json, setup_logging

log = logging.getLogger("rooftrace.cli")

_DEFAULT_LAYER = "roof_outlines"
_ID_FIELD = "building_id"


def _read_polygons(path: Path, layer: str | None, what: str, crs):
    """Polygons, their labels and the CRS of one layer; refuses non-polygon layers."""
    import shapely

    from rooftrace.errors import InputError
    from rooftrace.io.points import parse_crs
    from rooftrace.io.vector import list_layers, read_layer

    if layer is None:
        names = list_layers(path)
        if not names:
            raise InputError(f"{path}: {what} file has no layer")
        layer = _DEFAULT_LAYER if _DEFAULT_LAYER in names else names[0]
        if len(names) > 1 and layer != _DEFAULT_LAYER:
            log.warning("%s: several layers and no %r; using %r (choose with --layer/--reference-layer)",
                        path, _DEFAULT_LAYER, layer)
    data = read_layer(path, layer)
    geoms = list(data.geometries)
    bad = sorted({g.geom_type for g in geoms
                  if g is not None and not isinstance(g, (shapely.Polygon, shapely.MultiPolygon))})
    if bad:
        raise InputError(f"{path} (layer {layer!r}): {what} must be polygons, found {', '.join(bad)}; "
                         "choose a polygon layer with --layer/--reference-layer")
    labels = data.attributes.get(_ID_FIELD)
    labels = [v.item() if hasattr(v, "item") else v for v in labels] if labels is not None else None
    file_crs = data.crs
    if crs is not None:  # assign or override, as read_points does for clouds
        user = parse_crs(crs)
        if file_crs is not None and not file_crs.equals(user, ignore_axis_order=True):
            log.warning("%s: file CRS %s overridden by --crs %s", path, file_crs.name, user.name)
        file_crs = user
    return geoms, labels, file_crs, layer


def _read_lines(path: Path, layer: str = "ridges"):
    import shapely

    from rooftrace.io.vector import read_layer

    data = read_layer(path, layer, missing_ok=True)
    if data is None:
        return None
    return [g for g in data.geometries if isinstance(g, (shapely.LineString, shapely.MultiLineString))]


def _check_crs(a, b, what_a: str, what_b: str) -> None:
    from rooftrace.io.checks import check_same_crs

    if (a is None) != (b is None):
        log.warning("%s has no CRS; assuming it is in the CRS of %s", what_a if a is None else what_b,
                    what_b if a is None else what_a)
    check_same_crs(a, b, what_a, what_b)


def _points_xy(path: Path, crs):
    """x, y of the building points (class 6) when classified, else of all points."""
    import numpy as np

    from rooftrace.cloud import ASPRS
    from rooftrace.io.points import read_points

    cloud = read_points([path], crs, require_points=False)
    cls = cloud.fields.get("classification")
    if cls is not None and np.any(cls == ASPRS.BUILDING):
        return cloud.xyz[cls == ASPRS.BUILDING, :2], cloud.crs
    return cloud.xyz[:, :2], cloud.crs


def _cell(key: str, v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if key.startswith("n_"):
        return str(v)
    if key == "corner_ratio_median":
        return f"{v:.2f}×"
    if key.startswith(("polis", "hausdorff", "rmse", "ridge_position", "corner_offset")):
        return f"{v:.3f} m"
    if "_area" in key:
        return f"{v:,.1f} m²"
    return f"{100 * v:.1f} %"


def _table(sets: list[tuple[str, dict]], out_dir: Path) -> None:
    """The scene scores of one extracted set, or of several side by side."""
    from rich.console import Console
    from rich.table import Table

    from rooftrace.evaluate import SUMMARY_KEYS
    from rooftrace.evaluate.report import unit_sentence

    table = Table(title=f"rooftrace evaluate -> {out_dir}", title_justify="left")
    table.add_column("metric")
    for label, _ in sets:
        table.add_column("value" if len(sets) == 1 else label, justify="right")
    for key in SUMMARY_KEYS:
        if any(key in m for _, m in sets):
            table.add_row(key, *(_cell(key, m.get(key)) for _, m in sets))
    console = Console(soft_wrap=True)
    console.print(table)
    console.print(f"matching: {sets[0][1]['matching_rule_description']}")
    for label, m in sets:
        console.print(("" if len(sets) == 1 else f"{label}: ") + unit_sentence(m))


def _image_and_camera(image: Path, camera: Path | None):
    """The image as read (bands, H, W), for the report, and the camera that projects outlines into it."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from rooftrace.io.camera import image_camera
    from rooftrace.io.checks import check_image_size

    with warnings.catch_warnings():  # a frame image has no georeferencing, and needs none
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        cam = image_camera(image, camera)  # refuses an unreadable image with one error line
        with rasterio.open(image) as ds:
            bands = ds.read()
    check_image_size(bands.shape[:0:-1], cam, str(image), str(camera or image))
    return bands, cam


@app.command("evaluate")
def evaluate_cmd(
    extracted: Annotated[Path, typer.Argument(help="Extracted outlines (any OGR vector: GeoPackage, GeoJSON, "
                                                   "Shapefile, FlatGeobuf, SpatiaLite), 2D or 3D polygons.",
                                              show_default=False)],
    reference: Annotated[Path, typer.Argument(help="Reference outlines, same formats.", show_default=False)],
    output: opt.OutputDir,
    aoi: Annotated[Path | None, typer.Option("--aoi", help="Area of interest: a polygon vector file (first "
                                                "layer). Areas are clipped to it; buildings whose interior "
                                                "point lies inside it are evaluated.")] = None,
    layer: Annotated[str | None, typer.Option("--layer", help="Layer of EXTRACTED (default: roof_outlines "
                                                 "if present, else the first).")] = None,
    reference_layer: Annotated[str | None, typer.Option("--reference-layer", help="Layer of REFERENCE "
                                                           "(default: roof_outlines if present, else the first).")] = None,
    points: Annotated[Path | None, typer.Option("--points", help="LAS/LAZ drawn under the outlines in the "
                                                   "plots (class 6 when classified).")] = None,
    min_overlap: Annotated[float, typer.Option("--min-overlap",
                                               help="Overlap fraction (of the smaller polygon) to match, and of a "
                                                    "building's area to count it as found.", show_default=True)] = 0.5,
    no_merge_blocks: Annotated[bool, typer.Option("--no-merge-blocks", help="Match one-to-one instead of "
                                                  "evaluating blocks of overlapping buildings as units.")] = False,
    ridge_buffer: Annotated[float, typer.Option("--ridge-buffer",
                                                help="Buffer for the ridge scores, in metres (when both files have "
                                                     "a 'ridges' layer).", show_default=True)] = 0.5,
    boundary_band: Annotated[float, typer.Option("--boundary-band",
                                                 help="FP and FN within this distance (m) of a reference "
                                                      "boundary are reported apart (fp_area_boundary, "
                                                      "fn_area_boundary): where an outline runs, not which "
                                                      "buildings were found.", show_default=True)] = 1.0,
    corner_tolerance: Annotated[float, typer.Option("--corner-tolerance",
                                                    help="Largest distance (m) at which an extracted corner "
                                                         "matches a reference corner (corner completeness, "
                                                         "correctness and offset).", show_default=True)] = 0.5,
    compare: Annotated[Path | None, typer.Option("--compare", help="A second extracted set (e.g. the "
                                                    "LiDAR-only outlines of a run with an image), evaluated "
                                                    "against the same reference; its scores stand beside "
                                                    "EXTRACTED's in the table and the report, and in "
                                                    "metrics.json under 'compare'.")] = None,
    compare_layer: Annotated[str | None, typer.Option("--compare-layer", help="Layer of --compare (default: "
                                                         "roof_outlines if present, else the first).")] = None,
    label: Annotated[str | None, typer.Option("--label", help="Name of EXTRACTED in the table and the "
                                                 "report (default: its file name).")] = None,
    compare_label: Annotated[str | None, typer.Option("--compare-label", help="Name of --compare (default: "
                                                         "its file name).")] = None,
    image: Annotated[Path | None, typer.Option("--image", help="An image shown in the report with the "
                                                  "outlines over it: a georeferenced orthophoto (GeoTIFF) as "
                                                  "it is, an aerial frame image with --camera.")] = None,
    camera: Annotated[Path | None, typer.Option("--camera", help="camera.json of --image (needed for a frame "
                                                   "image; the outlines must then be 3D).")] = None,
    crs: opt.Crs = None,
    json_: opt.Json = False,
    overwrite: opt.Overwrite = False,
    quiet: opt.Quiet = False,
) -> None:
    """Compare extracted roof outlines with reference ones: completeness, correctness, F-score, quality,
    PoLiS, Hausdorff, RMSE and the corner scores of the shape (corner count ratio, corner completeness,
    correctness and offset), overall and per building; writes DIR/metrics.json and DIR/report.html."""
    import shapely

    from rooftrace.errors import InputError, OutputExistsError
    from rooftrace.evaluate import SUMMARY_KEYS, evaluate
    from rooftrace.evaluate.report import write_report
    from rooftrace.io.atomic import atomic_path
    from rooftrace.io.checks import check_camera_has_image

    setup_logging(quiet)
    if not 0.0 < min_overlap <= 1.0:
        raise InputError(f"--min-overlap must be in (0, 1], got {min_overlap}")
    if not ridge_buffer > 0.0:
        raise InputError(f"--ridge-buffer must be a positive distance in metres, got {ridge_buffer}")
    if not boundary_band > 0.0:
        raise InputError(f"--boundary-band must be a positive distance in metres, got {boundary_band}")
    if not corner_tolerance > 0.0:
        raise InputError(f"--corner-tolerance must be a positive distance in metres, got {corner_tolerance}")
    check_camera_has_image(image, camera)
    for path in (extracted, reference, aoi, points, compare, image, camera):
        if path is not None and not path.exists():
            raise InputError(f"{path}: no such file")
    if output.exists() and not output.is_dir():
        raise InputError(f"{output} is a file; -o takes a folder")
    metrics_path = output / "metrics.json"
    if metrics_path.exists() and not overwrite:
        raise OutputExistsError(f"{metrics_path} exists; pass {{overwrite}} to replace the evaluation in {output}", "overwrite")

    ext, ext_ids, ext_crs, ext_layer = _read_polygons(extracted, layer, "extracted outlines", crs)
    ref, ref_ids, ref_crs, ref_layer = _read_polygons(reference, reference_layer, "reference outlines", crs)
    _check_crs(ext_crs, ref_crs, str(extracted), str(reference))
    other = None
    if compare is not None:
        other, other_ids, other_crs, other_layer = _read_polygons(compare, compare_layer, "compared outlines", crs)
        _check_crs(other_crs, ref_crs, str(compare), str(reference))
    from rooftrace.io.checks import require_metric_crs

    # areas, PoLiS, Hausdorff and RMSE are reported in metres
    checked = [(extracted, ext, ext_crs), (reference, ref, ref_crs)]
    checked += [(compare, other, other_crs)] if other is not None else []
    for path, geoms, file_crs in checked:
        if file_crs is not None:  # a file without CRS was warned about by _check_crs
            require_metric_crs(file_crs, str(path))
        if not any(g is not None and not g.is_empty for g in geoms):
            log.warning("%s: no outlines; every score involving it is 0 or undefined", path)
    area = None
    if aoi is not None:
        aoi_geoms, _, aoi_crs, _ = _read_polygons(aoi, None, "area of interest", crs)
        _check_crs(aoi_crs, ext_crs or ref_crs, str(aoi), str(extracted))
        area = shapely.union_all([g for g in aoi_geoms if g is not None])
        if area.is_empty or area.area <= 0:
            raise InputError(f"{aoi}: the area of interest has no area")
    ext_ridges = _read_lines(extracted) if ext_layer != "ridges" else None
    ref_ridges = _read_lines(reference) if ref_layer != "ridges" else None
    xy = None
    if points is not None:
        xy, pts_crs = _points_xy(points, crs)
        _check_crs(pts_crs, ext_crs or ref_crs, str(points), str(extracted))

    picture = cam = None
    if image is not None:
        picture, cam = _image_and_camera(image, camera)
        from rooftrace.io.checks import check_same_crs

        check_same_crs(getattr(cam, "crs", None), ext_crs or ref_crs, str(camera or image), str(extracted))

    options = {"aoi": area, "ridge_buffer": ridge_buffer, "min_overlap": min_overlap,
               "merge_blocks": not no_merge_blocks, "reference_ids": ref_ids, "boundary_band": boundary_band,
               "corner_tolerance": corner_tolerance}
    metrics = evaluate(ext, ref, extracted_ridges=ext_ridges, reference_ridges=ref_ridges,
                       extracted_ids=ext_ids, **options)
    labels = (label or extracted.name, compare_label or (compare.name if compare is not None else "compared"))
    compared = None
    if other is not None:
        other_ridges = _read_lines(compare) if other_layer != "ridges" else None
        compared = evaluate(other, ref, extracted_ridges=other_ridges, reference_ridges=ref_ridges,
                            extracted_ids=other_ids, **options)
    metrics["inputs"] = {"extracted": str(extracted), "extracted_layer": ext_layer,
                         "reference": str(reference), "reference_layer": ref_layer,
                         "aoi": str(aoi) if aoi is not None else None,
                         "crs": (ext_crs or ref_crs).to_string() if (ext_crs or ref_crs) is not None else None,
                         "label": labels[0]}
    if compared is not None:
        compared["inputs"] = {"extracted": str(compare), "extracted_layer": other_layer}
        metrics["compare"] = {"label": labels[1], **compared}

    output.mkdir(parents=True, exist_ok=True)
    report = write_report(output, metrics, ext, ref, points_xy=xy,
                          extracted_ridges=ext_ridges, reference_ridges=ref_ridges,
                          compare=other, compare_metrics=compared, image=picture, camera=cam, labels=labels,
                          title=f"rooftrace evaluation: {extracted.name} vs {reference.name}")
    # metrics.json last: its presence marks a finished evaluation
    with atomic_path(metrics_path, overwrite) as tmp:
        tmp.write_text(json.dumps(metrics, indent=1, allow_nan=False) + "\n", encoding="utf-8")

    if json_:
        emit_json({"metrics": str(metrics_path), "report": str(report),
                   **{k: metrics[k] for k in SUMMARY_KEYS if k in metrics},
                   "matching_rule": metrics["matching_rule"],
                   **({"compare": {"label": labels[1], **{k: compared[k] for k in SUMMARY_KEYS if k in compared}}}
                      if compared is not None else {})})
    else:
        _table([(labels[0], metrics)] + ([(labels[1], compared)] if compared is not None else []), output)
