import numpy as np
import pytest

from rooftrace.errors import GeometryError, InputError
from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.image.resection import ResectionOptions, initial_exterior, space_resection

TRUE_EO = np.array([1000.0, 2000.0, 1200.0, 0.03, -0.02, 0.6])


def _camera(eo=TRUE_EO, **kw):
    return FrameCamera((4000, 3000), 0.01, 100.0, np.asarray(eo, float), **kw)


def _gcps(rng, n=8):
    xy = np.column_stack([rng.uniform(800, 1200, n), rng.uniform(1850, 2150, n)])
    return np.column_stack([xy, rng.uniform(0, 40, n)])


@pytest.mark.parametrize("distortion", [{}, {"k1": 1e-5, "p1": 2e-6}])
def test_exact_gcps_recover_the_orientation(rng, distortion):
    truth = _camera(distortion=distortion)
    xyz = _gcps(rng)
    start = truth.with_exterior(TRUE_EO + [30, -20, 50, 0.02, 0.03, -0.1])
    res = space_resection(start, xyz, truth.project(xyz))
    np.testing.assert_allclose(res.exterior, TRUE_EO, atol=1e-6)
    assert res.rms < 1e-6 and res.redundancy == 10
    assert res.camera.exterior_covariance is res.covariance or np.allclose(res.camera.exterior_covariance, res.covariance)


def test_noisy_gcps_recover_the_orientation_within_its_precision(rng):
    truth = _camera()
    xyz = _gcps(rng, 12)
    obs = truth.project(xyz) + rng.normal(0, 0.5, (12, 2))
    res = space_resection(truth.with_exterior(TRUE_EO + [5, 5, 5, 0, 0, 0]), xyz, obs)
    assert 0.25 < res.sigma0 < 0.9  # estimates the 0.5 px noise with 18 degrees of freedom
    z = (res.exterior - TRUE_EO) / res.std
    assert np.all(np.abs(z) < 4)
    np.testing.assert_allclose(res.covariance, res.covariance.T)
    assert np.all(np.linalg.eigvalsh(res.covariance) > 0)


def test_covariance_matches_monte_carlo_scatter(rng):
    truth = _camera()
    xyz = _gcps(rng, 10)
    clean = truth.project(xyz)
    sols, covs = [], []
    for _ in range(60):
        res = space_resection(truth, xyz, clean + rng.normal(0, 1.0, clean.shape),
                              options=ResectionOptions(sigma_px=1.0))
        sols.append(res.exterior)
        covs.append(res.covariance / res.sigma0**2)  # the a-priori sigma is 1 px
    emp = np.std(sols, axis=0)
    pred = np.sqrt(np.diag(np.mean(covs, axis=0)))
    np.testing.assert_allclose(emp / pred, 1.0, atol=0.35)


def test_far_start_falls_back_to_a_vertical_start(rng):
    truth = _camera()
    xyz = _gcps(rng)
    bad = truth.with_exterior(np.array([0.0, 0.0, 10.0, 0.0, 0.0, 3.0]))
    res = space_resection(bad, xyz, truth.project(xyz))
    np.testing.assert_allclose(res.exterior, TRUE_EO, atol=1e-5)
    start = initial_exterior(truth, xyz, truth.project(xyz))
    assert np.hypot(*(start[:2] - TRUE_EO[:2])) < 80 and abs(start[5] - TRUE_EO[5]) < 0.05


def test_three_gcps_have_no_redundancy(rng):
    truth = _camera(eo=[1000.0, 2000.0, 1200.0, 0, 0, 0.6])
    xyz = np.array([[900.0, 1900, 10], [1100, 1950, 0], [1000, 2100, 30]])
    res = space_resection(truth.with_exterior(truth.exterior + [3, 3, 3, 0, 0, 0.01]), xyz, truth.project(xyz),
                          options=ResectionOptions(sigma_px=0.5))
    assert res.redundancy == 0 and res.sigma0 == 0.5
    np.testing.assert_allclose(truth.project(xyz, res.exterior), truth.project(xyz), atol=1e-6)


def test_bad_gcps(rng):
    cam = _camera()
    xyz = _gcps(rng)
    cr = cam.project(xyz)
    with pytest.raises(InputError, match="at least 3 GCPs"):
        space_resection(cam, xyz[:2], cr[:2])
    with pytest.raises(InputError, match="finite"):
        space_resection(cam, np.where(np.arange(8)[:, None] == 1, np.nan, xyz), cr)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        space_resection(cam, xyz, cr[:5])
    line = np.column_stack([np.linspace(900, 1100, 6), np.linspace(1900, 2100, 6), np.zeros(6)])
    with pytest.raises(GeometryError, match="collinear"):
        space_resection(cam, line, cam.project(line))
    with pytest.raises(InputError, match="frame camera"):
        space_resection(OrthoCamera((10, 10), (1, 0, 0, 0, -1, 0)), xyz, cr)
    # image coordinates that no orientation explains
    with pytest.raises(GeometryError, match="did not converge"):
        space_resection(cam, xyz, rng.uniform(0, 4000, cr.shape), options=ResectionOptions(max_iterations=5))
