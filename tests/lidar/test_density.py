"""Detection from 2 to 12 pts/m², scan patterns, single returns, split files, one-class scenes (simulated and real)."""

import numpy as np
import pytest
import shapely

from rooftrace.cloud import ASPRS, PointCloud
from rooftrace.lidar.detect import DetectOptions, detect_buildings
from rooftrace.lidar.spacing import point_density, spanning_neighbours
from rooftrace.synth.buildings import Building
from rooftrace.synth.scene import SceneOptions
from rooftrace.synth.simulate import simulate_scene
from tests.lidar.scenes import f1

ORIGIN = (85000.0, 447000.0)


def _score(scene, det, min_area=50.0):
    """Per-point building F1 and the ids of the buildings of at least ``min_area`` m² not found (< half their points)."""
    truth = scene.cloud.fields["truth_class"] == ASPRS.BUILDING
    is_b = det.classification == ASPRS.BUILDING
    bid = scene.cloud.fields["truth_building_id"]
    missed = [b.building_id for b in scene.buildings
              if b.footprint.area >= min_area and (bid == b.building_id).any()
              and np.mean(is_b[bid == b.building_id]) < 0.5]
    return f1(is_b, truth), missed


@pytest.mark.parametrize("density,pattern", [(2.0, {}), (3.0, {"scan_pattern": "random"}),
                                             (2.0, {"scan_pattern": "parallel", "line_spacing": 2.0}),
                                             (4.0, {"single_return": True})])
def test_density_sweep_on_simulated_scenes(density, pattern):
    scene = simulate_scene(SceneOptions(seed=5, size=90.0, density=density, image=False, **pattern))
    det = detect_buildings(scene.cloud)
    score, missed = _score(scene, det)
    assert score > 0.93 and not missed, (score, missed)


@pytest.mark.parametrize("seed", [4, 6])
def test_zigzag_lines_far_apart_at_2_pts_miss_no_building(seed):
    # the mirror's lines pair up 3 m apart towards the swath edges, 0.3 m between
    # points along them: without the sector links (segment.link_sectors) seed 4
    # lost 3 buildings of 50 m² or more (F1 0.81), seed 6 one (F1 0.91)
    scene = simulate_scene(SceneOptions(seed=seed, size=90.0, density=2.0, image=False, line_spacing=1.5))
    score, missed = _score(scene, detect_buildings(scene.cloud))
    assert score > 0.97 and not missed, (score, missed)


def test_link_distance_follows_the_density_where_sector_links_bridge_the_lines():
    # s_avg grows with the gaps between scan lines; with the sector links L_Dxy need not
    scene = simulate_scene(SceneOptions(seed=1, size=60.0, density=4.0, image=False, scan_pattern="parallel",
                                        line_spacing=1.5))
    det = detect_buildings(scene.cloud)
    seg = det.params["segment"]
    assert det.mean_spacing > 1.1 * 1.132 / np.sqrt(det.density)
    assert seg["link_distance"] == pytest.approx(2.25 * 1.132 / np.sqrt(det.density), rel=1e-3)
    assert seg["sector_reach"] > 2.5 > seg["link_distance"]
    thesis = detect_buildings(scene.cloud, config={"segment": {"link_sectors": False}}).params["segment"]
    assert thesis["link_distance"] == pytest.approx(2.25 * det.mean_spacing) and thesis["sector_reach"] is None


def test_scan_lines_are_anisotropic_and_need_wider_normals():
    scene = simulate_scene(SceneOptions(seed=2, size=60.0, density=2.0, image=False, scan_pattern="parallel",
                                        line_spacing=2.0))
    assert scene.info["line_spacing_m"] == 2.0 and scene.info["point_spacing_m"] < 0.5
    xy = scene.cloud.xyz[:, :2]
    lines = spanning_neighbours(xy, point_density(xy))
    square = simulate_scene(SceneOptions(seed=2, size=60.0, density=2.0, image=False, scan_pattern="random"))
    xy = square.cloud.xyz[:, :2]
    assert lines > spanning_neighbours(xy, point_density(xy)) + 5


def test_single_returns_have_no_return_numbers_above_one():
    scene = simulate_scene(SceneOptions(seed=3, size=60.0, density=4.0, image=False, single_return=True))
    assert (scene.cloud.fields["number_of_returns"] == 1).all()
    # and without return numbers at all
    cloud = PointCloud(scene.cloud.xyz, {"classification": np.zeros(len(scene.cloud), np.uint8)}, crs=scene.crs)
    score, missed = _score(scene, detect_buildings(cloud))
    assert score > 0.93 and not missed


def test_ground_and_non_ground_in_separate_files(tmp_path):
    from rooftrace.io.las import write_las
    from rooftrace.io.points import read_points

    scene = simulate_scene(SceneOptions(seed=4, size=70.0, density=2.0, image=False, single_return=True))
    c = scene.cloud
    ground = c.fields["truth_class"] == ASPRS.GROUND
    paths = []
    for name, keep in (("ground.laz", ground), ("nonground.laz", ~ground)):
        part = PointCloud(c.xyz[keep], {k: v[keep] for k, v in c.fields.items() if not k.startswith("truth")},
                          crs=c.crs)
        write_las(tmp_path / name, part)
        paths.append(tmp_path / name)
    both = read_points(paths, None)
    det = detect_buildings(both)
    truth = np.concatenate([c.fields["truth_class"][ground], c.fields["truth_class"][~ground]]) == ASPRS.BUILDING
    assert f1(det.classification == ASPRS.BUILDING, truth) > 0.93


def _houses(n=4, size=80.0):
    out = []
    for i in range(n):
        c = (ORIGIN[0] + 15 + (i % 2) * 40, ORIGIN[1] + 15 + (i // 2) * 40)
        out.append(Building.rectangle(i + 1, c, 11.0, 9.0, angle_deg=20.0 * i, kind="gable", eave_height=5.5 + i,
                                      ridge_height=8.5 + i, overhang=0.4))
    return out


def test_a_scene_of_only_houses():
    scene = simulate_scene(SceneOptions(seed=6, size=80.0, density=3.0, image=False, trees=False),
                           buildings=_houses())
    score, missed = _score(scene, detect_buildings(scene.cloud))
    assert score > 0.93 and not missed
    # the thesis' k-means splits the one population (flat and pitched faces)
    entropy = DetectOptions.from_config(None, classify={"decision": "entropy"})
    assert _score(scene, detect_buildings(scene.cloud, entropy))[0] < score


@pytest.mark.parametrize("single", [False, True])
def test_a_scene_of_only_trees(single):
    # single-return crowns look planar to the entropy (its fallback threshold let 27 % of their points in)
    scene = simulate_scene(SceneOptions(seed=7, size=80.0, density=3.0, image=False, tree_density=60.0,
                                        single_return=single), buildings=[])
    assert (scene.cloud.fields["truth_class"] == ASPRS.HIGH_VEGETATION).sum() > 1000
    det = detect_buildings(scene.cloud)
    assert np.mean(det.classification[scene.cloud.fields["truth_class"] == ASPRS.HIGH_VEGETATION] == ASPRS.BUILDING) < 0.03


def test_small_pitched_houses_among_trees_at_12_pts():
    scene = simulate_scene(SceneOptions(seed=8, size=80.0, density=12.0, image=False, tree_density=60.0),
                           buildings=_houses())
    score, missed = _score(scene, detect_buildings(scene.cloud))
    assert not missed and score > 0.93, (score, missed)


def _houses_under_crowns():
    # 80-120 m², eaves 5-9 m, every house with a crown hanging over its eaves
    dims = [(10.0, 8.0), (11.0, 9.1), (12.0, 10.0), (10.5, 9.0)]
    eaves = [5.0, 6.3, 7.6, 9.0]
    return [Building.rectangle(i + 1, (ORIGIN[0] + 18 + (i % 2) * 40, ORIGIN[1] + 18 + (i // 2) * 40), *dims[i],
                               angle_deg=25.0 * i, kind="gable", eave_height=eaves[i], ridge_height=eaves[i] + 2.8,
                               overhang=0.4) for i in range(4)]


@pytest.mark.parametrize("pattern", ["random", "parallel"])
def test_crowns_grown_into_a_roof_level_at_2_pts_do_not_drop_the_house(pattern):
    # L_Dxy 1.6 m: house 3's roof level took in ~215 crown points and the
    # penetration tests dropped it, unless the patches split off first
    scene = simulate_scene(SceneOptions(seed=9, size=80.0, density=2.0, image=False, tree_density=60.0,
                                        scan_pattern=pattern), buildings=_houses())
    score, missed = _score(scene, detect_buildings(scene.cloud))
    assert score > 0.95 and not missed, (score, missed)
    whole = detect_buildings(scene.cloud, config={"classify": {"split_patches_from": False}})
    assert _score(scene, whole)[1] == [3]


@pytest.mark.parametrize("density,pattern,config", [(2.0, "random", None), (4.0, "parallel", None),
                                                    (12.0, "zigzag", {"classify": {"split_patches_from": 0.0}})])
def test_houses_with_crowns_over_the_eaves(density, pattern, config):
    # at 12 pts/m² (L_Dxy 0.74 m) the split is off by default: seeds 8 and 10 lose a house
    scene = simulate_scene(SceneOptions(seed=8, size=80.0, density=density, image=False, tree_density=60.0,
                                        scan_pattern=pattern, overhanging_trees=1.0, crowns_to_eaves=True),
                           buildings=_houses_under_crowns())
    veg = scene.cloud.fields["truth_class"] == ASPRS.HIGH_VEGETATION
    roofs = shapely.union_all([b.roof_outline for b in scene.buildings])
    assert shapely.contains_xy(roofs, scene.cloud.x[veg], scene.cloud.y[veg]).sum() > 10 * density
    score, missed = _score(scene, detect_buildings(scene.cloud, config=config))
    assert score > 0.92 and not missed, (score, missed)


@pytest.mark.slow
@pytest.mark.parametrize("target,expect", [(2.0, 0.9), (4.0, 0.93)])
def test_real_delft_thinned(target, expect):
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import read_layer
    from tests.conftest import DELFT, need

    folder = need(DELFT)
    full = read_points([folder / "ahn3_cropped_2.laz"], "EPSG:28992")
    keep = np.random.default_rng(0).random(len(full)) < target / point_density(full.xyz[:, :2])
    cloud = PointCloud(full.xyz[keep], {k: v[keep] for k, v in full.fields.items()}, crs=full.crs)
    truth = cloud.fields["classification"].copy()
    cloud.fields["classification"][:] = 0
    det = detect_buildings(cloud)
    pand = shapely.union_all([g for g in read_layer(folder / "bgt_pand.sqlite").geometries if g is not None])
    area = shapely.union_all([shapely.make_valid(g) for p in sorted(folder.glob("bgt_*.sqlite"))
                              for g in read_layer(p).geometries if g is not None]).buffer(-2.0)
    inside = shapely.contains_xy(area, cloud.x, cloud.y)
    assert pand.area > 0
    assert f1(det.classification[inside] == ASPRS.BUILDING, truth[inside] == ASPRS.BUILDING) > expect
