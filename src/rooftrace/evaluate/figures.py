"""The figures of the evaluation report, as PNG bytes.

Plots (matplotlib, Agg canvas, no pyplot state): a scene map coloured by
PoLiS, histograms of PoLiS and Hausdorff, per-building overlays of the
extracted and reference outlines over the LiDAR points (the worst buildings
by PoLiS, a few of the best, and a few missed ones), and, with an image and
its camera, the outlines projected into the image: the whole scene and
close-ups of the buildings where a second extracted set (e.g. the LiDAR-only
outlines) differs most.  Re-exported by :mod:`rooftrace.evaluate.report`,
which embeds them in the HTML page.
"""

from __future__ import annotations

import io
import logging
import math
from collections.abc import Sequence

import numpy as np
import shapely
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import PathPatch
from matplotlib.path import Path as MplPath
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.axes_grid1 import make_axes_locatable

__all__ = ["render_figures", "FIGURES"]

log = logging.getLogger(__name__)

#: file name -> caption, in page order
FIGURES = {
    "scene_map.png": "Scene: extracted outlines coloured by PoLiS (m); reference in black, "
                     "missed reference buildings in red, false detections in orange.",
    "histograms.png": "Distribution of PoLiS and Hausdorff distances over the matched buildings.",
    "overlays.png": "Per building: reference (black) and extracted (red, dashed) outlines over the points, "
                    "ridges dotted; with a second extracted set, its outlines in blue (dotted). "
                    "The worst buildings by PoLiS first, then the best, then missed ones and false detections.",
    "models_3d.png": "3D models (LoD 2.2, else the best level built) of the largest buildings: roofs red, "
                     "walls grey, seen from the south-west.",
    "image.png": "The image with the outlines projected into it by its camera: reference (yellow), "
                 "the second extracted set (cyan, dashed) and the extracted outlines (red). The whole scene, "
                 "then close-ups of the buildings whose PoLiS differs most between the two sets, then the worst.",
}
_REF, _EXT, _MISS, _FP, _PTS = "#111111", "#d62728", "#e31a1c", "#ff7f00", "#8a9bb0"
_CMP = "#1f5fbf"
# on an image: colours that stay visible on dark and bright roofs alike
_IMG_REF, _IMG_CMP, _IMG_EXT = "#ffd400", "#00d5ff", "#ff2d55"
_MAX_IMAGE_PX = 1400
_N_CLOSEUPS = 8
_MAX_POINTS_MAP = 300_000
_N_WORST, _N_BEST, _N_MISSED = 12, 4, 4


def _path(geom) -> MplPath:
    """A matplotlib path of a (Multi)Polygon, holes included (even-odd fill)."""
    paths = []
    for ring in shapely.get_rings(shapely.get_parts(geom)):
        xy = shapely.get_coordinates(ring)
        codes = np.full(len(xy), MplPath.LINETO, dtype=np.uint8)
        codes[0], codes[-1] = MplPath.MOVETO, MplPath.CLOSEPOLY
        paths.append(MplPath(xy, codes))
    return MplPath.make_compound_path(*paths)


def _union(geoms, idx):
    parts = [geoms[i] for i in idx if geoms[i] is not None and not geoms[i].is_empty]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else shapely.union_all(parts)


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    FigureCanvasAgg(fig)
    # no timestamps in the PNG, so the same metrics give the same bytes
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight", metadata={"Software": None})
    return buf.getvalue()


def _outline(ax, geom, **kw) -> None:
    for ring in shapely.get_rings(shapely.get_parts(geom)):
        xy = shapely.get_coordinates(ring)
        ax.plot(xy[:, 0], xy[:, 1], **kw)


def _scene_map(metrics, extracted, reference, points_xy) -> Figure:
    geoms = [g for g in (*extracted, *reference) if g is not None and not g.is_empty]
    x0, y0, x1, y1 = shapely.total_bounds(geoms) if geoms else (0.0, 0.0, 1.0, 1.0)
    # the figure follows the scene's shape so that the map fills it
    height = float(np.clip(9.0 * (y1 - y0) / max(x1 - x0, 1e-9), 3.0, 10.0)) + 1.0
    fig = Figure(figsize=(10, height))
    ax = fig.add_subplot()
    if points_xy is not None and len(points_xy):
        step = max(1, len(points_xy) // _MAX_POINTS_MAP)
        ax.scatter(points_xy[::step, 0], points_xy[::step, 1], s=0.2, c=_PTS, alpha=0.4, linewidths=0,
                   rasterized=True)
    units = metrics.get("buildings", [])
    matched = [b for b in units if b["status"] == "matched"]
    values = np.array([b["polis"] if b["polis"] is not None else np.nan for b in matched], dtype=float)
    vmax = float(np.nanpercentile(values, 95)) if np.isfinite(values).any() else 1.0
    patches = [_path(_union(extracted, b["extracted_index"])) for b in matched]
    if patches:
        coll = PatchCollection([PathPatch(p) for p in patches], cmap="viridis_r", alpha=0.85, linewidths=0)
        coll.set_array(values)
        coll.set_clim(0.0, max(vmax, 1e-3))
        ax.add_collection(coll)
        cax = make_axes_locatable(ax).append_axes("right", size="2.5%", pad=0.15)
        fig.colorbar(coll, cax=cax, label="PoLiS (m)", extend="max")
    fps = [_path(_union(extracted, b["extracted_index"])) for b in units if b["status"] == "false_positive"]
    if fps:
        ax.add_collection(PatchCollection([PathPatch(p) for p in fps], facecolor=_FP, alpha=0.7, linewidths=0))
    for b in units:
        r = _union(reference, b["reference_index"])
        if r is not None:
            missed = b["status"] == "missed"
            _outline(ax, r, color=_MISS if missed else _REF, lw=1.4 if missed else 0.6)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    merged = sum(b["status"] == "matched" and (len(b["reference_ids"]) > 1 or len(b["extracted_ids"]) > 1)
                 for b in units)
    ax.set_title(f"{metrics.get('n_reference', 0)} reference, {metrics.get('n_extracted', 0)} extracted buildings: "
                 f"{metrics.get('n_matched', 0)} matched units ({merged} merged block{'' if merged == 1 else 's'}), "
                 f"{sum(b['status'] == 'missed' for b in units)} missed, "
                 f"{sum(b['status'] == 'false_positive' for b in units)} false detections")
    return fig


def _histograms(metrics) -> Figure:
    fig = Figure(figsize=(9, 3.4))
    matched = [b for b in metrics.get("buildings", []) if b["status"] == "matched"]
    for k, (key, label) in enumerate((("polis", "PoLiS (m)"), ("hausdorff", "Hausdorff (m)"))):
        ax = fig.add_subplot(1, 2, k + 1)
        v = np.array([b[key] for b in matched if b[key] is not None], dtype=float)
        if len(v):
            ax.hist(v, bins=min(40, max(5, int(np.sqrt(len(v))) * 2)), color="#3b75af", edgecolor="white")
            ax.axvline(float(v.mean()), color=_EXT, lw=1.2, label=f"mean {v.mean():.3f} m")
            ax.legend(frameon=True, loc="upper right")
            ax.set_xlim(left=0.0)  # distances: the axis starts at zero
        else:
            ax.text(0.5, 0.5, "no matched buildings", ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel(label)
        ax.set_ylabel("buildings")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    fig.tight_layout()
    return fig


def _pick(metrics) -> list[dict]:
    units = metrics.get("buildings", [])
    matched = [b for b in units if b["status"] == "matched" and b["polis"] is not None]
    matched.sort(key=lambda b: (-b["polis"], b["unit"]))
    worst = matched[:_N_WORST]
    best = matched[_N_WORST:][-_N_BEST:][::-1]
    missed = [b for b in units if b["status"] == "missed"][:_N_MISSED]
    false = [b for b in units if b["status"] == "false_positive"][:_N_MISSED]
    return worst + best + missed + false


def _within(geoms, bounds) -> list:
    """The geometries (lines or polygons) that reach into a box."""
    if not geoms:
        return []
    geoms = np.asarray([g for g in geoms if g is not None and not g.is_empty], dtype=object)
    return list(geoms[shapely.intersects(geoms, shapely.box(*bounds))]) if len(geoms) else []


def _overlays(metrics, extracted, reference, points_xy, ridges=(None, None), compare=None) -> Figure | None:
    chosen = _pick(metrics)
    if not chosen:
        return None
    ncol = 4
    nrow = math.ceil(len(chosen) / ncol)
    fig = Figure(figsize=(3.2 * ncol, 3.3 * nrow))
    for k, b in enumerate(chosen):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        r = _union(reference, b["reference_index"])
        e = _union(extracted, b["extracted_index"])
        geoms = [g for g in (r, e) if g is not None]
        x0, y0, x1, y1 = shapely.total_bounds(geoms)
        pad = 0.15 * max(x1 - x0, y1 - y0, 1.0)
        if points_xy is not None and len(points_xy):
            inside = ((points_xy[:, 0] >= x0 - pad) & (points_xy[:, 0] <= x1 + pad)
                      & (points_xy[:, 1] >= y0 - pad) & (points_xy[:, 1] <= y1 + pad))
            ax.scatter(points_xy[inside, 0], points_xy[inside, 1], s=1.5, c=_PTS, linewidths=0, rasterized=True)
        if r is not None:
            _outline(ax, r, color=_REF, lw=1.6)
        box_ = (x0 - pad, y0 - pad, x1 + pad, y1 + pad)
        for other in _within(compare, box_):
            _outline(ax, other, color=_CMP, lw=1.3, ls=":")
        if e is not None:
            _outline(ax, e, color=_EXT, lw=1.4, ls="--")
        for lines, colour, ls in ((ridges[1], _REF, ":"), (ridges[0], _EXT, ":")):
            for line in _within(lines, box_):
                for part in shapely.get_parts(line):
                    xy = shapely.get_coordinates(part)
                    ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.2, ls=ls)
        ax.set_xlim(x0 - pad, x1 + pad)
        ax.set_ylim(y0 - pad, y1 + pad)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        side, label = ("extracted_ids", "ext") if b["status"] == "false_positive" else ("reference_ids", "ref")
        ids = ",".join(str(i) for i in b[side][:3]) + ("…" if len(b[side]) > 3 else "")
        if b["status"] == "matched":
            ax.set_title(f"ref {ids}\nPoLiS {b['polis']:.2f} m · H {b['hausdorff']:.2f} m · Q {b['quality']:.0%}",
                         fontsize=8)
        elif b["status"] == "missed":
            ax.set_title(f"ref {ids}\nmissed", fontsize=8, color=_MISS)
        else:
            ax.set_title(f"{label} {ids}\nfalse detection", fontsize=8, color=_FP)
    fig.tight_layout()
    return fig


_SURFACE_COLOURS = {"RoofSurface": "#c0392b", "WallSurface": "#d5d8dc", "GroundSurface": "#7f8c8d"}


def _models_view(models: Sequence, n: int = 4) -> Figure | None:
    """The ``n`` largest buildings' solids in 3D, one panel each (the scene would be too flat to read)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from rooftrace.model.types import LODS

    def best(m):
        return [p.lods[next(k for k in LODS[::-1] if k in p.lods)] for p in m.parts if p.lods]

    shown = sorted((m for m in models if best(m)), key=lambda m: -sum(p.footprint.area for p in m.parts))[:n]
    if not shown:
        return None
    fig = Figure(figsize=(3.4 * len(shown), 3.6))
    for i, m in enumerate(shown):
        ax = fig.add_subplot(1, len(shown), i + 1, projection="3d")
        faces, colours = [], []
        for solid in best(m):
            for s in solid.surfaces:
                faces.append(s.rings[0])
                colours.append(_SURFACE_COLOURS[s.kind])
        xyz = np.vstack(faces)
        low, high = xyz.min(axis=0), xyz.max(axis=0)
        # the limits are set below: matplotlib's own autoscale reads the padding of its ragged face array,
        # which is uninitialised memory, and failed the report now and then on NaN limits
        ax.add_collection3d(Poly3DCollection([f - low for f in faces], facecolors=colours, edgecolors="#333333",
                                             linewidths=0.2), autolim=False)
        span = float((high - low).max())
        ax.set_xlim(0, span)
        ax.set_ylim(0, span)
        ax.set_zlim(0, span)
        ax.view_init(elev=30, azim=-120)
        ax.set_axis_off()
        ax.set_title(f"building {m.building_id}", fontsize=9)
    return fig


def _raster(image) -> tuple[np.ndarray, float, dict]:
    """An image as an (H, W) grey or (H, W, 3) RGB view, the divisor mapping it to [0, 1], the imshow keywords.

    Only views: the pixels shown are converted where they are drawn, so a
    large orthophoto is never copied whole.
    """
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[0] <= 4 < a.shape[2]:  # bands first, as rasterio reads them
        a = np.moveaxis(a, 0, -1)
    if a.ndim == 3:
        a = a[..., :3] if a.shape[2] >= 3 else a[..., 0]
    if a.ndim != 2 and not (a.ndim == 3 and a.shape[2] == 3):
        raise ValueError(f"image must be (H, W), (H, W, 3) or (bands, H, W), not {np.shape(image)}")
    scale = 1.0
    if a.dtype == np.uint8:
        scale = 255.0
    elif a.size:
        # 16-bit and float images seldom use their type's range (12-bit sensors, reflectances): stretch
        sample = a[::max(1, a.shape[0] // 512), ::max(1, a.shape[1] // 512)].astype(np.float64)
        top = float(np.nanpercentile(sample, 99.5))
        if top > 1.0 or (np.issubdtype(a.dtype, np.integer) and top > 0):  # floats in [0, 1] stay
            scale = top
    return a, scale, ({"cmap": "gray", "vmin": 0.0, "vmax": 1.0} if a.ndim == 2 else {})


def _pixel_rings(camera, geom) -> list[np.ndarray]:
    """Rings of a (Multi)Polygon projected to (column, row); a ring that does not project is left out.

    A 2D ring has no height, so a frame camera cannot place it (NaN); an
    orthophoto's camera ignores z and places it.
    """
    if geom is None or geom.is_empty:
        return []
    out = []
    for ring in shapely.get_rings(shapely.get_parts(geom)):
        cr = camera.project(shapely.get_coordinates(ring, include_z=True))
        if len(cr) and np.isfinite(cr).all():
            out.append(cr)
    return out


def _image_panel(ax, img, scale, kw, window, layers) -> None:
    """Draw the image inside ``window`` (c0, r0, c1, r1; pixels), subsampled to fit, and the rings over it."""
    h, w = img.shape[:2]
    c0, r0 = max(0, int(math.floor(window[0]))), max(0, int(math.floor(window[1])))
    c1, r1 = min(w, int(math.ceil(window[2])) + 1), min(h, int(math.ceil(window[3])) + 1)
    if c1 > c0 and r1 > r0:
        step = max(1, int(math.ceil(max(c1 - c0, r1 - r0) / _MAX_IMAGE_PX)))
        piece = np.clip(img[r0:r1:step, c0:c1:step].astype(np.float64) / scale, 0.0, 1.0)
        ax.imshow(piece, extent=(c0 - 0.5, c1 - 0.5, r1 - 0.5, r0 - 0.5),
                  interpolation="nearest" if step == 1 else "antialiased", **kw)
    for rings, colour, ls, lw in layers:
        for cr in rings:
            ax.plot(cr[:, 0], cr[:, 1], color=colour, ls=ls, lw=lw)
    ax.set_xlim(window[0], window[2])
    ax.set_ylim(window[3], window[1])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _window(rings: list[np.ndarray], pad: float, min_pad: float) -> tuple[float, float, float, float] | None:
    if not rings:
        return None
    xy = np.concatenate(rings)
    (c0, r0), (c1, r1) = xy.min(axis=0), xy.max(axis=0)
    p = max(pad * max(c1 - c0, r1 - r0), min_pad)
    return c0 - p, r0 - p, c1 + p, r1 + p


def _closeups(metrics, compare_metrics) -> list[tuple[dict, dict | None]]:
    """Matched units to show up close: the largest PoLiS changes between the two sets, then the worst."""
    matched = [b for b in metrics.get("buildings", []) if b["status"] == "matched" and b["polis"] is not None]
    other = {}
    for b in (compare_metrics or {}).get("buildings", []):
        if b["status"] == "matched" and b["polis"] is not None:
            other[frozenset(b["reference_index"])] = b
    pairs = [(b, other.get(frozenset(b["reference_index"]))) for b in matched]
    changed = sorted((p for p in pairs if p[1] is not None), key=lambda p: (-abs(p[1]["polis"] - p[0]["polis"]),
                                                                        p[0]["unit"]))
    chosen = changed[:_N_CLOSEUPS // 2]
    seen = {p[0]["unit"] for p in chosen}
    for p in sorted(pairs, key=lambda p: (-p[0]["polis"], p[0]["unit"])):
        if len(chosen) >= _N_CLOSEUPS:
            break
        if p[0]["unit"] not in seen:
            chosen.append(p)
            seen.add(p[0]["unit"])
    return chosen


def _image_figure(metrics, image, camera, extracted, reference, compare=None, compare_metrics=None,
                  labels=("extracted", "compared")) -> Figure | None:
    img, scale, kw = _raster(image)
    ext_rings = [_pixel_rings(camera, g) for g in extracted]
    ref_rings = [_pixel_rings(camera, g) for g in reference]
    cmp_rings = [_pixel_rings(camera, g) for g in (compare or [])]
    every = [r for rings in (*ext_rings, *ref_rings, *cmp_rings) for r in rings]
    h, w = img.shape[:2]
    inside = [r for r in every if (r[:, 0].max() >= 0 and r[:, 0].min() <= w - 1
                                   and r[:, 1].max() >= 0 and r[:, 1].min() <= h - 1)]
    if not inside:
        return None
    scene = _window(inside, 0.03, 5.0)
    scene = (max(scene[0], -0.5), max(scene[1], -0.5), min(scene[2], w - 0.5), min(scene[3], h - 0.5))
    chosen = _closeups(metrics, compare_metrics)
    ncol = 4
    nrow = math.ceil(len(chosen) / ncol)
    aspect = (scene[3] - scene[1]) / max(scene[2] - scene[0], 1e-9)
    top = float(np.clip(12.0 * aspect, 4.0, 11.0))
    fig = Figure(figsize=(12, top + 3.2 * nrow))
    grid = fig.add_gridspec(1 + nrow, ncol, height_ratios=[top] + [3.2] * nrow)
    ax = fig.add_subplot(grid[0, :])
    flat = lambda groups: [r for rings in groups for r in rings]  # noqa: E731
    _image_panel(ax, img, scale, kw, scene, [(flat(ref_rings), _IMG_REF, "-", 0.9), (flat(cmp_rings), _IMG_CMP, "--", 0.9),
                                      (flat(ext_rings), _IMG_EXT, "-", 0.9)])
    handles = [ax.plot([], [], color=c, ls=ls, label=lab)[0]
               for c, ls, lab in ((_IMG_REF, "-", "reference"), (_IMG_CMP, "--", labels[1]),
                                  (_IMG_EXT, "-", labels[0])) if lab != labels[1] or compare is not None]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False, fontsize=9)
    for k, (b, o) in enumerate(chosen):
        ax = fig.add_subplot(grid[1 + k // ncol, k % ncol])
        ref_u = [r for i in b["reference_index"] for r in ref_rings[i]]
        ext_u = [r for i in b["extracted_index"] for r in ext_rings[i]]
        cmp_u = [r for i in (o["extracted_index"] if o is not None else []) for r in cmp_rings[i]]
        win = _window(ref_u + ext_u, 0.12, 6.0)
        if win is None:
            ax.set_axis_off()
            continue
        _image_panel(ax, img, scale, kw, win, [(ref_u, _IMG_REF, "-", 1.4), (cmp_u, _IMG_CMP, "--", 1.4),
                                        (ext_u, _IMG_EXT, "-", 1.4)])
        ids = ",".join(str(i) for i in b["reference_ids"][:3]) + ("…" if len(b["reference_ids"]) > 3 else "")
        change = f"{o['polis']:.2f} → {b['polis']:.2f} m" if o is not None else f"{b['polis']:.2f} m"
        ax.set_title(f"ref {ids} · PoLiS {change}", fontsize=8)
    fig.tight_layout()
    return fig


def render_figures(metrics: dict, extracted: Sequence, reference: Sequence, *, points_xy=None,
                   extracted_ridges: Sequence | None = None,
                   reference_ridges: Sequence | None = None,
                   compare: Sequence | None = None, compare_metrics: dict | None = None,
                   image=None, camera=None,
                   labels: tuple[str, str] = ("extracted", "compared"),
                   models: Sequence | None = None) -> dict[str, bytes]:
    """PNG images of the report.

    Parameters
    ----------
    metrics : dict
        The output of :func:`rooftrace.evaluate.evaluate` (its ``buildings``
        records index into ``extracted`` and ``reference``).
    extracted, reference : sequence of Polygon/MultiPolygon
        The same sequences that were evaluated.
    points_xy : ndarray of shape (N, 2) float64, optional
        LiDAR points drawn under the outlines (subsampled on the scene map).
    extracted_ridges, reference_ridges : sequence of LineString, optional
        Drawn dotted on the per-building overlays.
    compare : sequence of Polygon/MultiPolygon, optional
        A second extracted set (e.g. the LiDAR-only outlines of a run with
        an image), drawn on the overlays and the image.
    compare_metrics : dict, optional
        Its evaluation against the same reference; the image close-ups show
        the buildings whose PoLiS changes most between the two sets.
    image : ndarray, optional
        (H, W) grey, (H, W, 3) or (bands, H, W); 8 bits as they are, other
        types stretched to their 99.5th percentile.
    camera : FrameCamera or OrthoCamera, optional
        Anything with ``project(xyz) -> (column, row)``; needed with ``image``.
        A frame camera places only 3D outlines.
    labels : (str, str)
        Names of the extracted and the compared set in legends.
    models : sequence of BuildingModel, optional
        3D models; the largest are drawn in ``models_3d.png``.

    Returns
    -------
    dict of str to bytes
        File name -> PNG bytes, the keys of :data:`FIGURES` (no
        ``overlays.png`` when there is no building to show, no
        ``image.png`` without image and camera or when no outline falls
        inside the image).
    """
    if points_xy is not None:
        points_xy = np.asarray(points_xy, dtype=float)
        if points_xy.ndim != 2 or points_xy.shape[1] < 2:
            raise ValueError(f"points_xy must have shape (N, 2), not {points_xy.shape}")
        points_xy = points_xy[:, :2]
    extracted, reference = list(extracted), list(reference)
    out = {"scene_map.png": _png(_scene_map(metrics, extracted, reference, points_xy)),
           "histograms.png": _png(_histograms(metrics))}
    if (image is None) != (camera is None):
        raise ValueError("image and camera go together")
    compare = list(compare) if compare is not None else None
    if image is not None:
        fig = _image_figure(metrics, image, camera, extracted, reference, compare, compare_metrics, labels)
        if fig is not None:
            out["image.png"] = _png(fig)
        else:
            log.warning("no outline falls inside the image; the report shows no image (a frame camera "
                        "places only 3D outlines)")
    fig = _overlays(metrics, extracted, reference, points_xy, (extracted_ridges, reference_ridges), compare)
    if fig is not None:
        out["overlays.png"] = _png(fig)
    fig = _models_view(models) if models else None
    if fig is not None:
        out["models_3d.png"] = _png(fig)
    return out
