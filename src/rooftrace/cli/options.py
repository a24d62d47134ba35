"""Options shared by several commands, declared once (rasterio's ``options.py`` style)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

Inputs = Annotated[list[Path], typer.Argument(help="Input point clouds (LAS/LAZ; PLY or text x y z where noted).", show_default=False)]
Output = Annotated[Path, typer.Option("--output", "-o", help="Output file.", show_default=False)]
Outputs = Annotated[list[Path], typer.Option(
    "--output", "-o", show_default=False,
    help="Output file, format by its name: .gpkg (layers), .city.jsonl (CityJSONSeq), .city.json (CityJSON 2.0) "
         "or .obj; repeat -o to write several from one run.")]
OutputDir = Annotated[Path, typer.Option("--output", "-o", help="Output folder.", show_default=False)]
Crs = Annotated[str | None, typer.Option("--crs", help=(
    "Assign or override the input CRS, e.g. EPSG:28992; a compound CRS records the height system too, "
    "e.g. EPSG:7415 (RD New + NAP height)."))]
Config = Annotated[Path | None, typer.Option("--config", help="TOML file with stage options, one [table] per stage.")]
Json = Annotated[bool, typer.Option("--json", help="Print one JSON summary on stdout (logs stay on stderr).")]
Overwrite = Annotated[bool, typer.Option("--overwrite", help="Replace an existing output.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="Only warnings and errors on stderr.")]
Seed = Annotated[int, typer.Option("--seed", min=0, help="Seed of everything random (>= 0).")]
Workers = Annotated[int, typer.Option("--workers", min=1, help="Parallel workers (processes).")]
Scheduler = Annotated[str | None, typer.Option("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786.")]
TileSize = Annotated[float | None, typer.Option("--tile-size", min=1.0, help=(
    "Tile side in metres (default: no tiling; when tiling, about 3 M points a buffered tile)."))]
Buffer = Annotated[float | None, typer.Option("--buffer", min=0.0, help="Tile buffer in metres (default: derived).")]
Resume = Annotated[bool, typer.Option("--resume", help="Skip tiles finished by an earlier run into the same output.")]
IMAGE_HELP = "Aerial image: an orthophoto (georeferenced GeoTIFF, no camera file needed) or a frame image (give --camera)."
Image = Annotated[Path | None, typer.Option("--image", help=IMAGE_HELP, show_default=False)]
Camera = Annotated[Path | None, typer.Option("--camera", help=(
    "camera.json of a frame image (optional for an orthophoto: its GeoTIFF georeference is the camera)."),
    show_default=False)]


def _alpha_strategy(value: str | None) -> str | None:
    from rooftrace.contour.alpha_shape import STRATEGIES
    from rooftrace.errors import InputError

    if value is not None and value not in STRATEGIES:
        raise InputError(f"--alpha must be {', '.join(STRATEGIES[:-1])} or {STRATEGIES[-1]}, got {value!r}")
    return value


Alpha = Annotated[str | None, typer.Option(
    "--alpha", callback=_alpha_strategy, help="Alpha-shape strategy: global (S1), building (S2) or point (S3).")]


def flag_for(option: str) -> str:
    """The command-line flag of a library option (``tile_size`` -> ``--tile-size``).

    Library errors name options by field (:class:`rooftrace.errors.OptionError`);
    every flag is the field's name in kebab case, so one rule spells them all.
    """
    return "--" + option.replace("_", "-")
