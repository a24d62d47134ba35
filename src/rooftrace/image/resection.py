"""Space resection: the exterior orientation of a frame image from ground control points.

Least squares on the collinearity equations (Gauss-Newton): with the
observations ``l`` (pixel col, row of each GCP), the model ``F(EO)`` (the
camera's projection) and its Jacobian ``A = dF/dEO`` (2N x 6), iterate
``dEO = (A^T A)^-1 A^T (l - F(EO))`` until the step is negligible.  The
precision of the result is ``Sigma_EO = sigma0^2 (A^T A)^-1`` with the
a-posteriori variance of unit weight ``sigma0^2 = v^T v / (2N - 6)`` (px^2),
all pixel observations having equal weight.  Seed 003 orients its image this
way before projecting the LiDAR lines.

The interior orientation (focal length, principal point, pixel size,
distortion) is held fixed.  EO order and units follow the camera file:
``[X0, Y0, Z0, omega, phi, kappa]`` in CRS units and radians.

:func:`rooftrace.image.line_resection.line_resection` does the same from
straight-line correspondences (beyond the papers).

References
----------
.. [1] Wolf, P. R., Dewitt, B. A., Wilkinson, B. E. (2014). Elements of
   Photogrammetry, 4th ed., ch. 11 (space resection by collinearity).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rooftrace.errors import GeometryError, InputError

__all__ = ["ResectionOptions", "Resection", "space_resection", "initial_exterior", "wrap_angles"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ResectionOptions:
    """Options of the space resection (section ``[resection]``).

    Attributes
    ----------
    max_iterations : int, default 30
        Gauss-Newton iterations before giving up.
    tolerance : float, default 1e-6
        Convergence: the largest step of X0, Y0, Z0 in metres and of the
        angles in radians x 1000 (so 1e-6 m and 1e-9 rad).
    sigma_px : float, default 1.0
        A-priori standard deviation of a GCP's image measurement (px); used
        for the covariance when there is no redundancy (3 GCPs).
    """

    section = "resection"

    max_iterations: int = 30
    tolerance: float = 1e-6
    sigma_px: float = 1.0

    def __post_init__(self):
        if self.max_iterations < 1:
            raise ValueError(f"resection.max_iterations must be >= 1, got {self.max_iterations}")
        if not self.tolerance > 0 or not self.sigma_px > 0:
            raise ValueError("resection.tolerance and resection.sigma_px must be positive")


@dataclass
class Resection:
    """Result of :func:`space_resection`.

    Attributes
    ----------
    camera : FrameCamera
        The input camera with the solved exterior orientation and its covariance.
    exterior : ndarray of shape (6,)
    covariance : ndarray of shape (6, 6)
        ``sigma0^2 (A^T A)^-1`` (m^2, rad^2).
    sigma0 : float
        A-posteriori standard deviation of unit weight (px); the a-priori
        ``sigma_px`` when there is no redundancy.
    residuals : ndarray of shape (N, 2)
        Observed minus projected (col, row), px.
    rms : float
        Root mean square of the residual vector lengths (px).
    iterations : int
    redundancy : int
        ``2N - 6``.
    """

    camera: object
    exterior: np.ndarray
    covariance: np.ndarray
    sigma0: float
    residuals: np.ndarray
    rms: float
    iterations: int
    redundancy: int

    @property
    def std(self) -> np.ndarray:
        """Standard deviations (6,) of X0, Y0, Z0 (m) and omega, phi, kappa (rad)."""
        return np.sqrt(np.diag(self.covariance))


def initial_exterior(camera, xyz, cr) -> np.ndarray:
    """A near-vertical starting EO from a 2D similarity between ground and photo coordinates.

    For a vertical photo ``x = s (cos k dX + sin k dY)``, ``y = s (-sin k dX + cos k dY)``
    with the scale ``s = f / (Z0 - Zmean)``; fitting the similarity gives
    ``kappa``, ``X0, Y0`` (the ground point imaged at the principal point)
    and ``Z0``.  Good enough to start Gauss-Newton for tilts of a few degrees.
    """
    xyz = np.asarray(xyz, float)
    photo = camera.undistort(camera.pixel_to_photo(np.asarray(cr, float)))
    photo = photo - np.asarray(camera.principal_point_mm, float)
    n = len(xyz)
    a = np.zeros((2 * n, 4))
    a[0::2] = np.column_stack([xyz[:, 0], xyz[:, 1], np.ones(n), np.zeros(n)])
    a[1::2] = np.column_stack([xyz[:, 1], -xyz[:, 0], np.zeros(n), np.ones(n)])
    (p, q, c, d), *_ = np.linalg.lstsq(a, photo.reshape(-1), rcond=None)
    s = float(np.hypot(p, q))
    if not s > 0:
        raise GeometryError("GCPs are degenerate: their ground and image positions give no scale")
    kappa = float(np.arctan2(q, p))
    # the principal point (x = y = 0) is the ground point solving [[p, q], [-q, p]] [X, Y] = -[c, d]
    x0, y0 = np.linalg.solve(np.array([[p, q], [-q, p]]), -np.array([c, d]))
    z0 = float(xyz[:, 2].mean()) + camera.focal_length_mm / s
    return np.array([x0, y0, z0, 0.0, 0.0, kappa])


def wrap_angles(eo: np.ndarray) -> np.ndarray:
    """A copy of the EO (6,) with omega, phi, kappa wrapped to [-pi, pi)."""
    out = np.array(eo, float)
    out[3:] = np.mod(out[3:] + np.pi, 2 * np.pi) - np.pi
    return out


def _gauss_newton(camera, xyz, obs, eo, opt):
    """Returns (eo, A, residuals, iterations, converged)."""
    scale = np.array([1.0, 1.0, 1.0, 1e3, 1e3, 1e3])
    res = obs - camera.project(xyz, eo)
    ssr = float(np.sum(res**2)) if np.isfinite(res).all() else np.inf
    for it in range(1, opt.max_iterations + 1):
        j_eo, _ = camera.with_exterior(eo).jacobians(xyz)
        a = j_eo.reshape(-1, 6)
        if not np.isfinite(a).all() or not np.isfinite(res).all():
            return eo, a, res, it, False
        step, *_ = np.linalg.lstsq(a, res.reshape(-1), rcond=None)
        # halve the step while it makes things worse (far starts overshoot)
        for _ in range(20):
            trial = wrap_angles(eo + step)
            r_trial = obs - camera.project(xyz, trial)
            s_trial = float(np.sum(r_trial**2)) if np.isfinite(r_trial).all() else np.inf
            if s_trial <= ssr * (1 + 1e-12) or np.max(np.abs(step) * scale) < opt.tolerance:
                break
            step = step / 2
        eo, res, ssr = trial, r_trial, s_trial
        if np.max(np.abs(step) * scale) < opt.tolerance:
            j_eo, _ = camera.with_exterior(eo).jacobians(xyz)
            return eo, j_eo.reshape(-1, 6), res, it, np.isfinite(ssr)
    return eo, a, res, opt.max_iterations, False


def space_resection(camera, xyz, cr, *, exterior0=None, options: ResectionOptions | None = None) -> Resection:
    """Exterior orientation and its covariance from ground control points.

    Parameters
    ----------
    camera : FrameCamera
        Interior orientation (held fixed); its exterior orientation is the
        starting value unless ``exterior0`` is given.
    xyz : ndarray of shape (N, 3)
        GCP object coordinates (CRS units), N >= 3, not collinear.
    cr : ndarray of shape (N, 2)
        Their measured pixels (col, row), centres at integers.
    exterior0 : ndarray of shape (6,), optional
        Starting EO.  If Gauss-Newton does not converge from it, a vertical
        start from :func:`initial_exterior` is tried.
    options : ResectionOptions, optional

    Returns
    -------
    Resection

    Raises
    ------
    InputError
        Fewer than 3 GCPs, shapes that differ, or non-finite values.
    GeometryError
        No convergence (bad start, collinear GCPs, wrong interior orientation).

    Examples
    --------
    >>> from rooftrace.image.camera import FrameCamera
    >>> cam = FrameCamera((1000, 1000), 0.01, 100.0, np.array([10.0, 20.0, 900.0, 0.01, -0.02, 0.3]))
    >>> g = np.array([[0, 0, 0], [60, 0, 5], [0, 70, 2], [70, 70, 9], [30, 40, 20.0]])
    >>> start = cam.with_exterior(np.array([0, 0, 800.0, 0, 0, 0]))
    >>> res = space_resection(start, g, cam.project(g))
    >>> np.allclose(res.exterior, cam.exterior, atol=1e-6), res.rms < 1e-6
    (True, True)
    """
    opt = options or ResectionOptions()
    if getattr(camera, "kind", None) != "frame":
        raise InputError("space resection needs a frame camera (an orthophoto has no exterior orientation)")
    xyz = np.asarray(xyz, float)
    obs = np.asarray(cr, float)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or obs.shape != (len(xyz), 2):
        raise InputError(f"GCPs need (N, 3) ground and (N, 2) image coordinates, got {xyz.shape} and {obs.shape}")
    if len(xyz) < 3:
        raise InputError(f"space resection needs at least 3 GCPs, got {len(xyz)}")
    if not (np.isfinite(xyz).all() and np.isfinite(obs).all()):
        raise InputError("GCP coordinates must be finite numbers")
    centred = xyz[:, :2] - xyz[:, :2].mean(0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[-1] < 1e-6 * max(sv[0], 1e-12):
        raise GeometryError("GCPs are collinear in plan view: the orientation is undetermined")

    starts = [np.asarray(camera.exterior if exterior0 is None else exterior0, float)]
    try:
        starts.append(initial_exterior(camera, xyz, obs))
    except (GeometryError, np.linalg.LinAlgError):
        pass
    for k, eo0 in enumerate(starts):
        eo, a, res, iterations, converged = _gauss_newton(camera, xyz, obs, eo0, opt)
        if converged:
            break
        log.info("resection start %d did not converge after %d iterations", k, iterations)
    else:
        raise GeometryError(
            f"space resection did not converge in {opt.max_iterations} iterations; check the GCPs (X, Y, Z vs col, row), "
            "the interior orientation, and give a closer starting exterior orientation"
        )
    n_obs = 2 * len(xyz)
    redundancy = n_obs - 6
    vtv = float(np.sum(res**2))
    sigma0 = np.sqrt(vtv / redundancy) if redundancy > 0 else opt.sigma_px
    if redundancy == 0:
        log.warning("3 GCPs give no redundancy: covariance from the a-priori sigma of %.2f px", opt.sigma_px)
    n = a.T @ a
    try:
        cov = sigma0**2 * np.linalg.inv(n)
    except np.linalg.LinAlgError:
        raise GeometryError("the normal matrix is singular: GCP geometry does not determine the orientation") from None
    cov = 0.5 * (cov + cov.T)
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    log.info("resection: %d GCPs, %d iterations, rms %.3f px, sigma0 %.3f px", len(xyz), iterations, rms, sigma0)
    return Resection(camera.with_exterior(eo, cov), eo, cov, float(sigma0), res, rms, iterations, redundancy)
