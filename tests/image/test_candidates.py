import numpy as np
import pytest

from rooftrace.image.candidates import CandidateOptions, LineCandidates, extract_candidates
from rooftrace.image.projection import in_window
from tests.image._render import bar_polygon, close_to, gable_scene


@pytest.fixture(scope="module")
def scene():
    return gable_scene()


def test_candidates_recover_every_side_and_the_ridge(scene):
    out = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds)
    assert len(out) == 5 and all(isinstance(c, LineCandidates) for c in out)
    for c, truth, kind in zip(out, scene.truth, scene.kinds):
        assert c.kind == kind and not c.projected_only
        assert c.candidates.ndim == 3 and c.candidates.shape[1:] == (2, 2)
        assert len(c.source) == len(c.candidates) >= 1
        assert c.registration_error == pytest.approx(6.8, abs=0.2)  # 0.48 m at 0.1 m GSD, both axes
        assert in_window(c.reference, c.window).all()
        # the input lines are 0.3 m (3 px) off; a candidate is within 1 px and 1 deg of the truth
        assert not close_to(c.reference[None], truth)
        assert close_to(c.candidates, truth, px=1.0, deg=1.0)
    # a ridge with a bright cap is a line: Steger's answer joins Canny's double response
    assert "steger" in out[4].source
    assert all(set(c.source) <= {"canny", "merged"} for c in out[:4])


def test_seed003_rule_replaces_the_ridge_double_response(scene):
    both = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds)[4]
    paper = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds,
                               options=CandidateOptions(selection="seed003"))[4]
    near = lambda c: [src for seg, src in zip(c.candidates, c.source)  # noqa: E731
                      if close_to(seg[None], scene.truth[4], px=3.0, deg=3.0)]
    assert sorted(near(both)) == ["canny", "canny", "steger"]  # the cap's two edges and its centre
    assert near(paper) == ["steger"]
    canny = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds,
                               options=CandidateOptions(selection="canny"))[4]
    assert "steger" not in canny.source


def test_ridge_without_cap_is_a_step_edge_kept_from_canny():
    s = gable_scene(ridge_cap=False, seed=5)
    out = extract_candidates(s.image, s.camera, s.lines3d, s.kinds)
    assert close_to(out[4].candidates, s.truth[4])
    assert "steger" not in out[4].source


def test_side_without_image_evidence_keeps_its_projection():
    s = gable_scene()
    # repaint the ground beyond side 0 with the roof's grey: that side has no edge
    side = s.truth[0]
    n = side[1] - side[0]
    n = np.array([n[1], -n[0]]) / np.hypot(*n)
    centre = s.truth[:4].reshape(-1, 2).mean(0)
    if (side.mean(0) - centre) @ n < 0:
        n = -n
    patch = np.array([side[0] - 40 * n / 4, side[1] - 40 * n / 4, side[1] + 40 * n, side[0] + 40 * n])
    s2 = gable_scene(extra=[(patch, 0.62)])
    out = extract_candidates(s2.image, s2.camera, s2.lines3d, s2.kinds)
    assert out[0].projected_only and out[0].source == ["projected"]
    np.testing.assert_allclose(out[0].candidates[0], out[0].reference)
    assert not out[1].projected_only


def test_terrain_lines_are_removed_with_lidar_points():
    s0 = gable_scene()
    side = s0.truth[0]
    d = (side[1] - side[0]) / np.hypot(*(side[1] - side[0]))
    n = np.array([-d[1], d[0]])
    centre = s0.truth[:4].reshape(-1, 2).mean(0)
    if (side.mean(0) - centre) @ n < 0:
        n = -n
    # a dark road 16-30 px beyond side 0, parallel to it: its edge lies in the side's window
    p0, p1 = side[0] + 23 * n - 30 * d, side[1] + 23 * n + 30 * d
    road = bar_polygon(p0, p1, 14.0)
    s = gable_scene(extra=[(road, 0.1)])
    near_edge = s.truth[0] + 16 * n
    plain = extract_candidates(s.image, s.camera, s.lines3d, s.kinds)
    assert close_to(plain[0].candidates, near_edge, px=1.5, deg=1.5)
    filtered = extract_candidates(s.image, s.camera, s.lines3d, s.kinds,
                                  points_xyz=s.points_xyz, building_xyz=s.building_xyz)
    assert not close_to(filtered[0].candidates, near_edge, px=1.5, deg=1.5)
    assert close_to(filtered[0].candidates, s.truth[0])
    # without the building's own points the projected lines stand for it
    alt = extract_candidates(s.image, s.camera, s.lines3d, s.kinds, points_xyz=s.points_xyz)
    assert not close_to(alt[0].candidates, near_edge, px=1.5, deg=1.5)


def test_deterministic_and_outside_lines(scene):
    a = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds)
    b = extract_candidates(scene.image.copy(), scene.camera, scene.lines3d.copy(), list(scene.kinds))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.candidates, y.candidates)
        assert x.source == y.source
    far = scene.lines3d[:1] + [500.0, 0, 0]
    out = extract_candidates(scene.image, scene.camera, far, ["outline"])
    assert out[0].projected_only
    point = scene.lines3d[:1].copy()
    point[0, 1] = point[0, 0]  # a vertical edge seen from above: one pixel
    assert extract_candidates(scene.image, scene.camera, point, ["outline"])[0].projected_only


def test_options_change_the_outcome(scene):
    # a longer minimum length than any fragment leaves only projections
    opt = CandidateOptions(min_length_fraction=2.0)
    out = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds, options=opt)
    assert all(c.projected_only for c in out)
    small = extract_candidates(scene.image, scene.camera, scene.lines3d, scene.kinds,
                               options=CandidateOptions(window_k=0.0, window_margin=1.0))
    assert all(c.projected_only for c in small)  # a 1 px window cannot reach edges 3 px away


def test_bad_arguments(scene):
    cam, img = scene.camera, scene.image
    with pytest.raises(ValueError, match="kinds has 1"):
        extract_candidates(img, cam, scene.lines3d, ["outline"])
    with pytest.raises(ValueError, match="'outline' or 'ridge'"):
        extract_candidates(img, cam, scene.lines3d[:1], ["eave"])
    with pytest.raises(ValueError, match="grey"):
        extract_candidates(np.stack([img] * 3), cam, scene.lines3d[:1], ["outline"])
    with pytest.raises(ValueError, match="candidates.canny_sigma"):
        CandidateOptions(canny_sigma=0)
    with pytest.raises(ValueError, match="candidates.max_angle"):
        CandidateOptions(max_angle=95)
    assert extract_candidates(img, cam, np.zeros((0, 2, 3)), []) == []


def test_colour_image_finds_edges_of_equal_brightness():
    # ground as bright as roof half A: side 0 (bordering half A) has no grey edge
    s = gable_scene(noise=0.0, background=0.62)
    ground = gable_scene(noise=0.0, background=1.0, roof=(0.0, 0.0, 0.0)).image  # 1 on the ground, 0 on the roof
    rgb = s.image[..., None] + ground[..., None] * np.array([0.1, -0.1, 0.0])  # a hue shift of the ground
    np.testing.assert_allclose(rgb.mean(axis=2), s.image)
    out_grey = extract_candidates(s.image, s.camera, s.lines3d, s.kinds)
    out_rgb = extract_candidates(rgb, s.camera, s.lines3d, s.kinds)
    assert not close_to(out_grey[0].candidates, s.truth[0], px=1.5, deg=1.5)
    assert close_to(out_rgb[0].candidates, s.truth[0])
    assert close_to(out_rgb[4].candidates, s.truth[4])
