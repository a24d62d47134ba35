"""The HTML report: self-contained, images decodable, table consistent with the metrics."""

from __future__ import annotations

import base64
import io
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
    assert set(render_figures(m, ext, ref)) == set(FIGURES) - {"image.png", "models_3d.png"}  # no image, no models
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


def test_unit_sentence_says_what_was_merged():
    from rooftrace.evaluate.report import unit_sentence

    ref = [box(0, 0, 10, 10), box(10, 0, 20, 10), box(20, 0, 30, 10), box(40, 0, 50, 10), box(50, 0, 60, 10),
           box(70, 0, 80, 10), box(90, 0, 100, 10), box(120, 0, 130, 10)]
    # a block of three and one of two merged, one split in two, one one to one, one missed, one false detection
    ext = [box(0, 0, 30, 10), box(40, 0, 60, 10), box(70, 0, 75, 10), box(75, 0, 80, 10), box(90, 0, 100, 10),
           box(200, 0, 210, 10)]
    m = evaluate(ext, ref)
    assert (m["n_matched_merged"], m["n_reference_in_merged"], m["n_extracted_in_merged"]) == (3, 6, 4)
    assert unit_sentence(m) == (
        "8 reference and 6 extracted buildings: 4 matched units, 1 one to one, a merged block (3 reference "
        "buildings into 1 extracted), a merged block (2 reference buildings into 1 extracted) and a merged block "
        "(1 reference building split into 2 extracted); 1 reference building missed, 1 false detection.")
    two = evaluate([box(0, 0, 20, 10), box(30, 0, 50, 10)], [box(0, 0, 10, 10), box(10, 0, 20, 10),
                                                             box(30, 0, 40, 10), box(40, 0, 50, 10)])
    assert unit_sentence(two) == ("4 reference and 2 extracted buildings: 2 matched units, 2 merged blocks "
                                  "(2 reference buildings into 1 extracted each); 0 reference buildings missed, "
                                  "0 false detections.")
    chain = evaluate([box(5, 0, 15, 10), box(15, 0, 20, 10), box(40, 0, 50, 10)],
                     [box(0, 0, 10, 10), box(10, 0, 20, 10), box(40, 0, 50, 10), box(60, 0, 70, 10)])
    assert unit_sentence(chain) == ("4 reference and 3 extracted buildings: 2 matched units, 1 one to one and a "
                                    "merged block (2 reference buildings into 2 extracted); 1 reference building "
                                    "missed, 0 false detections.")
    assert unit_sentence(evaluate(ref[:2], ref[:2], merge_blocks=False)).startswith(
        "2 reference and 2 extracted buildings: 2 matched units, all one to one; ")
    text = report_html(m, {})
    assert "a merged block (3 reference buildings into 1 extracted)" in text


def test_building_table_fits_the_page(scene):
    ext, ref, _ = scene
    m = evaluate(ext, ref)
    text = report_html(m, {})
    assert "overflow-x" not in text and "scroll" not in text and 'class="units"' in text
    head = re.search(r'<table class="units"><thead><tr>(.*?)</tr>', text).group(1)
    # 2D outlines: no PoLiS 3D nor RMSE z column; ids of both sides in one column; x and y in one RMSE
    assert "PoLiS 3D" not in head and "RMSE z" not in head and "RMSE xy" in head
    assert head.count("<th") == 12
    assert "0 → 0" in text and "– → 7" in text


def test_image_with_two_outline_sets_and_scores_side_by_side(scene):
    from matplotlib.image import imread

    from rooftrace.evaluate.figures import _IMG_CMP, _IMG_EXT, _image_figure, _png
    from rooftrace.image.camera import FrameCamera, OrthoCamera

    ext, ref, pts = scene
    lidar_only = [translate(p, 0.0, 0.5) for p in ext]
    m, mo = evaluate(ext, ref), evaluate(lidar_only, ref)
    cam = OrthoCamera((1100, 100), (0.25, 0.0, -5.0, 0.0, -0.25, 20.0))  # 0.25 m pixels over the scene
    image = np.full((100, 1100, 3), 90, np.uint8)
    png = _png(_image_figure(m, image, cam, ext, ref, lidar_only, mo, ("refined", "LiDAR only")))
    images = {"image.png": png}
    rgb = (imread(io.BytesIO(png))[..., :3] * 255).round().astype(int)

    def has(colour):
        c = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)])
        return int((np.abs(rgb - c).max(axis=2) <= 10).sum())

    assert has(_IMG_EXT) > 200 and has(_IMG_CMP) > 200  # both sets drawn over the image
    text = report_html(m, images, compare_metrics=mo, labels=("refined", "LiDAR only"))
    assert "<th>refined</th><th>LiDAR only</th>" in text and "<h2>Image: LiDAR only and refined</h2>" in text
    assert f"{m['polis_mean']:.3f} m" in text and f"{mo['polis_mean']:.3f} m" in text
    # a frame camera cannot place 2D outlines: no image figure rather than a wrong one
    frame = FrameCamera((100, 100), 0.01, 50.0, np.array([50.0, 5.0, 500.0, 0.0, 0.0, 0.0]))
    assert _image_figure(m, image[:, :100], frame, ext, ref) is None
    with pytest.raises(ValueError, match="go together"):
        render_figures(m, ext, ref, image=image)


def test_image_display_scaling():
    from rooftrace.evaluate.figures import _raster

    bands = np.full((3, 10, 20), 51, np.uint8)
    rgb, scale, kw = _raster(bands)  # bands first, as rasterio reads them; a view, not a copy
    assert rgb.shape == (10, 20, 3) and np.shares_memory(rgb, bands) and scale == 255.0 and kw == {}
    grey, scale, kw = _raster(np.linspace(0, 4095, 200).reshape(10, 20).astype(np.uint16))  # 12 bits in 16
    assert grey.shape == (10, 20) and kw["cmap"] == "gray" and 4000 < scale < 4095
    assert _raster(np.full((10, 20), 0.3))[1] == 1.0  # floats in [0, 1] as they are
    with pytest.raises(ValueError, match="image must be"):
        _raster(np.zeros(5))
