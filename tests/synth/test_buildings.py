import math

import numpy as np
import pytest
import shapely

from rooftrace.synth import Building, default_buildings
from rooftrace.synth.buildings import CURVE_STEP
from rooftrace.synth.truth import plane_z, roof_faces, roof_outline_3d, roof_ridges

O = np.array([85000.0, 447000.0])


def _truth(b):
    faces = roof_faces(b)
    return faces, roof_ridges(faces), roof_outline_3d(b, faces)


def test_gable_faces_ridge_and_outline_heights():
    b = Building.rectangle(1, O + 20, 12.0, 8.0, angle_deg=30, kind="gable", eave_height=6, ridge_height=9,
                           overhang=0.5)
    faces, ridges, outline = _truth(b)
    assert len(faces) == 2
    assert sum(f.polygon.area for f in faces) == pytest.approx(13.0 * 9.0)
    for f in faces:
        assert f.slope_deg == pytest.approx(math.degrees(math.atan(3.0 / 4.5)))
    assert sorted(f.aspect_deg for f in faces) == pytest.approx([150.0, 330.0])
    assert [r.kind for r in ridges] == ["ridge"]
    line = np.asarray(ridges[0].line.coords)
    assert ridges[0].line.length == pytest.approx(13.0, abs=1e-3)
    np.testing.assert_allclose(line[:, 2], 9.0)
    np.testing.assert_allclose(np.mean(line[:, :2], axis=0), O + 20, atol=1e-6)
    z = shapely.get_coordinates(outline, include_z=True)[:, 2]
    # four eave corners and two gable apexes
    assert len(outline.exterior.coords) == 7
    assert sorted(np.round(z[:-1], 6)) == [6.0, 6.0, 6.0, 6.0, 9.0, 9.0]
    assert outline.area == pytest.approx(13.0 * 9.0)


def test_hip_has_one_ridge_and_four_hips():
    b = Building.rectangle(2, O + 20, 14.0, 8.0, kind="hip", eave_height=5, ridge_height=8, overhang=0.0)
    faces, ridges, _ = _truth(b)
    kinds = sorted(r.kind for r in ridges)
    assert kinds == ["hip"] * 4 + ["ridge"]
    ridge = next(r for r in ridges if r.kind == "ridge")
    assert ridge.line.length == pytest.approx(14.0 - 8.0, abs=1e-3)
    assert len(faces) == 4


def test_l_shape_has_valleys_and_partitions_the_outline():
    b = Building.l_shape(3, O + 20, 16.0, 8.0, 6.0, angle_deg=10, kind="gable", eave_height=6, ridge_height=9.5,
                         overhang=0.5)
    faces, ridges, outline = _truth(b)
    kinds = [r.kind for r in ridges]
    assert kinds.count("valley") == 2
    assert sum(f.polygon.area for f in faces) == pytest.approx(b.roof_outline.area, rel=1e-6)
    assert b.roof_outline.area == pytest.approx(b.footprint.buffer(0.5, join_style="mitre").area, rel=1e-6)
    # every outline vertex sits on the roof surface
    xyz = shapely.get_coordinates(outline, include_z=True)
    h = b.height(xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(xyz[:, 2], h, atol=1e-6)


def test_split_level_ridge_is_a_step_and_dormers_make_steps():
    split = Building.rectangle(4, O + 20, 12.0, 9.0, kind="split", eave_height=5, ridge_height=9)
    _, ridges, _ = _truth(split)
    assert [r.kind for r in ridges] == ["step"]
    dorm = Building.rectangle(5, O + 20, 14.0, 9.0, kind="gable", eave_height=6, ridge_height=10).with_dormers([-3, 3])
    faces, ridges, _ = _truth(dorm)
    assert len(faces) == 4
    assert {"ridge", "step", "valley"} <= {r.kind for r in ridges}
    assert sum(f.polygon.area for f in faces) == pytest.approx(dorm.roof_outline.area)


def test_annex_is_lower_and_joins_with_a_step():
    b = Building.rectangle(6, O + 20, 14.0, 9.0, kind="hip", eave_height=6, ridge_height=9).with_annex(
        O + 20 - [0.0, 7.0], 6.0, 5.0, eave_height=3.0, wall_side="+v")
    faces, ridges, outline = _truth(b)
    assert "step" in [r.kind for r in ridges]
    assert min(f.plane[2] for f in faces if abs(f.plane[0]) + abs(f.plane[1]) < 1e-12) == pytest.approx(3.0)
    assert outline.is_valid


def test_courtyard_has_a_hole_and_round_walls_are_densified():
    c = Building.courtyard(7, O + 30, 24.0, 20.0, 7.0, overhang=0.3)
    _, _, outline = _truth(c)
    assert len(outline.interiors) == 1
    assert outline.area == pytest.approx(24.6 * 20.6 - 9.4 * 5.4)
    r = Building.round(8, O + 30, 7.0)
    seg = np.diff(np.asarray(r.footprint.exterior.coords), axis=0)
    assert np.hypot(*seg.T).max() <= CURVE_STEP + 1e-9
    assert r.footprint.area == pytest.approx(math.pi * 49, rel=2e-3)
    arc = Building.arc(9, O, 55.0, 8.0, 20.0)
    assert arc.footprint.is_valid and arc.footprint.area == pytest.approx(math.radians(20) * 55 * 8, rel=1e-3)


def test_terrace_houses_share_walls_without_overlapping_roofs():
    row = Building.terrace(10, O + 30, [5.0, 5.0, 6.0], 9.0, eave_heights=[6, 6, 6.5], ridge_heights=[9, 9, 9.8])
    assert [b.building_id for b in row] == [10, 11, 12]
    for a, b in zip(row[:-1], row[1:]):
        assert a.footprint.intersection(b.footprint).length == pytest.approx(9.0)
        assert a.roof_outline.intersection(b.roof_outline).area < 1e-6


def test_default_mix_has_every_kind_and_faces_partition_each_roof():
    bs = default_buildings(1, 160.0, tuple(O))
    kinds = " ".join(b.kind for b in bs)
    for k in ("flat", "gable", "hip", "shed", "split", "round", "stadium", "arc", "courtyard", "l_shape",
              "t_shape", "u_shape", "terrace", "annex", "dormers", "pyramid"):
        assert k in kinds, k
    assert len({b.building_id for b in bs}) == len(bs)
    box = shapely.box(*O, *(O + 160))
    for b in bs:
        assert box.contains(b.roof_outline)
        faces = roof_faces(b)
        assert sum(f.polygon.area for f in faces) == pytest.approx(b.roof_outline.area, rel=1e-6), b.kind
    assert any(b.overhang > 0 for b in bs) and any(b.ridge_height > 20 for b in bs)
    assert [b.building_id for b in default_buildings(1, 160.0, tuple(O))] == [b.building_id for b in bs]


def test_height_and_bad_polygon():
    b = Building.rectangle(1, O, 10.0, 6.0, kind="gable", eave_height=4, ridge_height=7, overhang=0.0)
    assert b.height(np.array([O[0]]), np.array([O[1]]))[0] == pytest.approx(7.0)
    assert np.isnan(b.height(np.array([O[0] + 50]), np.array([O[1]]))[0])
    f = roof_faces(b)[0]
    assert plane_z(f.plane, *O) == pytest.approx(7.0)
    with pytest.raises(ValueError, match="footprint"):
        Building.from_polygon(1, shapely.Polygon())
    with pytest.raises(ValueError, match="kind"):
        Building.rectangle(1, O, 10.0, 6.0, kind="dome")
