"""The HTML report: self-contained, images decodable, table consistent with the metrics."""

from __future__ import annotations

import base64
import re

import numpy as np
import pytest
from shapely import box
from shapely.affinity import translate

from rooftrace.evaluate import evaluate
from rooftrace.evaluate.report import FIGURES, render_figures, report_html, write_report

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def scene(rng):
    ref = [box(30.0 * k, 0, 30.0 * k + rng.uniform(8, 15), rng.uniform(8, 15)) for k in range(8)]
    ext = [translate(p, 0.1 * k, 0) for k, p in enumerate(ref[:-1])] + [box(500, 0, 505, 5)]
    pts = rng.uniform([0, 0], [250, 15], (5000, 2))
    return ext, ref, pts


def test_write_report_self_contained(tmp_path, scene):
    ext, ref, pts = scene
    m = evaluate(ext, ref)
    page = write_report(tmp_path / "out", m, ext, ref, points_xy=pts, title="T <&>")
    text = page.read_text()
    assert page.name == "report.html" and "T &lt;&amp;&gt;" in text
    assert not re.search(r'(src|href)="(?!data:)', text)  # nothing fetched from outside
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(images) == 3
    for name, b64 in zip(FIGURES, images):
        png = base64.b64decode(b64)
        assert png.startswith(PNG) and (tmp_path / "out" / name).read_bytes() == png
    # one row per unit, statuses as in the metrics
    assert text.count('<tr class="matched">') == m["n_matched"] == 7
    assert text.count('<tr class="missed">') == 1 and text.count('<tr class="false_positive">') == 1
    assert f"{m['polis_mean']:.3f} m" in text


def test_figures_deterministic_and_without_points(scene):
    ext, ref, pts = scene
    m = evaluate(ext, ref)
    a = render_figures(m, ext, ref, points_xy=pts)
    assert a == render_figures(m, ext, ref, points_xy=pts)
    assert set(render_figures(m, ext, ref)) == set(FIGURES) - {"models_3d.png"}  # no models given
    with pytest.raises(ValueError, match="points_xy"):
        render_figures(m, ext, ref, points_xy=np.zeros(5))


def test_only_false_detections_get_overlays():
    m = evaluate([box(0, 0, 5, 5)], [])
    assert "overlays.png" in render_figures(m, [box(0, 0, 5, 5)], [])


def test_empty_report():
    m = evaluate([], [])
    images = render_figures(m, [], [])
    assert "overlays.png" not in images
    text = report_html(m, images)
    assert "no matched buildings" not in text  # drawn in the PNG, not the page
    assert text.startswith("<!DOCTYPE html>") and "<tbody></tbody>" in text


def test_ridges_are_drawn(scene):
    from shapely import LineString

    ext, ref, _ = scene
    m = evaluate(ext, ref)
    x0, y0, x1, y1 = ref[0].bounds
    ridges = [LineString([(x0, (y0 + y1) / 2), (x1, (y0 + y1) / 2)])]
    plain = render_figures(m, ext, ref)["overlays.png"]
    drawn = render_figures(m, ext, ref, extracted_ridges=ridges, reference_ridges=ridges)["overlays.png"]
    assert plain != drawn
