"""A preview PNG of a simulated scene: the image with the truth drawn over it, and the LiDAR by height."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import shapely

__all__ = ["save_preview"]

_RIDGE_COLOURS = {"ridge": "#ff2bd6", "hip": "#ffd400", "valley": "#00e5ff", "step": "#ff7f0e"}


def _lines(geom):
    for part in shapely.get_parts(geom):
        if part.geom_type == "Polygon":
            yield from (np.asarray(r.coords) for r in [part.exterior, *part.interiors])
        else:
            yield np.asarray(part.coords)


def save_preview(scene, path: str | os.PathLike, *, dpi: int = 80, cell: float | None = None) -> Path:
    """Write a two-panel PNG: image + projected truth, and the cloud's top height above terrain per ``cell``.

    Parameters
    ----------
    scene : Scene
        A simulated scene (with or without an image).
    path : path-like
        Output PNG (overwritten).
    dpi : int
        Resolution; the default keeps the file near 200 kB for the default scene.
    cell : float, optional
        Cell of the height raster of the right panel (m); default
        2 / sqrt(density), about two pulses per cell.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12.8, 6.6), dpi=dpi)
    axes = fig.subplots(1, 2)
    outlines = scene.truth["roof_outlines"].geometries
    ridges = scene.truth["ridges"]
    ax = axes[0]
    if scene.image is not None and scene.camera is not None:
        ax.imshow(np.transpose(scene.image, (1, 2, 0)), interpolation="nearest")
        for g in outlines:
            for xyz in _lines(g):
                cr = scene.camera.project(xyz)
                ax.plot(cr[:, 0], cr[:, 1], color="#00ffff", lw=0.8)
        for g, kind in zip(ridges.geometries, ridges.attributes["kind"]):
            cr = scene.camera.project(np.asarray(g.coords))
            ax.plot(cr[:, 0], cr[:, 1], color=_RIDGE_COLOURS.get(kind, "w"), lw=0.9)
        ax.set_title(f"aerial image ({scene.camera.kind}) with truth roof outlines and ridges", fontsize=10)
    else:
        ax.text(0.5, 0.5, "no image", ha="center", va="center", transform=ax.transAxes)
    ax.set_axis_off()
    ax = axes[1]
    x0, y0, x1, y1 = scene.options.bounds
    cell = cell or max(0.25, 2.0 / np.sqrt(scene.options.density))
    nx, ny = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    xyz = scene.cloud.xyz
    keep = scene.cloud.fields["truth_class"] != 7
    ix = np.clip(((xyz[keep, 0] - x0) / cell).astype(int), 0, nx - 1)
    iy = np.clip(((y1 - xyz[keep, 1]) / cell).astype(int), 0, ny - 1)
    top = np.full(ny * nx, np.nan)
    hag = xyz[keep, 2] - scene.terrain.height(xyz[keep, 0], xyz[keep, 1]) if scene.terrain is not None else xyz[keep, 2]
    order = np.argsort(hag)
    top[(iy * nx + ix)[order]] = hag[order]  # the highest point wins
    top = top.reshape(ny, nx)
    im = ax.imshow(top, extent=(x0, x1, y0, y1), cmap="viridis", vmin=0.0, vmax=14.0, interpolation="nearest")
    for g in outlines:
        for c in _lines(g):
            ax.plot(c[:, 0], c[:, 1], color="w", lw=0.6)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label="height above terrain (m)")
    ax.set_title(f"ALS: {len(scene.cloud):,} points, {scene.options.density:g} pts/m², seed {scene.options.seed}",
                 fontsize=10)
    ax.set_xticks([])
    ax.set_yticks([])
    fig.tight_layout()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgb = Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3])
    path = Path(path)
    # a 256-colour palette keeps the PNG small (the docs' copy must stay under 300 kB)
    rgb.quantize(colors=256, method=Image.Quantize.FASTOCTREE).save(path, format="PNG", optimize=True)
    return path
