"""Exterior orientation corrected from the line matches of the grouping (ours, beyond the seeds).

Seed 000 leaves the camera as it is: a registration error moves every
refined line in the image, and rays through the refined pixels then miss the
roof in object space by the same amount (3 px = 0.6 m at 0.2 m GSD).  Once
the grouping has matched the LiDAR sides and ridges to image lines, those
matches observe the orientation, as control lines do in a resection [1]_:
the projections of a LiDAR line's two end points should lie on its image
line.  With the signed distance ``r`` (px) of a projected end point to its
image line, measured along the outward normal of an outline side,

    r = n . (F(X; EO) - q) + b_k

where ``F`` is the collinearity projection, ``q`` a point of the image line
and ``b_k`` the outward growth of roof ``k`` (a LiDAR outline lies about
half a point spacing inside the roof edge; ridges carry no growth).  The
correction ``dEO`` (6 parameters, or ``X0, Y0, Z0, kappa`` when the tilts are
not determined) and the growths are found by Gauss-Newton, with

* the camera's EO covariance as a prior (when it has one), so few or
  badly spread lines cannot move the orientation beyond what it allows;
* outlier rejection (data snooping): after a least-squares solution, the
  lines whose RMS residual exceeds three robust sigmas (from the median,
  at least ``min_scale_px``) are dropped and the rest solved again until the
  kept set is stable, since a few percent of the matches are another edge
  (a wall foot, a neighbour's roof) a few pixels off.

Without a prior, the normal matrix of the orientation (the growths
eliminated, columns scaled to unit length) must have a reciprocal condition
number above ``min_rcond``; otherwise the tilts are held fixed (the reduced
set), and if that is still undetermined (all lines parallel, too few lines)
the correction is refused with a :class:`~rooftrace.errors.GeometryError`.

References
----------
.. [1] Habib, A., Morgan, M., Lee, Y.-R. (2002). Bundle adjustment with
   self-calibration using straight lines. The Photogrammetric Record 17(100),
   635-650. :doi:`10.1111/0031-868X.00211`
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rooftrace.errors import GeometryError, InputError
from rooftrace.image.line_resection import check_line_matches, line_equations, whitened_prior
from rooftrace.image.resection import wrap_angles

__all__ = ["OrientationCorrection", "correct_orientation", "EO_NAMES"]

log = logging.getLogger(__name__)

#: names of the exterior orientation parameters, in the camera file's order
EO_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
_REDUCED = (0, 1, 2, 5)  # the tilts held fixed: translation, height and rotation of the image


@dataclass
class OrientationCorrection:
    """Result of :func:`correct_orientation`.

    Attributes
    ----------
    camera : FrameCamera
        The camera with the corrected EO and its a-posteriori covariance.
    exterior : ndarray of shape (6,)
        Corrected ``[X0, Y0, Z0, omega, phi, kappa]`` (m, rad).
    delta : ndarray of shape (6,)
        ``exterior`` minus the input EO.
    covariance : ndarray of shape (6, 6)
        A-posteriori covariance (m², rad²); rows and columns of parameters
        held fixed are those of the prior (zero without one).
    parameters : tuple of str
        The parameters estimated.
    growth : ndarray of shape (K,)
        Outward growth (px) of each group of outline lines.
    weights : ndarray of shape (M,)
        1 for the lines kept, 0 for those rejected.
    residuals : ndarray of shape (M, 2)
        Signed distances (px) of the projected end points to their image
        lines, growth removed.
    rms : float
        RMS of the residuals of the kept lines (px).
    sigma0 : float
        A-posteriori standard deviation of unit weight.
    n_lines, n_inliers : int
    iterations : int
    """

    camera: object
    exterior: np.ndarray
    delta: np.ndarray
    covariance: np.ndarray
    parameters: tuple
    growth: np.ndarray
    weights: np.ndarray
    residuals: np.ndarray
    rms: float
    sigma0: float
    n_lines: int
    n_inliers: int
    iterations: int

    def std(self) -> np.ndarray:
        """Standard deviations (6,) of X0, Y0, Z0 (m) and omega, phi, kappa (rad)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


def _oriented_lines(image_lines: np.ndarray, outward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image lines ``n . p + c = 0`` (:func:`line_equations`), the normal turned outward where ``outward`` is given."""
    n, c = line_equations(image_lines)
    flip = np.isfinite(outward).all(axis=1) & (np.einsum("md,md->m", n, np.nan_to_num(outward)) < 0)
    n[flip] *= -1
    c[flip] *= -1
    return n, c


def _rcond(a: np.ndarray) -> float:
    """Reciprocal condition number of ``a^T a`` with the columns of ``a`` scaled to unit length."""
    norms = np.linalg.norm(a, axis=0)
    if not np.all(norms > 0):
        return 0.0
    s = np.linalg.svd(a / norms, compute_uv=False)
    return float((s[-1] / s[0]) ** 2)


def _eliminate(a_eo: np.ndarray, groups: np.ndarray, n_groups: int, w: np.ndarray, prior_b: float) -> np.ndarray:
    """The orientation's weighted design matrix with the growth columns projected out, for the rank test.

    Each roof's growth is a column of ones on its rows: eliminating it takes
    from each of those rows its weighted mean over the roof (damped by the
    growth prior ``prior_b``, in the same weighted units).
    """
    g = np.sqrt(w)
    a = a_eo * g[:, None]
    rows = np.flatnonzero(groups >= 0)
    if not len(rows) or not n_groups:
        return a
    k = groups[rows]
    sums = np.zeros((n_groups, a.shape[1]))
    np.add.at(sums, k, g[rows, None] * a[rows])
    norm = np.bincount(k, weights=g[rows] ** 2, minlength=n_groups) + prior_b
    out = a.copy()
    out[rows] -= g[rows, None] * sums[k] / norm[k, None]
    return out


def correct_orientation(camera, lines3d, image_lines, *, outward=None, groups=None, start=None, sigma_px: float = 1.0,
                        growth_sigma_px: float = 3.0, min_lines: int = 8, min_rcond: float = 1e-4,
                        min_scale_px: float = 0.7, reject_k: float = 3.0, parameters: str = "auto",
                        max_iterations: int = 30, max_rounds: int = 10,
                        tolerance: float = 1e-6) -> OrientationCorrection:
    """Correct a frame camera's exterior orientation from matched 3D and image lines (see the module notes).

    Parameters
    ----------
    camera : FrameCamera
        Interior orientation (fixed), starting EO and, when it has an
        ``exterior_covariance``, the prior.
    lines3d : ndarray of shape (M, 2, 3)
        Object-space lines (map CRS, m), e.g. LiDAR outline sides and ridges.
    image_lines : ndarray of shape (M, 2, 2)
        Their matched image lines (col, row), any part of the same line.
    outward : ndarray of shape (M, 2), optional
        Outward image normal of outline sides; NaN rows (ridges) and the
        default (none) have no growth.
    groups : ndarray of shape (M,) int, optional
        Roof of each line (0..K-1): one growth per roof for its outline
        sides; default: all lines one roof.
    start : ndarray of shape (6,), optional
        Starting EO (e.g. an earlier correction); the prior stays centred on
        the camera's own EO.  Default: the camera's EO.
    sigma_px : float or ndarray of shape (M,), default 1.0
        A-priori precision (px) of each match: the image line's and the
        projected object line's errors together.
    growth_sigma_px : float, default 3.0
        Prior standard deviation of a roof's growth around 0 (px).
    min_lines : int, default 8
        Fewest lines, and fewest inliers after the robust weighting.
    min_rcond : float, default 1e-4
        Without a prior, smallest reciprocal condition number of the scaled
        orientation normal matrix for a parameter set to be estimated.
    min_scale_px : float, default 0.7
        Smallest robust sigma (px) of a line's residual.
    reject_k : float, default 3.0
        Lines whose RMS residual exceeds ``reject_k`` robust sigmas (1.4826
        times the median over the kept lines) are rejected and the rest
        solved again, until the kept set no longer changes.
    parameters : {'auto', 'full', 'reduced'}, default 'auto'
        ``'full'``: all six; ``'reduced'``: ``X0, Y0, Z0, kappa``;
        ``'auto'``: all six with a prior, otherwise the full set when the
        lines determine it and the reduced set when they do not.
    max_iterations : int, default 30
        Gauss-Newton iterations per solve.
    max_rounds : int, default 10
        Rejection rounds.
    tolerance : float, default 1e-6
        Convergence on the step (m, and rad x 1000).

    Returns
    -------
    OrientationCorrection

    Raises
    ------
    InputError
        Not a frame camera, shapes that differ, non-finite values,
        degenerate image lines, an unknown ``parameters``.
    GeometryError
        Fewer than ``min_lines`` lines or inliers, or lines that do not
        determine even the reduced set (e.g. all parallel) without a prior.

    Examples
    --------
    >>> from rooftrace.image.camera import FrameCamera
    >>> cam = FrameCamera((2000, 2000), 0.012, 120.0, np.array([0, 0, 1000.0, 0.01, 0.0, 0.2]))
    >>> g = np.random.default_rng(0).uniform(-80, 80, (12, 2))
    >>> sq = np.array([[0, 0], [12, 0], [12, 9], [0, 9.0]])
    >>> lines = np.array([[[*(c + sq[i]), 8], [*(c + sq[(i + 1) % 4]), 8]] for c in g for i in range(4)])
    >>> px = cam.project(lines.reshape(-1, 3)).reshape(-1, 2, 2)
    >>> start = cam.with_exterior(cam.exterior + [0.5, -0.4, 0.0, 0.0, 0.0, 0.001])
    >>> res = correct_orientation(start, lines, px, parameters="reduced")
    >>> bool(np.abs(res.camera.project(lines.reshape(-1, 3)) - px.reshape(-1, 2)).max() < 1e-3)
    True
    """
    l3, l2 = check_line_matches(camera, lines3d, image_lines, "orientation correction")
    if parameters not in ("auto", "full", "reduced"):
        raise InputError(f"parameters must be 'auto', 'full' or 'reduced', got {parameters!r}")
    m = len(l3)
    sig = np.broadcast_to(np.asarray(sigma_px, float), (m,)).copy() if m else np.zeros(0)
    if not np.all(sig > 0):
        raise InputError("sigma_px must be positive")
    if m < min_lines:
        raise GeometryError(f"orientation correction needs at least {min_lines} matched lines, got {m}")
    out = np.full((m, 2), np.nan) if outward is None else np.asarray(outward, float).reshape(m, 2)
    grp = np.zeros(m, int) if groups is None else np.asarray(groups, int).reshape(m)
    grown = np.isfinite(out).all(axis=1)
    gid = np.full(m, -1)
    keys, inv = np.unique(grp[grown], return_inverse=True)
    gid[grown] = inv
    n_groups = len(keys)
    normal, offset = _oriented_lines(l2, out)
    xyz = l3.reshape(-1, 3)
    nn, cc, gg = np.repeat(normal, 2, axis=0), np.repeat(offset, 2), np.repeat(gid, 2)
    eo0 = np.asarray(camera.exterior, float)
    prior = getattr(camera, "exterior_covariance", None)
    has_prior = prior is not None and np.all(np.isfinite(prior)) and np.any(np.diag(np.asarray(prior)) > 0)
    p_rows = None
    if has_prior:
        p_rows = whitened_prior(prior)  # in units of one sigma_px observation

    def model(eo, b):
        r = np.einsum("kd,kd->k", nn, camera.project(xyz, eo)) + cc
        return r + np.where(gg >= 0, b[np.maximum(gg, 0)] if n_groups else 0.0, 0.0)

    def eo_jacobian(eo):
        j_eo, _ = camera.with_exterior(eo).jacobians(xyz)
        return np.einsum("kd,kdj->kj", nn, j_eo)

    # which parameters: with a prior all six; without, the six if the lines determine them
    a0 = eo_jacobian(eo0 if start is None else np.asarray(start, float).reshape(6))
    if parameters == "auto":
        if has_prior:
            free = tuple(range(6))
        else:
            a_el = _eliminate(a0, gg, n_groups, np.repeat(sig, 2) ** -2.0, 1.0 / growth_sigma_px**2)
            free = tuple(range(6)) if _rcond(a_el) >= min_rcond else _REDUCED
    else:
        free = tuple(range(6)) if parameters == "full" else _REDUCED
    if not has_prior:
        a_el = _eliminate(a0[:, list(free)], gg, n_groups, np.repeat(sig, 2) ** -2.0, 1.0 / growth_sigma_px**2)
        if _rcond(a_el) < min_rcond:
            raise GeometryError(
                f"the {m} matched lines do not determine the orientation ({', '.join(EO_NAMES[i] for i in free)}): "
                "too few, all parallel or all in one spot; give the camera an exterior_covariance")
    nf = len(free)
    n_par = nf + n_groups
    scale = np.array([1.0, 1.0, 1.0, 1e3, 1e3, 1e3])[list(free)]

    def system(eo, b, w_obs):
        """Whitened design matrix and residual vector (observations, growth prior, EO prior)."""
        a = np.zeros((2 * m, n_par))
        a[:, :nf] = eo_jacobian(eo)[:, list(free)]
        if n_groups:
            rows = np.flatnonzero(gg >= 0)
            a[rows, nf + gg[rows]] = 1.0
        sw = np.sqrt(w_obs) / np.repeat(sig, 2)
        blocks_a, blocks_r = [a * sw[:, None]], [model(eo, b) * sw]
        if n_groups:
            blocks_a.append(np.hstack([np.zeros((n_groups, nf)), np.eye(n_groups) / growth_sigma_px]))
            blocks_r.append(b / growth_sigma_px)
        if p_rows is not None:
            pa = np.zeros((6, n_par))
            pa[:, :nf] = p_rows[:, list(free)]
            blocks_a.append(pa)
            blocks_r.append(p_rows @ (eo - eo0))
        return np.vstack(blocks_a), np.concatenate(blocks_r)

    def solve(eo, b, w_line):
        """Gauss-Newton to convergence with fixed line weights; returns (eo, b, iterations) or None."""
        for it in range(1, max_iterations + 1):
            a, r = system(eo, b, np.repeat(w_line, 2))
            step, *_ = np.linalg.lstsq(a, -r, rcond=None)
            eo = eo.copy()
            eo[list(free)] += step[:nf]
            b = b + step[nf:]
            if np.max(np.abs(step[:nf]) * scale) < tolerance:
                return eo, b, it
        return None

    eo, b = (eo0.copy() if start is None else np.asarray(start, float).reshape(6).copy()), np.zeros(n_groups)
    iterations = 0
    # a robust start: least absolute residuals by reweighting (w = 1 / |r|), so that a third of the lines
    # off by several pixels cannot drag the first solution, and the rejection below sees them
    w_line = np.ones(m)
    for _ in range(10):
        out_ = solve(eo, b, w_line)
        if out_ is None:
            break
        eo, b, its = out_
        iterations += its
        r_line = np.sqrt(np.mean(model(eo, b).reshape(m, 2) ** 2, axis=1)) / sig
        w_line = 1.0 / np.sqrt(r_line**2 + (min_scale_px / sig) ** 2)
        w_line /= w_line.max()
    w_line = np.ones(m)
    # then reject the lines beyond k robust sigmas and solve again until the kept set is stable (data
    # snooping): deterministic and convergent, where reweighting every step can oscillate
    for k_round in range(max_rounds + 1):
        if k_round:
            out_ = solve(eo, b, w_line)
            if out_ is None:
                raise GeometryError(f"orientation correction did not converge in {max_iterations} iterations")
            eo, b, its = out_
            iterations += its
        if w_line.sum() < min_lines or k_round == max_rounds:
            break  # too few left (refused below), or the last solve of a set that kept changing
        # residuals in units of each line's sigma
        r_line = np.sqrt(np.mean(model(eo, b).reshape(m, 2) ** 2, axis=1)) / sig
        sigma = max(1.4826 * float(np.median(r_line[w_line > 0])), min_scale_px / float(np.median(sig)))
        keep = (r_line <= reject_k * sigma).astype(float)
        if k_round and np.array_equal(keep, w_line):
            break
        w_line = keep
    inliers = w_line > 0.5
    if inliers.sum() < min_lines:
        raise GeometryError(f"orientation correction: only {int(inliers.sum())} of {m} matched lines agree "
                            f"(at least {min_lines} needed)")
    a, r = system(eo, b, np.repeat(w_line, 2))
    redundancy = max(2 * float(w_line.sum()) + (6 if has_prior else 0) - nf, 1.0)
    sigma0 = float(np.sqrt(r @ r / redundancy))
    try:
        # sigma0 below 1 would claim more than the a-priori line precision: not trusted
        cov_free = np.linalg.inv(a.T @ a)[:nf, :nf] * max(sigma0, 1.0) ** 2
    except np.linalg.LinAlgError:
        raise GeometryError("the matched lines do not determine the orientation") from None
    cov = np.zeros((6, 6)) if not has_prior else np.asarray(prior, float).copy()
    idx = np.array(free)
    cov[np.ix_(idx, idx)] = cov_free
    if has_prior:
        cov[np.ix_(idx, np.setdiff1d(np.arange(6), idx))] = 0.0
        cov[np.ix_(np.setdiff1d(np.arange(6), idx), idx)] = 0.0
    cov = 0.5 * (cov + cov.T)
    res = model(eo, b).reshape(m, 2)
    rms = float(np.sqrt(np.mean(res[inliers] ** 2)))
    eo = wrap_angles(eo)
    log.info("orientation correction: %d lines (%d inliers), %s, rms %.2f px, shift %s", m, int(inliers.sum()),
             ",".join(EO_NAMES[i] for i in free), rms, np.round(eo - eo0, 5).tolist())
    return OrientationCorrection(camera.with_exterior(eo, cov), eo, eo - eo0, cov,
                                 tuple(EO_NAMES[i] for i in free), b, w_line, res, rms, sigma0, m,
                                 int(inliers.sum()), iterations)

