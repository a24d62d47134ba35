"""The evaluation report: PNG plots and one self-contained HTML page.

Plots (matplotlib, Agg canvas, no pyplot state): a scene map coloured by
PoLiS, histograms of PoLiS and Hausdorff, and per-building overlays of the
extracted and reference outlines over the LiDAR points (the worst buildings
by PoLiS, a few of the best, and a few missed ones). The HTML page embeds
every image as base64, so it can be mailed or archived as one file.
"""

from __future__ import annotations

import base64
import html
import io
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import shapely
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import PathPatch
from matplotlib.path import Path as MplPath
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.axes_grid1 import make_axes_locatable

from rooftrace.io.atomic import atomic_path

__all__ = ["write_report", "render_figures", "report_html", "FIGURES"]

log = logging.getLogger(__name__)

#: file name -> caption, in page order
FIGURES = {
    "scene_map.png": "Scene: extracted outlines coloured by PoLiS (m); reference in black, "
                     "missed reference buildings in red, false detections in orange.",
    "histograms.png": "Distribution of PoLiS and Hausdorff distances over the matched buildings.",
    "overlays.png": "Per building: reference (black) and extracted (red, dashed) outlines over the points, "
                    "ridges dotted. "
                    "The worst buildings by PoLiS first, then the best, then missed ones and false detections.",
}
_REF, _EXT, _MISS, _FP, _PTS = "#111111", "#d62728", "#e31a1c", "#ff7f00", "#8a9bb0"
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
    ax.set_title(f"{metrics.get('n_matched', 0)} matched, "
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


def _ridges_in(lines, bounds) -> list:
    if not lines:
        return []
    lines = np.asarray([g for g in lines if g is not None and not g.is_empty], dtype=object)
    return list(lines[shapely.intersects(lines, shapely.box(*bounds))]) if len(lines) else []


def _overlays(metrics, extracted, reference, points_xy, ridges=(None, None)) -> Figure | None:
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
        if e is not None:
            _outline(ax, e, color=_EXT, lw=1.4, ls="--")
        box_ = (x0 - pad, y0 - pad, x1 + pad, y1 + pad)
        for lines, colour, ls in ((ridges[1], _REF, ":"), (ridges[0], _EXT, ":")):
            for line in _ridges_in(lines, box_):
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


def render_figures(metrics: dict, extracted: Sequence, reference: Sequence, *, points_xy=None,
                   extracted_ridges: Sequence | None = None,
                   reference_ridges: Sequence | None = None) -> dict[str, bytes]:
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

    Returns
    -------
    dict of str to bytes
        File name -> PNG bytes, the keys of :data:`FIGURES` (no
        ``overlays.png`` when there is no building to show).
    """
    if points_xy is not None:
        points_xy = np.asarray(points_xy, dtype=float)
        if points_xy.ndim != 2 or points_xy.shape[1] < 2:
            raise ValueError(f"points_xy must have shape (N, 2), not {points_xy.shape}")
        points_xy = points_xy[:, :2]
    extracted, reference = list(extracted), list(reference)
    out = {"scene_map.png": _png(_scene_map(metrics, extracted, reference, points_xy)),
           "histograms.png": _png(_histograms(metrics))}
    fig = _overlays(metrics, extracted, reference, points_xy, (extracted_ridges, reference_ridges))
    if fig is not None:
        out["overlays.png"] = _png(fig)
    return out


# (key, label, unit) of the scene summary; unit "%" shows a 0–1 score as a percentage
_SUMMARY = (
    ("completeness", "Completeness (area)", "%"),
    ("correctness", "Correctness (area)", "%"),
    ("f_score", "F-score (area)", "%"),
    ("quality", "Quality, ISPRS (area)", "%"),
    ("object_completeness", "Completeness (objects)", "%"),
    ("object_correctness", "Correctness (objects)", "%"),
    ("polis_mean", "PoLiS mean", "m"),
    ("polis_median", "PoLiS median", "m"),
    ("polis_3d_mean", "PoLiS 3D mean", "m"),
    ("hausdorff_mean", "Hausdorff mean", "m"),
    ("hausdorff_max", "Hausdorff max", "m"),
    ("rmse_x", "RMSE x", "m"),
    ("rmse_y", "RMSE y", "m"),
    ("rmse_z", "RMSE z", "m"),
    ("n_reference", "Reference buildings", ""),
    ("n_extracted", "Extracted buildings", ""),
    ("n_matched", "Matched units", ""),
    ("n_reference_found", "Reference buildings found", ""),
    ("n_extracted_correct", "Extracted buildings correct", ""),
    ("ridge_completeness", "Ridge completeness", "%"),
    ("ridge_correctness", "Ridge correctness", "%"),
    ("ridge_position_error", "Ridge position error", "m"),
    ("n_ridges_reference", "Reference ridges", ""),
    ("n_ridges_extracted", "Extracted ridges", ""),
)
_COLUMNS = (("unit", "unit", ""), ("status", "status", ""), ("reference_ids", "reference", ""),
            ("extracted_ids", "extracted", ""), ("area_reference", "area ref (m²)", "a"),
            ("completeness", "compl.", "%"), ("correctness", "corr.", "%"), ("quality", "quality", "%"),
            ("polis", "PoLiS (m)", "m"), ("polis_3d", "PoLiS 3D (m)", "m"), ("hausdorff", "Hausdorff (m)", "m"),
            ("rmse_x", "RMSE x", "m"), ("rmse_y", "RMSE y", "m"), ("rmse_z", "RMSE z", "m"))
_MAX_ROWS = 500
_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:1150px;color:#222;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em} h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.9em}
td,th{padding:.25em .7em;border-bottom:1px solid #eee;text-align:right;white-space:nowrap}
th{background:#f4f5f7;position:sticky;top:0} td:first-child,th:first-child{text-align:left}
.summary td:first-child{font-weight:600} .note{color:#666;font-size:.9em}
.scroll{overflow-x:auto} .missed{color:#b30000} .false_positive{color:#c25e00}
figure{margin:1em 0} figure img{max-width:100%;border:1px solid #ddd} figcaption{color:#555;font-size:.9em}
"""


def _fmt(value, unit: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, list):
        return ", ".join(str(v) for v in value[:4]) + (" …" if len(value) > 4 else "")
    if unit == "%":
        return f"{100 * value:.1f}\u00a0%"
    if unit == "m":
        return f"{value:.3f}"
    if unit == "a":
        return f"{value:.1f}"
    return html.escape(str(value))


def report_html(metrics: dict, images: dict[str, bytes], *, title: str = "rooftrace evaluation") -> str:
    """The report page as one HTML string, images embedded as base64 PNG.

    Parameters
    ----------
    metrics : dict
        The output of :func:`rooftrace.evaluate.evaluate`.
    images : dict of str to bytes
        File name -> PNG bytes (see :func:`render_figures`); captions from
        :data:`FIGURES`.
    title : str
    """
    esc = html.escape
    rows = "".join(
        f"<tr><td>{esc(label)}</td><td>{_fmt(metrics[key], unit)}{' m' if unit == 'm' and metrics[key] is not None else ''}"
        f"</td></tr>"
        for key, label, unit in _SUMMARY if key in metrics)
    rule = esc(str(metrics.get("matching_rule_description", metrics.get("matching_rule", ""))))
    aoi = metrics.get("aoi_area")
    figs = "".join(
        f'<figure><img alt="{esc(name)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'
        f"<figcaption>{esc(FIGURES.get(name, name))}</figcaption></figure>"
        for name, png in images.items())
    units = list(metrics.get("buildings", []))
    units.sort(key=lambda b: (b["status"] != "matched", -(b["polis"] if b["polis"] is not None else -1), b["unit"]))
    shown = units[:_MAX_ROWS]
    head = "".join(f"<th>{esc(label)}</th>" for _, label, _ in _COLUMNS)
    body = "".join(
        f'<tr class="{esc(b["status"])}">' + "".join(f"<td>{_fmt(b.get(key), unit)}</td>" for key, _, unit in _COLUMNS)
        + "</tr>" for b in shown)
    more = (f'<p class="note">Showing the {len(shown)} worst of {len(units)} units; all are in metrics.json.</p>'
            if len(units) > len(shown) else "")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_CSS}</style></head>
<body>
<h1>{esc(title)}</h1>
<p class="note">Area scores after Wiedemann et al. (1998) and the ISPRS quality; PoLiS after Avbelj et al. (2015);
RMSE of reference vertices against their closest points on the extracted outline. Matching rule: {rule}.
{f"Area of interest: {aoi:.1f} m²." if aoi else ""}</p>
<h2>Summary</h2>
<table class="summary">{rows}</table>
<h2>Figures</h2>
{figs or '<p class="note">No figures.</p>'}
<h2>Buildings</h2>
{more}
<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>
</body></html>
"""


def write_report(
    out_dir: str | os.PathLike,
    metrics: dict,
    extracted: Sequence,
    reference: Sequence,
    *,
    points_xy=None,
    title: str = "rooftrace evaluation",
    extracted_ridges: Sequence | None = None,
    reference_ridges: Sequence | None = None,
    overwrite: bool = True,
) -> Path:
    """Write the PNG figures and ``report.html`` into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Created when missing. Files are written atomically.
    metrics : dict
        The output of :func:`rooftrace.evaluate.evaluate` on ``extracted``
        and ``reference``.
    extracted, reference : sequence of Polygon/MultiPolygon
    points_xy : ndarray of shape (N, 2), optional
        LiDAR points (x, y) drawn under the outlines.
    title : str, default "rooftrace evaluation"
    extracted_ridges, reference_ridges : sequence of LineString, optional
        Ridge lines drawn (dotted) on the per-building overlays.
    overwrite : bool, default True
        Replace existing report files; the caller decides whether the
        folder may be reused (the CLI refuses when ``metrics.json`` exists).

    Returns
    -------
    Path
        The path of ``report.html``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    images = render_figures(metrics, extracted, reference, points_xy=points_xy,
                            extracted_ridges=extracted_ridges, reference_ridges=reference_ridges)
    for name, png in images.items():
        with atomic_path(out / name, overwrite) as tmp:
            tmp.write_bytes(png)
    page = out / "report.html"
    with atomic_path(page, overwrite) as tmp:
        tmp.write_text(report_html(metrics, images, title=title), encoding="utf-8")
    log.info("wrote %s", page)
    return page
