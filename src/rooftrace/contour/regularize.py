"""Regularisation options, and the 'cdspline' method's outward correction and snapping.

The default method, 'lines', is :mod:`rooftrace.contour.lines` (the shape by
model selection) and :mod:`rooftrace.contour.edge` (the edge between roof and
non-roof points).  The 'cdspline' method keeps the thesis' CD-spline and
corrects it as follows.  The alpha-shape boundary runs through the outermost roof points, which lie
on average about half a point spacing inside the true roof edge; the
outward correction moves every ring that far away from the roof.  Snapping
turns near-orthogonal straight segments to the building's dominant
direction (the usual footprint regularisation).  Both keep vertex count and
corner indices, and are kept as defaults only when they measure better
(docs/design-notes.md, "Roof outlines").
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

__all__ = ["METHODS", "RegularizeOptions", "offset_ring", "dominant_direction", "snap_ring"]

log = logging.getLogger(__name__)

#: the regularisation methods, the default first
METHODS = ("lines", "cdspline")


@dataclass(frozen=True)
class RegularizeOptions:
    """Options of the regularisation stage (TOML table ``[regularize]``).

    Attributes
    ----------
    method : {'lines', 'cdspline'}
        'lines' (default, beyond the thesis): the building shape by model
        selection on the traced boundary (:mod:`rooftrace.contour.lines`):
        straight walls as robust lines meeting at corners, curves only where
        the CD-spline beats the line by more than the sampling noise, walls
        on the dominant direction where that fits as well, narrow inlets
        bridged, the edge placed between the last roof point and the first
        point that is not roof (:mod:`rooftrace.contour.edge`).
        'cdspline': the thesis' iterative CD-spline with the F-test, then
        ``snap`` and the outward shift by ``offset_factor`` below.
    noise_factor : float
        'lines': standard deviation of the boundary points about a straight
        edge, in sampling steps across the edge (σ0, the floor of every
        residual variance in the model choice;
        :func:`rooftrace.contour.lines.boundary_step`).  A boundary point lies
        anywhere between the edge and one step inside it: 1/√12 ≈ 0.29.
    edge_factor : float
        'lines': half the sampling step across a roof edge, in local
        spacings: the outward shift of the fitted boundary to the roof edge
        where no point that is not roof lies nearer than the step
        (:func:`rooftrace.contour.edge.edge_shift`), and everywhere when none
        are known (``rooftrace outline --single-building``).
    bridge_factor : float
        'lines': inlets of the outer ring narrower than this many local
        spacings are closed (a morphological closing): where two roof levels
        meet without points on the step the alpha shape cuts a notch.  0
        disables it.
    directions : bool
        'lines': try the building's dominant direction (or its perpendicular)
        on every wall within 20° of it; a wall takes it when its BIC is lower.
    offset_factor : float
        Outward correction as a fraction of the local mean spacing (ps_avg of
        the ring's points for the per-point alpha, else alpha): distance =
        ``offset_factor`` * spacing, metres.  0 disables it.  Against roof
        outlines (City3D/BAG) 0.3 measures best (the outermost points lie
        about half a grid spacing inside the edge); against wall footprints
        (Delft/BGT, where eaves already overhang) any correction costs
        correctness.  The default 0.1 meets both benchmarks' targets
        (docs/design-notes.md, "Roof outlines"); use 0.3 when the reference
        is the roof edge, 0 for wall lines.
    snap : bool
        Snap straight segments within ``snap_tolerance`` of the dominant
        direction (or its perpendicular) to it exactly (on by default: it
        measured better).
    snap_tolerance : float
        Degrees.
    max_offset_ratio : float
        Mitre limit: a vertex moves at most this many times the offset distance.
    """

    section = "regularize"

    method: str = "lines"
    noise_factor: float = 0.3
    edge_factor: float = 0.4
    bridge_factor: float = 4.0
    directions: bool = True
    offset_factor: float = 0.1
    snap: bool = True
    snap_tolerance: float = 10.0
    max_offset_ratio: float = 3.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"regularize.method must be one of {', '.join(METHODS)}, not {self.method!r}")
        for name in ("noise_factor", "edge_factor", "bridge_factor"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"regularize.{name} must be >= 0, not {getattr(self, name)}")
        if not self.noise_factor > 0:
            raise ValueError(f"regularize.noise_factor must be > 0, not {self.noise_factor}")
        if self.offset_factor < 0:
            raise ValueError(f"regularize.offset_factor must be >= 0, not {self.offset_factor}")
        if not 0 <= self.snap_tolerance < 45:
            raise ValueError(f"regularize.snap_tolerance must be in [0, 45) degrees, not {self.snap_tolerance}")
        if not self.max_offset_ratio >= 1:
            raise ValueError(f"regularize.max_offset_ratio must be >= 1, not {self.max_offset_ratio}")


def offset_ring(vertices: np.ndarray, distance: float, max_ratio: float = 3.0) -> np.ndarray:
    """Move a closed ring ``distance`` metres to the right of its direction of travel (mitred).

    Parameters
    ----------
    vertices : ndarray of shape (K, 2) or (K, 3) float64
        Ring with the roof on the left (outer ring CCW, holes CW), first
        vertex not repeated.  z is left unchanged.
    distance : float
        Metres; negative moves inwards.
    max_ratio : float
        A vertex moves at most ``max_ratio * |distance|`` (sharp spikes).

    Returns
    -------
    ndarray of the same shape
    """
    v = np.array(vertices, dtype=np.float64)
    if distance == 0 or len(v) < 3:
        return v
    d = np.roll(v[:, :2], -1, axis=0) - v[:, :2]
    length = np.linalg.norm(d, axis=1)
    d = d / np.where(length > 0, length, 1.0)[:, None]
    normal = np.column_stack([d[:, 1], -d[:, 0]])  # right of each edge k -> k+1
    n_in, n_out = np.roll(normal, 1, axis=0), normal
    denom = 1.0 + np.einsum("ij,ij->i", n_in, n_out)
    mitre = (n_in + n_out) / np.where(denom > 1e-9, denom, 1e-9)[:, None]
    norm = np.linalg.norm(mitre, axis=1)
    mitre *= np.minimum(1.0, max_ratio / np.maximum(norm, 1e-12))[:, None]
    v[:, :2] += distance * mitre
    return v


def dominant_direction(vertices: np.ndarray, corners: np.ndarray, degrees) -> float:
    """Length-weighted dominant direction (radians in [0, pi/2)) of a ring's straight segments."""
    c = vertices[corners, :2]
    d = np.roll(c, -1, axis=0) - c
    straight = np.asarray(degrees) == 1
    w = np.linalg.norm(d, axis=1) * straight
    if w.sum() == 0:
        return 0.0
    theta = np.arctan2(d[:, 1], d[:, 0])
    angle = np.arctan2(np.sum(w * np.sin(4 * theta)), np.sum(w * np.cos(4 * theta))) / 4.0
    return float(angle % (np.pi / 2))


def _intersect(p1, d1, p2, d2):
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) < np.sin(np.radians(10)):
        return None
    s = ((p2[0] - p1[0]) * d2[1] - (p2[1] - p1[1]) * d2[0]) / den
    return p1 + s * d1


def snap_ring(vertices: np.ndarray, corners: np.ndarray, degrees, direction: float, tolerance: float = 10.0) -> np.ndarray:
    """Turn straight segments near ``direction`` (mod 90°) onto it and re-intersect their corners.

    Parameters
    ----------
    vertices : ndarray of shape (K, 3) float64
        Closed ring (first not repeated).
    corners : ndarray of int, shape (M,)
        Vertex index of each segment's first corner, increasing.
    degrees : sequence of M int
        Degree of each segment; only degree-1 segments turn.
    direction : float
        Dominant direction, radians.
    tolerance : float
        Largest turn in degrees.

    Returns
    -------
    ndarray of shape (K, 3)
        The ring with corners moved; vertices along curved segments stay.
    """
    v = np.array(vertices, dtype=np.float64)
    m = len(corners)
    if m < 3:
        return v
    c = v[corners, :2]
    nxt = np.roll(c, -1, axis=0)
    lines = []
    for k in range(m):
        mid, d = 0.5 * (c[k] + nxt[k]), nxt[k] - c[k]
        length = np.hypot(*d)
        if length == 0:
            lines.append(None)
            continue
        d = d / length
        if degrees[k] == 1:
            theta = np.arctan2(d[1], d[0])
            delta = (theta - direction + np.pi / 4) % (np.pi / 2) - np.pi / 4
            if abs(np.degrees(delta)) <= tolerance:
                theta -= delta
                d = np.array([np.cos(theta), np.sin(theta)])
            lines.append((mid, d))
        else:
            lines.append(None)
    for k in range(m):
        a, b = lines[k - 1], lines[k]
        if a is None and b is None:
            continue
        if a is not None and b is not None:
            p = _intersect(a[0], a[1], b[0], b[1])
            if p is None:  # nearly parallel: the foot on the outgoing line
                p = b[0] + np.dot(c[k] - b[0], b[1]) * b[1]
        else:
            ln = a if a is not None else b
            p = ln[0] + np.dot(c[k] - ln[0], ln[1]) * ln[1]
        if np.hypot(*(p - c[k])) <= 5.0 * max(1e-9, np.hypot(*(c[k] - c[k - 1]))):
            v[corners[k], :2] = p
    return v
