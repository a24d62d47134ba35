"""Exterior orientation from straight-line correspondences (beyond the papers).

Once the refinement has matched LiDAR lines to image lines, each match says
that the projections of the 3D endpoints lie on the image line, two
equations per line, and the exterior orientation of
:mod:`rooftrace.image.resection` is corrected by least squares, optionally
with the camera's EO covariance as a prior.

References
----------
.. [1] Habib, A., Morgan, M., Lee, Y.-R. (2002). Bundle adjustment with
   self-calibration using straight lines. The Photogrammetric Record 17(100),
   635-650. :doi:`10.1111/0031-868X.00211`
"""

from __future__ import annotations

import logging

import numpy as np

from rooftrace.errors import GeometryError, InputError
from rooftrace.image.resection import Resection, ResectionOptions, wrap_angles

__all__ = ["line_resection", "check_line_matches", "line_equations", "whitened_prior"]

log = logging.getLogger(__name__)


def line_equations(image_lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (M, 2) and offsets (M,) of the image lines n . p + c = 0."""
    d = image_lines[:, 1] - image_lines[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    if np.any(length < 1e-9):
        raise InputError("image lines must have two distinct endpoints")
    n = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    return n, -np.einsum("md,md->m", n, image_lines[:, 0])


def whitened_prior(covariance: np.ndarray) -> np.ndarray:
    """Rows ``L^-1`` (6, 6) with ``covariance = L L^T``: ``L^-1 (eo - eo0)`` is an EO prior in units of one observation sigma."""
    return np.linalg.inv(np.linalg.cholesky(np.asarray(covariance, float) + 1e-18 * np.eye(6)))


def check_line_matches(camera, lines3d, image_lines, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Checked ``(M, 2, 3)`` object and ``(M, 2, 2)`` image lines of a frame camera, as float arrays.

    Raises
    ------
    InputError
        Not a frame camera (``what`` names the caller), shapes that differ,
        or non-finite coordinates.
    """
    if getattr(camera, "kind", None) != "frame":
        raise InputError(f"{what} needs a frame camera (an orthophoto has no exterior orientation)")
    l3 = np.asarray(lines3d, float)
    l2 = np.asarray(image_lines, float)
    if l3.ndim != 3 or l3.shape[1:] != (2, 3) or l2.shape != (len(l3), 2, 2):
        raise InputError(f"need (M, 2, 3) object lines and (M, 2, 2) image lines, got {l3.shape} and {l2.shape}")
    if not (np.isfinite(l3).all() and np.isfinite(l2).all()):
        raise InputError("line coordinates must be finite numbers")
    return l3, l2


def line_resection(camera, lines3d, image_lines, *, weights=None, use_prior: bool = True,
                   options: ResectionOptions | None = None) -> Resection:
    """Correct the exterior orientation from matched 3D and image lines.

    Each 3D segment's two endpoints must project onto the (infinite) image
    line matched to it; the signed distances (px) are the residuals, so the
    image lines may be shorter, longer or shifted along the 3D ones.  With
    ``use_prior`` the camera's exterior orientation enters as an observation
    with its covariance, which keeps the solution stable when the lines are
    few or nearly parallel.

    Parameters
    ----------
    camera : FrameCamera
        Interior orientation and the starting (and prior) exterior orientation.
    lines3d : ndarray of shape (M, 2, 3)
        Object-space segments (e.g. LiDAR outline sides).
    image_lines : ndarray of shape (M, 2, 2)
        Their matches in the image (col, row), e.g. the refined lines.
    weights : ndarray of shape (M,), optional
        Relative weights of the lines (1 = a line measured to 1 px).
    use_prior : bool, default True
        Use the camera's ``exterior_covariance`` as a prior (ignored if None).
    options : ResectionOptions, optional

    Returns
    -------
    Resection
        ``residuals`` has shape (M, 2): the endpoints' distances to their lines (px).

    Raises
    ------
    InputError
        Shapes that differ, degenerate image lines, or fewer than 3 lines
        without a prior.
    GeometryError
        No convergence or an undetermined orientation.

    Examples
    --------
    >>> from rooftrace.image.camera import FrameCamera
    >>> cam = FrameCamera((1000, 1000), 0.01, 100.0, np.array([0, 0, 500.0, 0.01, 0.0, 0.2]))
    >>> sq = np.array([[0, 0, 5], [20, 0, 5], [20, 15, 8], [0, 15, 8.0]])
    >>> lines = np.stack([sq, np.roll(sq, -1, axis=0)], axis=1)
    >>> start = cam.with_exterior(cam.exterior + [1.0, -1.0, 2.0, 0.0, 0.0, 0.002])
    >>> res = line_resection(start, lines, cam.project(lines.reshape(-1, 3)).reshape(-1, 2, 2), use_prior=False)
    >>> bool(np.abs(cam.project(sq, res.exterior) - cam.project(sq)).max() < 1e-6)
    True
    """
    opt = options or ResectionOptions()
    l3, l2 = check_line_matches(camera, lines3d, image_lines, "line resection")
    w = np.ones(len(l3)) if weights is None else np.broadcast_to(np.asarray(weights, float), (len(l3),))
    prior = camera.exterior_covariance if use_prior else None
    if prior is None and len(l3) < 3:
        raise InputError(f"line resection without a prior needs at least 3 lines, got {len(l3)}")
    n, c = line_equations(l2)
    xyz = l3.reshape(-1, 3)
    nn = np.repeat(n, 2, axis=0)
    cc = np.repeat(c, 2)
    sw = np.sqrt(np.repeat(w, 2))
    eo0 = np.asarray(camera.exterior, float)
    if prior is not None:
        p_rows = whitened_prior(prior)

    def residual(eo):
        r = (np.einsum("kd,kd->k", nn, camera.project(xyz, eo)) + cc) * sw
        if prior is not None:
            r = np.concatenate([r, p_rows @ (eo - eo0)])
        return r

    def jacobian(eo):
        j_eo, _ = camera.with_exterior(eo).jacobians(xyz)
        a = np.einsum("kd,kdj->kj", nn, j_eo) * sw[:, None]
        return np.vstack([a, p_rows]) if prior is not None else a

    scale = np.array([1.0, 1.0, 1.0, 1e3, 1e3, 1e3])
    eo = eo0.copy()
    r = residual(eo)
    converged = False
    for it in range(1, opt.max_iterations + 1):  # noqa: B007 (the count is reported after the loop)
        a = jacobian(eo)
        if not (np.isfinite(a).all() and np.isfinite(r).all()):
            break
        # minimise |r + a step|^2 (the residual is model minus observation here)
        step, *_ = np.linalg.lstsq(a, -r, rcond=None)
        for _ in range(20):
            trial = wrap_angles(eo + step)
            r_trial = residual(trial)
            if np.isfinite(r_trial).all() and (r_trial @ r_trial <= r @ r * (1 + 1e-12)
                                               or np.max(np.abs(step) * scale) < opt.tolerance):
                break
            step = step / 2
        eo, r = trial, r_trial
        if np.max(np.abs(step) * scale) < opt.tolerance:
            converged = True
            break
    if not converged:
        raise GeometryError(f"line resection did not converge in {opt.max_iterations} iterations")
    a = jacobian(eo)
    n_obs = 2 * len(l3) + (6 if prior is not None else 0)
    redundancy = n_obs - 6
    vtv = float(r @ r)
    sigma0 = np.sqrt(vtv / redundancy) if redundancy > 0 else opt.sigma_px
    try:
        cov = sigma0**2 * np.linalg.inv(a.T @ a)
    except np.linalg.LinAlgError:
        raise GeometryError("the lines do not determine the orientation (too few or all parallel)") from None
    res = (r[: 2 * len(l3)] / sw).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(res**2)))
    log.info("line resection: %d lines, %d iterations, rms %.3f px, sigma0 %.3f", len(l3), it, rms, sigma0)
    cov = 0.5 * (cov + cov.T)
    return Resection(camera.with_exterior(eo, cov), eo, cov, float(sigma0), res, rms, it, redundancy)
