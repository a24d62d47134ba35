import numpy as np
import pytest

from rooftrace.image.camera import FrameCamera, OrthoCamera, rotation_matrix


def _cam(**kw):
    eo = kw.pop("exterior", np.array([1000.0, 2000.0, 800.0, 0.02, -0.03, 0.4]))
    return FrameCamera((4000, 3000), 0.01, 100.0, eo, **kw)


def test_nadir_camera_north_up():
    cam = FrameCamera((1001, 801), 0.01, 100.0, np.array([0, 0, 1000.0, 0, 0, 0]))
    # GSD = 0.01 mm / 100 mm * 1000 m = 0.1 m per pixel
    cr = cam.project(np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]]))
    np.testing.assert_allclose(cr[0], [500, 400])
    np.testing.assert_allclose(cr[1], [600, 400])  # east -> right
    np.testing.assert_allclose(cr[2], [500, 300])  # north -> up
    assert cam.ground_sample_distance == pytest.approx(0.1)


def test_rotation_is_orthonormal():
    m = rotation_matrix(0.1, -0.2, 1.3)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(m) == pytest.approx(1.0)


@pytest.mark.parametrize("distortion", [{}, {"k1": 2e-5, "k2": -1e-9, "p1": 1e-6, "p2": -2e-6}])
def test_project_then_ray_plane_round_trip(rng, distortion):
    cam = _cam(distortion=distortion)
    pts = np.column_stack([rng.uniform(900, 1100, 200), rng.uniform(1900, 2100, 200), rng.uniform(0, 30, 200)])
    cr = cam.project(pts)
    for i in range(0, 200, 37):
        plane = np.array([0, 0, 1.0, -pts[i, 2]])
        back = cam.intersect_plane(cr[i:i + 1], plane)
        np.testing.assert_allclose(back[0], pts[i], atol=1e-6)


def test_registration_error_grows_with_eo_covariance():
    pts = np.array([[1000.0, 2000.0, 10.0]])
    a = _cam().registration_error(pts)
    b = _cam(exterior_covariance=np.diag([0.25, 0.25, 0.25, 1e-8, 1e-8, 1e-8])).registration_error(pts)
    assert b[0] > a[0] > 0
    # LiDAR-only part: 0.48 m planimetric at ~0.08 m GSD is ~6 px per axis
    gsd = 0.01 / 100 * 790
    assert a[0] == pytest.approx(np.sqrt(2) * 0.48 / gsd, rel=0.1)


def test_ortho_camera_pixel_centres():
    cam = OrthoCamera((252, 252), (0.2, 0, 770549.8, 0, -0.2, 6277600.2))
    cr = cam.project(np.array([[770549.9, 6277600.1, 30.0]]))
    np.testing.assert_allclose(cr, [[0, 0]], atol=1e-9)
    np.testing.assert_allclose(cam.intersect_plane(cr, np.array([0, 0, 1.0, -30]))[0], [770549.9, 6277600.1, 30])
