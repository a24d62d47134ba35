"""Scene evaluation: exact values on constructed scenes, empty inputs, AOI, determinism."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import shapely
from shapely import LineString, Polygon, box
from shapely.affinity import translate

from rooftrace.evaluate import SUMMARY_KEYS, evaluate

REQUIRED = ("completeness", "correctness", "f_score", "quality", "polis_mean", "hausdorff_mean",
            "rmse_x", "rmse_y", "rmse_z", "n_reference", "n_extracted", "n_matched", "buildings")


def _scene(rng, n=6):
    """Random rectangles and L-shapes on a 40 m grid (no two overlap)."""
    out = []
    for k in range(n):
        x0, y0 = 40.0 * (k % 3), 40.0 * (k // 3)
        w, h = rng.uniform(8, 20, 2)
        p = box(x0, y0, x0 + w, y0 + h)
        if k % 2:
            p = p.difference(box(x0 + w / 2, y0 + h / 2, x0 + w + 1, y0 + h + 1))
        out.append(p)
    return out


def _dump(m):
    return json.dumps(m, allow_nan=False)


def test_identical_scene_is_perfect(rng):
    ref = _scene(rng)
    m = evaluate(ref, ref)
    _dump(m)
    assert all(k in m for k in REQUIRED)
    assert (m["completeness"], m["correctness"], m["f_score"], m["quality"]) == (1.0, 1.0, 1.0, 1.0)
    assert m["polis_mean"] == 0.0 and m["hausdorff_mean"] == 0.0 and m["rmse_x"] == 0.0
    assert m["rmse_z"] is None  # 2D input
    assert m["n_matched"] == m["n_reference"] == m["n_extracted"] == len(ref)
    assert [b["reference_ids"] for b in m["buildings"]] == [[i] for i in range(len(ref))]


def test_shifted_scene_matches_independent_computation(rng):
    ref = _scene(rng)
    d = 0.7
    ext = [translate(p, d, 0) for p in ref]
    m = evaluate(ext, ref)
    assert m["polis_mean"] == pytest.approx(d / 2, abs=1e-9)  # rectangles and L-shapes alike
    assert m["hausdorff_mean"] == pytest.approx(d, abs=1e-9)
    tp = sum(a.intersection(b).area for a, b in zip(ext, ref))
    assert m["completeness"] == pytest.approx(tp / sum(p.area for p in ref), abs=1e-9)
    assert m["quality"] == pytest.approx(tp / shapely.union_all(ext + ref).area, abs=1e-9)
    for b in m["buildings"]:
        (i,) = b["reference_ids"]
        assert b["hausdorff"] == pytest.approx(shapely.hausdorff_distance(ext[i].boundary, ref[i].boundary), abs=1e-9)
        assert b["quality"] == pytest.approx(ref[i].intersection(ext[i]).area / ref[i].union(ext[i]).area, abs=1e-9)
    # pooled RMSE in x: each reference vertex is d off or lies on the shifted outline
    verts = np.concatenate([np.asarray(p.exterior.coords)[:-1] for p in ref])
    dist = shapely.distance(shapely.points(verts), shapely.union_all([e.boundary for e in ext]))
    assert m["rmse_x"] == pytest.approx(math.sqrt(np.mean(dist ** 2)), abs=1e-9)
    assert m["rmse_y"] == pytest.approx(0.0, abs=1e-12)


def test_terraced_block_rule_is_recorded():
    ref = [box(0, 0, 10, 10), box(10, 0, 20, 10), box(20, 0, 30, 10)]
    ext = [box(0, 0, 30, 10)]
    m = evaluate(ext, ref)
    assert m["matching_rule"] == "merged-blocks" and m["n_matched"] == 1
    (b,) = m["buildings"]
    assert b["reference_ids"] == [0, 1, 2] and b["polis"] == 0.0 and b["hausdorff"] == 0.0
    assert m["n_reference_found"] == 3 and m["object_completeness"] == 1.0
    # how the buildings formed units, not only in the table
    assert (m["n_matched_merged"], m["n_reference_in_merged"], m["n_extracted_in_merged"]) == (1, 3, 1)
    assert (m["n_matched_one_to_one"], m["n_missed"], m["n_false_positive"]) == (0, 0, 0)
    m1 = evaluate(ext, ref, merge_blocks=False)
    assert (m1["n_matched_one_to_one"], m1["n_matched_merged"], m1["n_missed"]) == (1, 0, 2)
    assert m1["matching_rule"] == "one-to-one" and m1["n_matched"] == 1
    assert [b["status"] for b in m1["buildings"]] == ["matched", "missed", "missed"]
    assert m1["completeness"] == 1.0  # area scores do not depend on matching


def test_empty_inputs():
    ref = [box(0, 0, 10, 10)]
    m = evaluate([], ref)
    _dump(m)
    assert m["completeness"] == 0.0 and m["correctness"] is None and m["f_score"] == 0.0
    assert m["n_matched"] == 0 and m["polis_mean"] is None and m["hausdorff_mean"] is None
    assert m["buildings"][0]["status"] == "missed" and m["object_completeness"] == 0.0
    m = evaluate(ref, [])
    assert m["completeness"] is None and m["correctness"] == 0.0
    assert m["buildings"][0]["status"] == "false_positive"
    m = evaluate([], [])
    _dump(m)
    assert m["buildings"] == [] and m["n_reference"] == 0 and m["f_score"] is None
    m = evaluate([None, Polygon()], ref)  # empty geometries are ignored
    assert m["n_extracted"] == 0


def test_no_overlap():
    m = evaluate([box(0, 0, 5, 5)], [box(10, 0, 15, 5)])
    assert (m["completeness"], m["correctness"], m["quality"]) == (0.0, 0.0, 0.0)
    assert sorted(b["status"] for b in m["buildings"]) == ["false_positive", "missed"]


def test_aoi_selects_and_clips():
    ref = [box(0, 0, 10, 10), box(20, 0, 30, 10)]
    ext = [box(0, 0, 10, 10), box(21, 0, 31, 10)]
    aoi = box(-1, -1, 15, 11)
    m = evaluate(ext, ref, aoi=aoi)
    assert m["n_reference"] == 1 and m["n_extracted"] == 1 and m["polis_mean"] == 0.0
    assert m["completeness"] == 1.0 and m["aoi_area"] == pytest.approx(16 * 12)
    # an AOI cutting a building: areas clipped, the building kept whole for distances
    m = evaluate(ext, ref, aoi=box(-1, -1, 25, 11))
    assert m["tp_area"] == pytest.approx(100 + 4 * 10) and m["fn_area"] == pytest.approx(10)
    assert m["n_reference"] == 1  # point_on_surface of the second one lies at x = 25


def test_3d_and_ridges():
    ref = [Polygon([(0, 0, 5), (10, 0, 5), (10, 10, 5), (0, 10, 5)])]
    ext = [Polygon([(0, 0, 5.2), (10, 0, 5.2), (10, 10, 5.2), (0, 10, 5.2)])]
    m = evaluate(ext, ref, extracted_ridges=[LineString([(0, 5.1, 8), (10, 5.1, 8)])],
                 reference_ridges=[LineString([(0, 5, 8), (10, 5, 8)])])
    assert m["rmse_z"] == pytest.approx(0.2, abs=1e-12) and m["polis_3d_mean"] == pytest.approx(0.2, abs=1e-12)
    assert m["ridge_completeness"] == pytest.approx(1.0) and m["ridge_position_error"] == pytest.approx(0.1)
    assert m["n_ridges_reference"] == 1
    assert all(k in m for k in SUMMARY_KEYS)


def test_vertical_step_pooled_and_per_building():
    # an annex (z 3) meeting the main roof (z 8) at x = 4; extracted 0.1 m higher
    step = [(0, 0, 3), (4, 0, 3), (4, 0, 8), (10, 0, 8), (10, 5, 8), (4, 5, 8), (4, 5, 3), (0, 5, 3)]
    m = evaluate([Polygon([(x, y, z + 0.1) for x, y, z in step])], [Polygon(step)])
    assert m["rmse_z"] == pytest.approx(0.1, abs=1e-12)
    assert m["buildings"][0]["rmse_z"] == pytest.approx(0.1, abs=1e-12)


def test_deterministic_and_order_free(rng):
    ref = _scene(rng)
    ext = [translate(p, 0.3, -0.2) for p in ref]
    m1 = evaluate(ext, ref)
    perm = np.random.default_rng(1).permutation(len(ext))
    m2 = evaluate([ext[i] for i in perm], ref, extracted_ids=[int(i) for i in perm])
    for key in ("completeness", "quality", "polis_mean", "hausdorff_mean", "rmse_x", "rmse_y"):
        assert m2[key] == pytest.approx(m1[key], abs=1e-12)
    assert [b["extracted_ids"] for b in m2["buildings"]] == [b["extracted_ids"] for b in m1["buildings"]]
    assert evaluate(ext, ref) == m1


def test_invalid_polygon_is_repaired_and_bad_type_refused(caplog):
    bowtie = Polygon([(0, 0), (10, 10), (10, 0), (0, 10)])
    m = evaluate([bowtie], [box(0, 0, 10, 10)])
    assert m["correctness"] == pytest.approx(1.0) and "invalid" in caplog.text
    with pytest.raises(TypeError, match="extracted"):
        evaluate([LineString([(0, 0), (1, 1)])], [])


def test_errors_along_the_reference_walls_are_reported_apart():
    """Eaves over a wall-line footprint are boundary FP; a missed building far from any other is not."""
    from rooftrace.evaluate.metrics import boundary_errors

    house, shed = box(0, 0, 10, 10), box(30, 0, 40, 10)
    roof = box(-0.5, -0.5, 10.5, 10.5)  # 0.5 m eaves all round
    m = evaluate([roof], [house, shed])
    assert m["fp_area"] == pytest.approx(21.0) and m["fp_area_boundary"] == pytest.approx(21.0)
    assert m["fn_area"] == pytest.approx(100.0)
    # of the missed 10 x 10 m building only its 1 m rim is "boundary"
    assert m["fn_area_boundary"] == pytest.approx(100.0 - 64.0)
    assert m["boundary_band"] == 1.0 and {"fp_area_boundary", "fn_area_boundary"} <= set(SUMMARY_KEYS)
    # an area of interest cutting through the house is no wall: the missed strip y 3..5 touches the cut at
    # y = 5, but only its ends by the side walls (x 0..1 and 9..10) are boundary error
    cut = evaluate([box(0, 0, 10, 3)], [house], aoi=box(-5, -5, 15, 5))
    assert cut["fn_area"] == pytest.approx(20.0) and cut["fn_area_boundary"] == pytest.approx(4.0)
    assert boundary_errors(box(0, 0, 1, 1), None) == {"fp_boundary": 0.0, "fn_boundary": 0.0}
    with pytest.raises(ValueError, match="band"):
        boundary_errors(roof, house, 0.0)
