"""Figure: LiDAR-only and image-refined roof outlines over the IGN orthophoto (issue 7, real data).

Usage (from the repository root)::

    .venv/bin/python benchmarks/fig_ign_refine.py [docs/images/ign_refine.png]

Runs ``rooftrace run`` on the IGN LiDAR HD tile 77055_627760 twice — without
and with ``--image test_data_rgb.tif --camera`` (an orthophoto camera file,
``{"type": "orthophoto"}``) — and draws both outline sets and the refined
ridges over the image.  Prints per building the refinement status and how
many sides took an image line.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

import _data

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import rasterio
import shapely

from rooftrace.io.vector import read_layer

ROOT = Path(__file__).resolve().parents[1]
IGN = _data.DATA / "ign_montpellier_lidarhd_bdortho"
RT = str(Path(sys.executable).with_name("rooftrace"))


def main(out: Path) -> None:
    laz, image = IGN / "test_data_77055_627760_LA93_IGN69.laz", IGN / "test_data_rgb.tif"
    with tempfile.TemporaryDirectory() as tmp:
        camera = Path(tmp) / "ortho.json"
        camera.write_text(json.dumps({"type": "orthophoto"}))
        lidar, refined = Path(tmp) / "lidar.gpkg", Path(tmp) / "refined.gpkg"
        subprocess.run([RT, "run", str(laz), "-o", str(lidar), "-q"], check=True)
        subprocess.run([RT, "run", str(laz), "--image", str(image), "--camera", str(camera), "-o", str(refined), "-q"],
                       check=True)
        before = read_layer(lidar, "roof_outlines")
        after = read_layer(refined, "roof_outlines")
        ridges = read_layer(refined, "ridges")
    with rasterio.open(image) as src:
        rgb = np.moveaxis(src.read(), 0, -1)
        left, bottom, right, top = src.bounds
    fig, ax = plt.subplots(figsize=(8, 8))
    ax.imshow(rgb, extent=(left, right, bottom, top))
    for geoms, style, label in ((before.geometries, dict(color="yellow", ls="--", lw=1.2), "LiDAR only"),
                                (after.geometries, dict(color="red", lw=1.4), "refined with the image")):
        for k, g in enumerate(geoms):
            for part in shapely.get_parts(g):
                ax.plot(*part.exterior.xy, **style, label=label if k == 0 else None)
    for k, r in enumerate(ridges.geometries):
        ax.plot(*np.asarray(r.coords)[:, :2].T, color="cyan", lw=1, label="ridges (refined)" if k == 0 else None)
    ax.set_xlim(left, right)
    ax.set_ylim(bottom, top)
    ax.set_title("IGN LiDAR HD + 20 cm orthophoto, Montpellier (EPSG:2154)")
    ax.legend(loc="lower left", fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90, bbox_inches="tight")
    a = after.attributes
    for i in range(len(after)):
        print(f"building {a['building_id'][i]}: {a['refine_status'][i]}, {a['n_refined'][i]} of {a['n_sides'][i]} "
              f"sides from image lines; area {before.geometries[i].area:.1f} -> {after.geometries[i].area:.1f} m²")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images" / "ign_refine.png")
