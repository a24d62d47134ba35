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

__all__ = ["write_report", "render_figures", "report_html", "unit_sentence", "FIGURES"]

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
    ("n_matched", "Matched units (one to one or merged blocks)", ""),
    ("n_matched_merged", "of them merged blocks", ""),
    ("n_reference_in_merged", "Reference buildings in merged blocks", ""),
    ("n_extracted_in_merged", "Extracted buildings in merged blocks", ""),
    ("n_missed", "Reference buildings missed", ""),
    ("n_false_positive", "False detections (extracted, unmatched)", ""),
    ("n_reference_found", "Reference buildings found (area ≥ overlap threshold)", ""),
    ("n_extracted_correct", "Extracted buildings correct (area ≥ overlap threshold)", ""),
    ("ridge_completeness", "Ridge completeness", "%"),
    ("ridge_correctness", "Ridge correctness", "%"),
    ("ridge_position_error", "Ridge position error", "m"),
    ("n_ridges_reference", "Reference ridges", ""),
    ("n_ridges_extracted", "Extracted ridges", ""),
)
# the building table, compact enough for the page: (header, cell function, unit, metric key); pairs
# of shares share a column ("98.5 / 99.7"); a column whose cells are all empty (no z) is left out
_COLUMNS = (
    ("unit", lambda b: b["unit"], "", "unit"),
    ("status", lambda b: b["status"].replace("_", " "), "", "status"),
    ("reference → extracted", lambda b: _ids(b), "ids", "reference_ids"),
    ("area ref. (m²)", lambda b: b["area_reference"], "a", "area_reference"),
    ("compl. / corr. (%)", lambda b: (b["completeness"], b["correctness"]), "%/", "completeness"),
    ("quality (%)", lambda b: b["quality"], "%.", "quality"),
    ("PoLiS (m)", lambda b: b["polis"], "m", "polis"),
    ("PoLiS 3D (m)", lambda b: b["polis_3d"], "m", "polis_3d"),
    ("Haus\u00addorff (m)", lambda b: b["hausdorff"], "m", "hausdorff"),
    ("RMSE xy (m)", lambda b: _hypot(b.get("rmse_x"), b.get("rmse_y")), "m", "rmse_x"),
    ("RMSE z (m)", lambda b: b["rmse_z"], "m", "rmse_z"),
    ("corners ext. / ref.", lambda b: _corner_counts(b), "", "n_corners"),
    ("corner compl. / corr. (%)", lambda b: (b.get("corner_completeness"), b.get("corner_correctness")), "%/",
     "n_corners"),
    ("corner offset (m)", lambda b: b.get("corner_offset"), "m", "n_corners"),
)
_MAX_ROWS = 500
_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:1150px;color:#222;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em} h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.9em}
td,th{padding:.25em .7em;border-bottom:1px solid #eee;text-align:right;white-space:nowrap}
th{background:#f4f5f7;position:sticky;top:0} td:first-child,th:first-child{text-align:left}
.summary td:first-child{font-weight:600} .summary th{text-align:right} .note{color:#666;font-size:.9em}
.counts{font-size:1.05em}
table.units{width:100%;font-size:.8em} .units td,.units th{padding:.2em .35em}
@media (max-width:1000px){table.units{font-size:.68em} .units td,.units th{padding:.15em .2em}}
.units th{white-space:normal;vertical-align:bottom;hyphens:auto}
.units th.ids{text-align:left} .units td.ids{white-space:normal;text-align:left;max-width:14em;overflow-wrap:anywhere}
.missed{color:#b30000} .false_positive{color:#c25e00}
figure{margin:1em 0} figure img{max-width:100%;border:1px solid #ddd} figcaption{color:#555;font-size:.9em}
"""


def _fmt(value, unit: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, list):
        return ", ".join(str(v) for v in value[:4]) + (" …" if len(value) > 4 else "")
    if unit == "%/":  # two shares in one cell, the unit in the header
        return " / ".join(_fmt(v, "%.") for v in value)
    if unit == "%.":
        return f"{100 * value:.1f}"
    if unit == "%":
        return f"{100 * value:.1f}\u00a0%"
    if unit == "m":
        return f"{value:.3f}"
    if unit == "x":
        return f"{value:.2f}×"
    if unit == "a":
        return f"{value:.1f}"
    return html.escape(str(value))


def _ids(b: dict) -> str:
    def few(ids):
        return ", ".join(str(i) for i in ids[:6]) + (" …" if len(ids) > 6 else "") if ids else "–"
    return f"{few(b['reference_ids'])} → {few(b['extracted_ids'])}"


def _hypot(x, y):
    return None if x is None or y is None else math.hypot(x, y)


def _corner_counts(b: dict):
    if b.get("n_corners") is None:
        return None
    return f"{b['n_corners']} / {b['n_corners_reference']}"


def _plural(n: int, word: str) -> str:
    return f"{n} {word if n == 1 else word + 's'}"


def unit_sentence(metrics: dict) -> str:
    """How the buildings were matched, in words: units, merged blocks and what each merged.

    Examples
    --------
    >>> from shapely import box
    >>> from rooftrace.evaluate import evaluate
    >>> m = evaluate([box(0, 0, 20, 10), box(30, 0, 40, 10)], [box(0, 0, 10, 10), box(10, 0, 20, 10)])
    >>> print(unit_sentence(m))  # doctest: +NORMALIZE_WHITESPACE
    2 reference and 2 extracted buildings: 1 matched unit, a merged block (2 reference buildings into
    1 extracted); 0 reference buildings missed, 1 false detection.
    """
    units = metrics.get("buildings", [])
    n_ref, n_ext, n_matched = metrics.get("n_reference", 0), metrics.get("n_extracted", 0), metrics.get("n_matched", 0)
    shapes: dict[tuple[int, int], int] = {}
    for b in units:
        if b["status"] == "matched" and (len(b["reference_ids"]) > 1 or len(b["extracted_ids"]) > 1):
            key = (len(b["reference_ids"]), len(b["extracted_ids"]))
            shapes[key] = shapes.get(key, 0) + 1
    one = n_matched - sum(shapes.values())
    parts = []
    if one:
        parts.append(f"{one} one to one" if shapes else ("all one to one" if n_matched > 1 else ""))
    for (nr, ne), k in sorted(shapes.items(), key=lambda kv: (-kv[0][0], -kv[0][1])):
        what = f"{nr} reference buildings into {ne} extracted" if nr > 1 else \
            f"1 reference building split into {ne} extracted"
        parts.append(f"{'a merged block' if k == 1 else f'{k} merged blocks'} ({what}{'' if k == 1 else ' each'})")
    parts = [p for p in parts if p]
    detail = ", ".join(parts[:-1]) + " and " + parts[-1] if len(parts) > 1 else "".join(parts)
    return (f"{n_ref} reference and {n_ext} extracted buildings: {_plural(n_matched, 'matched unit')}"
            f"{', ' + detail if detail else ''}; "
            f"{_plural(metrics.get('n_missed', 0), 'reference building')} missed, "
            f"{_plural(metrics.get('n_false_positive', 0), 'false detection')}.")


def _units_table(units: list[dict]) -> str:
    esc = html.escape
    cols = [c for c in _COLUMNS
            if any(b.get(c[3]) not in (None, [], "") and not (isinstance(b.get(c[3]), float)
                                                           and math.isnan(b[c[3]])) for b in units)]
    head = "".join(f'<th class="ids">{esc(label)}</th>' if unit == "ids" else f"<th>{esc(label)}</th>"
                   for label, _, unit, _ in cols)
    body = "".join(
        f'<tr class="{esc(b["status"])}">'
        + "".join(f'<td class="ids">{esc(fn(b))}</td>' if unit == "ids" else f"<td>{_fmt(fn(b), unit)}</td>"
                  for _, fn, unit, _ in cols)
        + "</tr>" for b in units)
    return f'<table class="units"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def _summary_table(metrics: dict, compare: dict | None, labels: tuple[str, str]) -> str:
    esc = html.escape
    sets = [metrics] if compare is None else [metrics, compare]
    head = "" if compare is None else (
        f"<thead><tr><th></th><th>{esc(labels[0])}</th><th>{esc(labels[1])}</th></tr></thead>")

    def cell(m, key, unit):
        v = m.get(key)
        return f"<td>{_fmt(v, unit)}{' m' if unit == 'm' and v is not None else ''}</td>"

    rows = "".join(f"<tr><td>{esc(label)}</td>{''.join(cell(m, key, unit) for m in sets)}</tr>"
                   for key, label, unit in _SUMMARY if any(key in m for m in sets))
    return f'<table class="summary">{head}<tbody>{rows}</tbody></table>'


def report_html(metrics: dict, images: dict[str, bytes], *, title: str = "rooftrace evaluation",
                compare_metrics: dict | None = None,
                labels: tuple[str, str] = ("extracted", "compared")) -> str:
    """The report page as one HTML string, images embedded as base64 PNG.

    Parameters
    ----------
    metrics : dict
        The output of :func:`rooftrace.evaluate.evaluate`.
    images : dict of str to bytes
        File name -> PNG bytes (see :func:`render_figures`); captions from
        :data:`FIGURES`. ``image.png`` gets a section of its own.
    title : str
    compare_metrics : dict, optional
        A second extracted set evaluated against the same reference; its
        scene scores stand beside those of ``metrics`` in the summary.
    labels : (str, str)
        Column headings of the two sets in the summary.
    """
    esc = html.escape
    rule = esc(str(metrics.get("matching_rule_description", metrics.get("matching_rule", ""))))
    aoi = metrics.get("aoi_area")

    def figure(name, png):
        return (f'<figure><img alt="{esc(name)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'
                f"<figcaption>{esc(FIGURES.get(name, name))}</figcaption></figure>")

    image = (f"<h2>Image: {esc(labels[1])} and {esc(labels[0])}</h2>" if compare_metrics is not None
             else "<h2>Image</h2>") + figure("image.png", images["image.png"]) if "image.png" in images else ""
    figs = "".join(figure(name, png) for name, png in images.items() if name != "image.png")
    units = list(metrics.get("buildings", []))
    units.sort(key=lambda b: (b["status"] != "matched", -(b["polis"] if b["polis"] is not None else -1), b["unit"]))
    shown = units[:_MAX_ROWS]
    more = (f'<p class="note">Showing the {len(shown)} worst of {len(units)} units; all are in metrics.json.</p>'
            if len(units) > len(shown) else "")
    compared = ("" if compare_metrics is None else
                f'<p class="counts">{esc(labels[1])}: {esc(unit_sentence(compare_metrics))}</p>')
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_CSS}</style></head>
<body>
<h1>{esc(title)}</h1>
<p class="counts">{esc(labels[0]) + ": " if compare_metrics is not None else ""}{esc(unit_sentence(metrics))}</p>
{compared}
<p class="note">Area scores after Wiedemann et al. (1998) and the ISPRS quality; PoLiS after Avbelj et al. (2015);
RMSE of reference vertices against their closest points on the extracted outline. Corners are the vertices
where an outline turns (vertices within 2&nbsp;cm of their neighbours' line and vertices along curves set aside),
matched one-to-one within {_fmt(metrics.get("corner_tolerance"), "m")}&nbsp;m. Matching rule: {rule}.
{f"Area of interest: {aoi:.1f} m²." if aoi else ""}</p>
<h2>Summary</h2>
{_summary_table(metrics, compare_metrics, labels)}
{image}
<h2>Figures</h2>
{figs or '<p class="note">No figures.</p>'}
<h2>Buildings</h2>
{more}
{_units_table(shown)}
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
    compare: Sequence | None = None,
    compare_metrics: dict | None = None,
    image=None,
    camera=None,
    labels: tuple[str, str] = ("extracted", "compared"),
    overwrite: bool = True,
    models: Sequence | None = None,
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
    compare : sequence of Polygon/MultiPolygon, optional
        A second extracted set, e.g. the LiDAR-only outlines of a run whose
        ``extracted`` outlines were refined with an image.
    compare_metrics : dict, optional
        :func:`rooftrace.evaluate.evaluate` of ``compare`` against
        ``reference``: its scores stand beside those of ``metrics``.
    image : ndarray, optional
        The image, drawn with the outlines projected into it by ``camera``
        (see :func:`render_figures`).
    camera : FrameCamera or OrthoCamera, optional
    labels : (str, str)
        Names of the extracted and the compared set.
    overwrite : bool, default True
        Replace existing report files; the caller decides whether the
        folder may be reused (the CLI refuses when ``metrics.json`` exists).
    models : sequence of BuildingModel, optional
        3D models of the run: a 3D view of the largest (``models_3d.png``).

    Returns
    -------
    Path
        The path of ``report.html``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (compare is None) != (compare_metrics is None):
        raise ValueError("compare and compare_metrics go together")
    images = render_figures(metrics, extracted, reference, points_xy=points_xy,
                            extracted_ridges=extracted_ridges, reference_ridges=reference_ridges,
                            compare=compare, compare_metrics=compare_metrics, image=image, camera=camera,
                            labels=labels, models=models)
    for name, png in images.items():
        with atomic_path(out / name, overwrite) as tmp:
            tmp.write_bytes(png)
    page = out / "report.html"
    with atomic_path(page, overwrite) as tmp:
        tmp.write_text(report_html(metrics, images, title=title, compare_metrics=compare_metrics, labels=labels),
                       encoding="utf-8")
    log.info("wrote %s", page)
    return page
