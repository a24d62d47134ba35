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


def _building_lines(rng, n_buildings=4):
    """Outline sides and ridges of a few gable houses at different places and heights (M, 2, 3)."""
    lines = []
    for _ in range(n_buildings):
        c = rng.uniform([850, 1850], [1150, 2150])
        a = rng.uniform(0, np.pi)
        u, v = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        h = rng.uniform(5, 20)
        corners = [c - 8 * u - 5 * v, c + 8 * u - 5 * v, c + 8 * u + 5 * v, c - 8 * u + 5 * v]
        ring = [np.array([*p, h]) for p in corners]
        lines += [[ring[i], ring[(i + 1) % 4]] for i in range(4)]
        lines.append([np.array([*(c - 8 * u), h + 3]), np.array([*(c + 8 * u), h + 3])])
    return np.array(lines)


def test_line_resection_recovers_the_orientation_from_partial_lines(rng):
    from rooftrace.image.line_resection import line_resection

    truth = _camera()
    lines = _building_lines(rng)
    px = truth.project(lines.reshape(-1, 3)).reshape(-1, 2, 2)
    # image lines cover other parts of the same infinite lines: shorter, shifted along
    t = rng.uniform(-0.3, 0.3, (len(px), 2)) + [0.0, 1.0]
    image = px[:, :1] + t[..., None] * (px[:, 1:] - px[:, :1])
    start = truth.with_exterior(TRUE_EO + [4, -3, 5, 0.003, -0.002, 0.004])
    res = line_resection(start, lines, image, use_prior=False)
    np.testing.assert_allclose(res.exterior, TRUE_EO, atol=1e-5)
    assert res.rms < 1e-6 and res.residuals.shape == (len(lines), 2)


def test_line_resection_with_noise_and_prior_improves_a_perturbed_camera(rng):
    from rooftrace.image.line_resection import line_resection

    truth = _camera()
    lines = _building_lines(rng, 6)
    image = truth.project(lines.reshape(-1, 3)).reshape(-1, 2, 2) + rng.normal(0, 0.3, (len(lines), 2, 2))
    prior = np.diag([2.0, 2.0, 2.0, 2e-3, 2e-3, 2e-3]) ** 2
    start = truth.with_exterior(TRUE_EO + [2, -2, 2, 0.002, -0.002, 0.002], prior)
    before = np.abs(start.project(lines.reshape(-1, 3)) - truth.project(lines.reshape(-1, 3))).max()
    res = line_resection(start, lines, image)
    after = np.abs(res.camera.project(lines.reshape(-1, 3)) - truth.project(lines.reshape(-1, 3))).max()
    assert before > 5 and after < 1.0
    assert res.redundancy == 2 * len(lines)
    assert np.all(np.abs(res.exterior - TRUE_EO) < 4 * res.std)


def test_line_resection_bad_input(rng):
    from rooftrace.image.line_resection import line_resection

    cam = _camera()
    lines = _building_lines(rng, 1)
    px = cam.project(lines.reshape(-1, 3)).reshape(-1, 2, 2)
    with pytest.raises(InputError, match="at least 3 lines"):
        line_resection(cam, lines[:2], px[:2])
    with pytest.raises(InputError, match="distinct"):
        line_resection(cam, lines, np.repeat(px[:, :1], 2, axis=1))
    with pytest.raises(InputError, match=r"\(M, 2, 3\)"):
        line_resection(cam, lines, px[:3])
    with pytest.raises(InputError, match="frame camera"):
        line_resection(OrthoCamera((10, 10), (1, 0, 0, 0, -1, 0)), lines, px)
