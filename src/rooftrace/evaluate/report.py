"""The evaluation report: PNG plots and one self-contained HTML page.

The plots (a scene map coloured by PoLiS, histograms of PoLiS and
Hausdorff, per-building overlays) are drawn by
:mod:`rooftrace.evaluate.figures`. The HTML page embeds every image as
base64, so it can be mailed or archived as one file.
"""

from __future__ import annotations

import base64
import html
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path

from rooftrace.evaluate.figures import FIGURES, render_figures
from rooftrace.io.atomic import atomic_path

__all__ = ["write_report", "render_figures", "report_html", "FIGURES"]

log = logging.getLogger(__name__)

# (key, label, unit) of the scene summary; unit "%" shows a 0–1 score as a percentage
_SUMMARY = (
    ("completeness", "Completeness (area)", "%"),
    ("correctness", "Correctness (area)", "%"),
    ("f_score", "F-score (area)", "%"),
    ("quality", "Quality, ISPRS (area)", "%"),
    ("fn_area", "Missed area, FN (m²)", "a"),
    ("fp_area", "Extra area, FP (m²)", "a"),
    ("fn_area_boundary", "of it within the boundary band: FN (m²)", "a"),
    ("fp_area_boundary", "of it within the boundary band: FP (m²)", "a"),
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
    ("corner_ratio_median", "Corner count ratio, median (extracted / reference)", "x"),
    ("corner_ratio_within_1_5", "Units with a corner ratio within 1.5×", "%"),
    ("corner_completeness", "Corner completeness", "%"),
    ("corner_correctness", "Corner correctness", "%"),
    ("corner_offset_mean", "Corner offset, mean", "m"),
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
            ("n_corners", "corners", ""), ("n_corners_reference", "ref. corners", ""),
            ("corner_completeness", "corner compl.", "%"), ("corner_correctness", "corner corr.", "%"),
            ("corner_offset", "corner offset (m)", "m"),
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
    if unit == "x":
        return f"{value:.2f}×"
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
RMSE of reference vertices against their closest points on the extracted outline. Corners are the vertices
where an outline turns (vertices within 2&nbsp;cm of their neighbours' line and vertices along curves set aside),
matched one-to-one within {_fmt(metrics.get("corner_tolerance"), "m")}&nbsp;m. Matching rule: {rule}.
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
