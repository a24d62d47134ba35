"""Put the selected image lines back together, then back into object space.

Image space (Marcato & Dal Poz §2.4): along the topology of the projected roof, two
lines meet at their intersection; three or more (ridge junctions, a hip at an
outline corner) at the least-squares point minimising the squared
perpendicular distances to all of them (the paper's parametric adjustment,
unweighted).  A line end that meets nothing is the projection of its
projected reference end onto the selected line.

Object space (beyond the paper): each junction's pixel is turned into a ray
and intersected with the roof plane it lies on - for an outline vertex the
roof plane through the LiDAR vertex (the eave of that face), for ridge ends
one of the ridge's two planes - with a horizontal plane through the LiDAR
point as the fallback when no plane fits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rooftrace.grouping.topology import RoofTopology

__all__ = ["ImageReconstruction", "reconstruct_image", "junction_planes", "ridge_lines", "to_object_space"]


@dataclass(frozen=True)
class ImageReconstruction:
    """Refined pixels of one roof.

    Attributes
    ----------
    points : ndarray of shape (J, 2)
        Pixel (col, row) of every junction of the topology.
    moved : ndarray of shape (J,) bool
        False where the reconstruction was refused (degenerate lines, or a
        shift beyond ``max_shift``) and the projected point was kept.
    lines : ndarray of shape (M, 2, 2)
        Refined end points of every line.
    """

    points: np.ndarray
    moved: np.ndarray
    lines: np.ndarray


def _unit_normal(line: np.ndarray) -> tuple[np.ndarray, float]:
    d = line[1] - line[0]
    d = d / max(np.linalg.norm(d), 1e-12)
    n = np.array([-d[1], d[0]])
    return n, float(n @ line[0])


def _project_on(line: np.ndarray, p: np.ndarray) -> np.ndarray:
    d = line[1] - line[0]
    t = (p - line[0]) @ d / max(d @ d, 1e-12)
    return line[0] + t * d


def meet(lines: np.ndarray, reference: np.ndarray, min_angle_deg: float = 5.0) -> tuple[np.ndarray, bool]:
    """Point where lines (L, 2, 2) meet: intersection (L = 2) or least squares (L >= 3).

    When the lines are (nearly) parallel the point is the mean of the
    projections of ``reference`` (2,) onto them, and the flag is False.
    """
    if len(lines) == 1:
        return _project_on(lines[0], reference), True
    normals = np.empty((len(lines), 2))
    offsets = np.empty(len(lines))
    for i, ln in enumerate(lines):
        normals[i], offsets[i] = _unit_normal(ln)
    a = normals.T @ normals
    # smallest eigenvalue of Σ n nᵀ is sin² of the spread of directions (two lines)
    if np.linalg.eigvalsh(a)[0] < np.sin(np.radians(min_angle_deg)) ** 2 / (1 if len(lines) == 2 else 2):
        return np.mean([_project_on(ln, reference) for ln in lines], axis=0), False
    return np.linalg.solve(a, normals.T @ offsets), True


def reconstruct_image(topology: RoofTopology, selected: np.ndarray, reference_points: np.ndarray,
                      max_shift: np.ndarray | float = np.inf, min_angle_deg: float = 5.0) -> ImageReconstruction:
    """Reconstruct the refined roof in the image from one selected line per side.

    Parameters
    ----------
    topology : RoofTopology
    selected : ndarray of shape (M, 2, 2)
        Chosen image line of each side/ridge, pixel (col, row).
    reference_points : ndarray of shape (J, 2)
        Projected input junction points (the LiDAR roof in the image).
    max_shift : float or ndarray of shape (J,), default inf
        Largest accepted move of a junction (px); beyond it the projected
        point is kept.
    min_angle_deg : float, default 5
        Lines closer than this to parallel do not intersect.

    Returns
    -------
    ImageReconstruction
    """
    selected = np.asarray(selected, float)
    ref = np.asarray(reference_points, float)
    limit = np.broadcast_to(np.asarray(max_shift, float), (len(ref),))
    points = ref.copy()
    moved = np.zeros(len(ref), bool)
    lines = selected.copy()
    for j, junction in enumerate(topology.junctions):
        ids = sorted({line for line, _ in junction.members})
        p, ok = meet(selected[ids], ref[j], min_angle_deg)
        if ok and np.all(np.isfinite(p)) and np.linalg.norm(p - ref[j]) <= limit[j]:
            points[j], moved[j] = p, True
        for line, end in junction.members:
            if end >= 0:
                lines[line, end] = points[j]
    return ImageReconstruction(points, moved, lines)


def _vertical_residual(planes: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """|z - z_plane(x, y)| for planes (K, 4) with c > 0 and points (N, 3): (N, K)."""
    a, b, c, d = planes.T
    z = -(a[None] * xyz[:, :1] + b[None] * xyz[:, 1:2] + d[None]) / c[None]
    return np.abs(xyz[:, 2:3] - z)


def junction_planes(topology: RoofTopology, planes: np.ndarray | None, tolerance: float = 0.5,
                    min_c: float = 0.2) -> np.ndarray:
    """The plane (J, 4) each junction is intersected with in object space.

    Outline vertices: the roof plane nearest (vertically) to the LiDAR vertex.
    Ridge junctions: the plane nearest to the ends of their ridges (a ridge
    lies on two planes; either one holds its points).  No plane within
    ``tolerance`` (m), or none given: the horizontal plane through the LiDAR
    point.  Planes with |c| < ``min_c`` (walls) are ignored.
    """
    pts = np.array([j.point for j in topology.junctions], float).reshape(-1, 3)
    out = np.column_stack([np.zeros((len(pts), 2)), np.ones(len(pts)), -pts[:, 2]])
    if planes is None or len(planes) == 0:
        return out
    pl = np.asarray(planes, float).reshape(-1, 4)
    pl = pl * np.where(pl[:, 2:3] < 0, -1.0, 1.0)
    pl = pl[pl[:, 2] / np.maximum(np.linalg.norm(pl[:, :3], axis=1), 1e-12) >= min_c]
    if len(pl) == 0:
        return out
    n_outline = topology.n_outline
    for j, junction in enumerate(topology.junctions):
        if junction.vertex >= 0:
            res = _vertical_residual(pl, pts[j:j + 1])[0]
        else:
            ridges = sorted({line for line, end in junction.members if line >= n_outline and end >= 0})
            ends = topology.lines[ridges].reshape(-1, 3) if ridges else pts[j:j + 1]
            res = _vertical_residual(pl, ends).mean(axis=0)
        best = int(np.argmin(res))
        if res[best] <= tolerance:
            out[j] = pl[best]
    return out


def ridge_lines(topology: RoofTopology, planes: np.ndarray | None, tolerance: float = 0.5,
                min_angle_deg: float = 5.0, max_slope: float = 0.1) -> np.ndarray:
    """The 3D ridge line (point, unit direction) each ridge junction lies on, (J, 2, 3); NaN where none.

    A ridge lies on the two roof planes that hold both its LiDAR end points
    (vertical residuals within ``tolerance``); their intersection is the
    line.  Outline vertices get one only where a level ridge (slope below
    ``max_slope``) ends on them, as at a gable apex; others get NaN and use
    :func:`junction_planes`.
    Plane intersections are far more precise across the ridge than any
    image line at 0.2 m GSD, so ridge points are only moved *along* them.
    """
    out = np.full((len(topology.junctions), 2, 3), np.nan)
    if planes is None or len(planes) < 2:
        return out
    pl = np.asarray(planes, float).reshape(-1, 4)
    pl = pl * np.where(pl[:, 2:3] < 0, -1.0, 1.0)
    pl = pl / np.linalg.norm(pl[:, :3], axis=1, keepdims=True)
    pl = pl[pl[:, 2] >= 0.2]  # walls hold no ridge
    if len(pl) < 2:
        return out
    n_outline = topology.n_outline
    for j, junction in enumerate(topology.junctions):
        ridges = [line for line, end in junction.members if line >= n_outline and end >= 0]
        if junction.vertex >= 0:
            # an outline vertex follows a level ridge (gable apex), never a hip: the eave plane
            # leaves the image free to place a corner in both directions
            seg = topology.lines[ridges] if ridges else np.zeros((0, 2, 3))
            ridges = [r for r, ln in zip(ridges, seg)
                      if abs(ln[1, 2] - ln[0, 2]) <= max_slope * np.linalg.norm(ln[1, :2] - ln[0, :2])]
        if not ridges:
            continue
        res = _vertical_residual(pl, topology.lines[ridges[0]]).max(axis=0)
        a, b = np.argsort(res)[:2]
        if res[b] > tolerance:
            continue
        u = np.cross(pl[a, :3], pl[b, :3])
        if np.linalg.norm(u) < np.sin(np.radians(min_angle_deg)):
            continue
        u /= np.linalg.norm(u)
        # the point of the line nearest to the LiDAR ridge end
        m = np.stack([pl[a, :3], pl[b, :3], u])
        p = np.linalg.solve(m, [-pl[a, 3], -pl[b, 3], u @ junction.point])
        out[j] = [p, u]
    return out


def to_object_space(camera, pixels: np.ndarray, planes: np.ndarray, fallback: np.ndarray,
                    max_move: float = 5.0, lines: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the rays of pixels (J, 2) with planes (J, 4); returns (J, 3) and an ok flag (J,).

    Where ``lines`` (J, 2, 3) (point, unit direction; NaN = none) is given,
    the point is instead the one of that 3D line nearest to the ray.  A ray
    that misses (parallel, behind the camera) or lands more than
    ``max_move`` (m, planimetric) from ``fallback`` (J, 3) keeps the
    fallback point and gets ok = False.
    """
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    fallback = np.asarray(fallback, float).reshape(-1, 3)
    if len(pixels) == 0:
        return fallback.copy(), np.zeros(0, bool)
    o, d = camera.ray(pixels)
    n, off = planes[:, :3], planes[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(np.einsum("ij,ij->i", o, n) + off) / np.einsum("ij,ij->i", d, n)
    xyz = o + t[:, None] * d
    if lines is not None:
        p, u = lines[:, 0], lines[:, 1]
        w = o - p
        b = np.einsum("ij,ij->i", d, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (np.einsum("ij,ij->i", u, w) - b * np.einsum("ij,ij->i", d, w)) / (1.0 - b * b)
        on_line = p + s[:, None] * u
        use = np.isfinite(on_line).all(axis=1) & (1.0 - b * b > 1e-6)
        xyz = np.where(use[:, None], on_line, xyz)
        t = np.where(use, 1.0, t)
    ok = np.isfinite(xyz).all(axis=1) & (t > 0)
    ok &= np.linalg.norm(np.where(ok[:, None], xyz, 0)[:, :2] - fallback[:, :2], axis=1) <= max_move
    return np.where(ok[:, None], xyz, fallback), ok
