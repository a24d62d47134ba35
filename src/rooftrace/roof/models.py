"""Analytic roof models with exact planes and ridge lines, and ALS-like sampling.

These are the constructed roofs of the roof tests and benchmark (gable, hip,
L-shaped hip, flat with a lower annex, shed, gable with a dormer, optional
chimneys): every face is an exact plane, every ridge, hip, valley and step
edge is known in closed form.  A roof is a list of rectangular *parts*; in a
part the surface is the lowest of the part's planes (a convex roof), and where
parts overlap the highest part wins, which gives the valleys of L-shaped hip
roofs and the walls of dormers and annexes.

Coordinates are built in a local frame, then rotated by ``angle`` (deg,
counter-clockwise) and shifted by ``offset`` (m), so tests can place a roof at
real CRS offsets and any orientation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

__all__ = ["RoofModel", "gable", "hip", "l_hip", "flat_annex", "shed", "gable_dormer", "terraced", "sample_roof",
           "BENCHMARK_MODELS"]


@dataclass
class RoofModel:
    """An analytic roof.

    Attributes
    ----------
    name : str
    outline : shapely Polygon
        Roof outline in plan (world coordinates).
    planes : ndarray of shape (K, 4)
        Exact face planes ``(a, b, c, d)``, unit normal, ``c > 0``.
    ridges : list of shapely LineString (3D)
    ridge_kind : list of str
        ``ridge``, ``hip``, ``valley`` or ``step``.
    """

    name: str
    outline: Polygon
    planes: np.ndarray
    ridges: list
    ridge_kind: list
    # local description
    _local_planes: np.ndarray = field(repr=False, default=None)  # (K, 3): z = z0 + gx x + gy y
    _parts: list = field(repr=False, default_factory=list)  # (xmin, ymin, xmax, ymax, [plane ids])
    _chimneys: list = field(repr=False, default_factory=list)  # (xmin, ymin, xmax, ymax, z)
    _angle: float = 0.0
    _offset: tuple = (0.0, 0.0)

    @property
    def slopes_deg(self) -> np.ndarray:
        return np.degrees(np.arccos(np.clip(self.planes[:, 2], -1, 1)))

    def to_local(self, xy):
        xy = np.asarray(xy, dtype=float) - np.asarray(self._offset)
        c, s = np.cos(np.radians(self._angle)), np.sin(np.radians(self._angle))
        return np.stack([c * xy[:, 0] + s * xy[:, 1], -s * xy[:, 0] + c * xy[:, 1]], axis=1)

    def to_world(self, xy):
        xy = np.asarray(xy, dtype=float)
        c, s = np.cos(np.radians(self._angle)), np.sin(np.radians(self._angle))
        return np.stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]], axis=1) + np.asarray(self._offset)

    def height(self, xy: np.ndarray):
        """Roof height and face index at world ``xy`` (M, 2); face ``-1`` on
        chimneys, NaN height outside every part."""
        loc = self.to_local(xy)
        lp = self._local_planes
        zall = lp[:, 0] + loc[:, :1] * lp[:, 1] + loc[:, 1:2] * lp[:, 2]  # (M, K)
        z = np.full(len(loc), -np.inf)
        face = np.full(len(loc), -1)
        for x0, y0, x1, y1, ids in self._parts:
            inside = (loc[:, 0] >= x0) & (loc[:, 0] <= x1) & (loc[:, 1] >= y0) & (loc[:, 1] <= y1)
            ids = np.asarray(ids)
            j = np.argmin(zall[:, ids], axis=1)
            zp = zall[np.arange(len(loc)), ids[j]]
            better = inside & (zp > z)
            z[better] = zp[better]
            face[better] = ids[j][better]
        for x0, y0, x1, y1, zc in self._chimneys:
            inside = (loc[:, 0] >= x0) & (loc[:, 0] <= x1) & (loc[:, 1] >= y0) & (loc[:, 1] <= y1)
            z[inside] = zc
            face[inside] = -1
        z[~np.isfinite(z)] = np.nan
        return z, face


def _build(name, local_outline, local_planes, parts, ridges_local, kinds, chimneys=(), angle=0.0, offset=(0.0, 0.0)):
    lp = np.asarray(local_planes, dtype=float)
    m = RoofModel(name, None, None, [], list(kinds), lp, list(parts), list(chimneys), float(angle), tuple(offset))
    ring = np.asarray(local_outline, dtype=float)
    m.outline = Polygon(m.to_world(ring))
    # Exact world planes: z = z0 + g . R^T (x - t)  =>  gradient R g.
    c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    gw = np.stack([c * lp[:, 1] - s * lp[:, 2], s * lp[:, 1] + c * lp[:, 2]], axis=1)
    z0w = lp[:, 0] - gw @ np.asarray(offset, dtype=float)
    pl = np.column_stack([-gw, np.ones(len(lp)), -z0w])
    m.planes = pl / np.linalg.norm(pl[:, :3], axis=1, keepdims=True)
    for line in ridges_local:
        a = np.asarray(line, dtype=float)
        m.ridges.append(LineString(np.column_stack([m.to_world(a[:, :2]), a[:, 2]])))
    return m


def gable(length=14.0, width=9.0, eave=5.0, slope=35.0, *, chimney=False, vents=False, edge_vents=False, angle=0.0,
          offset=(0.0, 0.0)):
    """Gable roof, ridge along the local x axis.

    ``chimney``: a 0.8 m x 0.8 m box 1 m above the ridge; ``vents``: four
    small boxes on the pitches (0.3 m to 0.7 m square, 0.7 m to 1.2 m above
    the roof at their upper edge: a vent pipe, small chimneys), one to five
    points each at 10 pts/m²; ``edge_vents``: two boxes at the roof's edges,
    a 0.5 m x 0.4 m one from the eave (its outer side in the wall's plane,
    0.8 m above the roof's highest point under it) and a 0.6 m square
    chimney on the ridge (0.9 m above it).
    """
    t = np.tan(np.radians(slope))
    h = eave + t * width / 2
    planes = [(eave, 0, t), (eave + t * width, 0, -t)]
    ch = [(length * 0.3, width / 2 + 0.6, length * 0.3 + 0.8, width / 2 + 1.4, h + 1.0)] if chimney else []
    if vents:
        for x, y, side, rise in ((0.2, 0.2, 0.3, 0.8), (0.45, 0.3, 0.5, 1.0), (0.7, 0.65, 0.7, 1.2), (0.3, 0.8, 0.4, 0.7)):
            x0, y0 = x * length, y * width
            top = eave + t * min(y0 + side, width - y0)  # the roof's highest point under the box
            ch.append((x0, y0, x0 + side, y0 + side, top + rise))
    if edge_vents:
        ch.append((0.55 * length, 0.0, 0.55 * length + 0.5, 0.4, eave + t * 0.4 + 0.8))
        ch.append((0.8 * length, width / 2 - 0.3, 0.8 * length + 0.6, width / 2 + 0.3, h + 0.9))
    return _build(
        "gable", [(0, 0), (length, 0), (length, width), (0, width)], planes,
        [(0, 0, length, width, [0, 1])], [[(0, width / 2, h), (length, width / 2, h)]], ["ridge"], ch, angle, offset,
    )


def hip(length=16.0, width=10.0, eave=5.0, slope=30.0, *, chimney=False, angle=0.0, offset=(0.0, 0.0)):
    """Hip roof on a rectangle, equal slopes."""
    t = np.tan(np.radians(slope))
    w2, h = width / 2, eave + t * width / 2
    planes = [(eave, 0, t), (eave + t * width, 0, -t), (eave, t, 0), (eave + t * length, -t, 0)]
    ridges = [
        [(w2, w2, h), (length - w2, w2, h)],
        [(0, 0, eave), (w2, w2, h)], [(0, width, eave), (w2, w2, h)],
        [(length, 0, eave), (length - w2, w2, h)], [(length, width, eave), (length - w2, w2, h)],
    ]
    ch = [(length * 0.6, 1.5, length * 0.6 + 0.9, 2.4, eave + 3.0)] if chimney else []
    return _build(
        "hip", [(0, 0), (length, 0), (length, width), (0, width)], planes,
        [(0, 0, length, width, [0, 1, 2, 3])], ridges, ["ridge"] + ["hip"] * 4, ch, angle, offset,
    )


def l_hip(length_a=18.0, length_b=15.0, width=8.0, eave=5.0, slope=30.0, *, angle=0.0, offset=(0.0, 0.0)):
    """L-shaped hip roof of two wings of equal width meeting at the origin corner."""
    t = np.tan(np.radians(slope))
    W, LA, LB = width, length_a, length_b
    w2, h = W / 2, eave + t * W / 2
    planes = [
        (eave, 0, t),  # 0 south of wing A (also the hip end of wing B)
        (eave + t * W, 0, -t),  # 1 north of wing A
        (eave + t * LA, -t, 0),  # 2 east hip end of wing A
        (eave, t, 0),  # 3 west of wing B (also the hip end of wing A)
        (eave + t * W, -t, 0),  # 4 east of wing B
        (eave + t * LB, 0, -t),  # 5 north hip end of wing B
    ]
    parts = [(0, 0, LA, W, [0, 1, 2, 3]), (0, 0, W, LB, [3, 4, 5, 0])]
    ridges = [
        [(w2, w2, h), (LA - w2, w2, h)], [(w2, w2, h), (w2, LB - w2, h)],
        [(0, 0, eave), (w2, w2, h)],
        [(LA, 0, eave), (LA - w2, w2, h)], [(LA, W, eave), (LA - w2, w2, h)],
        [(0, LB, eave), (w2, LB - w2, h)], [(W, LB, eave), (w2, LB - w2, h)],
        [(W, W, eave), (w2, w2, h)],
    ]
    kinds = ["ridge", "ridge", "hip", "hip", "hip", "hip", "hip", "valley"]
    outline = [(0, 0), (LA, 0), (LA, W), (W, W), (W, LB), (0, LB)]
    return _build("l_hip", outline, planes, parts, ridges, kinds, (), angle, offset)


def flat_annex(*, chimney=True, stair_house=False, angle=0.0, offset=(0.0, 0.0)):
    """Flat roof (14 m x 10 m, 9 m high) with a lower flat annex (6 m x 6 m, 5 m).

    ``chimney``: a 1 m x 1 m box to 10.2 m; ``stair_house``: a 2.5 m x 2.5 m
    box to 11.5 m.  Both are boxes of the model's chimneys: not in ``planes``,
    their points have face ``-1``."""
    planes = [(9.0, 0, 0), (5.0, 0, 0)]
    parts = [(0, 0, 14, 10, [0]), (14, 2, 20, 8, [1])]
    outline = [(0, 0), (14, 0), (14, 2), (20, 2), (20, 8), (14, 8), (14, 10), (0, 10)]
    ch = [(3, 3, 4, 4, 10.2)] if chimney else []
    ch += [(8, 4, 10.5, 6.5, 11.5)] if stair_house else []
    return _build("flat_annex", outline, planes, parts, [[(14, 2, 9.0), (14, 8, 9.0)]], ["step"], ch, angle, offset)


def shed(length=10.0, width=6.0, eave=4.0, slope=10.0, *, angle=0.0, offset=(0.0, 0.0)):
    """Single-plane shed roof, rising to the local +y."""
    t = np.tan(np.radians(slope))
    return _build("shed", [(0, 0), (length, 0), (length, width), (0, width)], [(eave, 0, t)],
                  [(0, 0, length, width, [0])], [], [], (), angle, offset)


def gable_dormer(positions=(8.0,), *, width=4.0, angle=0.0, offset=(0.0, 0.0)):
    """Gable roof (16 m x 10 m, 40°) with shed dormers (10°) on its south slope.

    ``positions`` are the dormer centres along the ridge (m); all dormers lie
    in one plane (coplanar but separate roof faces).  The dormer top meets the
    main slope in a horizontal valley (listed); its cheeks and front are
    walls, whose step edges are not listed."""
    m = gable(16.0, 10.0, 5.0, 40.0)
    t, td = np.tan(np.radians(40.0)), np.tan(np.radians(10.0))
    lp = list(map(tuple, m._local_planes))
    # Dormer plane: 0.4 m below the ridge at y = 4.5, falling 10° to the south;
    # it meets the main slope where both are equal.
    ztop = 5.0 + t * 4.5 - 0.4
    lp.append((ztop - td * 4.5, 0, td))
    z0 = ztop - td * 4.5
    yv = (z0 - 5.0) / (t - td)
    parts = list(m._parts)
    ridges = [[(c[0], c[1], c[2]) for c in np.asarray(r.coords)] for r in m.ridges]
    kinds = ["ridge"]
    for x in positions:
        parts.append((x - width / 2, 2.0, x + width / 2, 4.5, [2]))
        ridges.append([(x - width / 2, yv, 5.0 + t * yv), (x + width / 2, yv, 5.0 + t * yv)])
        kinds.append("valley")
    return _build("gable_dormer", [(0, 0), (16, 0), (16, 10), (0, 10)], lp, parts, ridges, kinds, (), angle, offset)


def terraced(eaves=(5.0, 6.5, 4.0, 6.5), *, house=6.0, width=10.0, slope=35.0, angle=0.0, offset=(0.0, 0.0)):
    """A terraced row of gable houses (ridges along the row) at different eave heights (m).

    Houses ``house`` m wide side by side along the local x axis; where two
    eaves differ the party wall is a height step (its step edge, a gable
    profile, is not listed), where they are equal the two roofs continue
    each other (one pair of planes).
    """
    t = np.tan(np.radians(slope))
    planes, parts, ridges, kinds = [], [], [], []
    for i, eave in enumerate(eaves):
        x0, x1 = i * house, (i + 1) * house
        if i and eave == eaves[i - 1]:
            parts[-1] = (parts[-1][0], 0, x1, width, parts[-1][4])
            ridges[-1] = [ridges[-1][0], (x1, width / 2, eave + t * width / 2)]
            continue
        planes += [(eave, 0, t), (eave + t * width, 0, -t)]
        parts.append((x0, 0, x1, width, [len(planes) - 2, len(planes) - 1]))
        ridges.append([(x0, width / 2, eave + t * width / 2), (x1, width / 2, eave + t * width / 2)])
        kinds.append("ridge")
    n = len(eaves) * house
    return _build("terraced", [(0, 0), (n, 0), (n, width), (0, width)], planes, parts, ridges, kinds, (),
                  angle, offset)


def sample_roof(model: RoofModel, density: float = 12.0, noise: float = 0.04, seed: int = 0):
    """Sample a roof like an ALS scan: a jittered grid in plan plus height noise.

    Parameters
    ----------
    density : float
        Points per m².
    noise : float
        Standard deviation of the height noise (m).

    Returns
    -------
    xyz : ndarray of shape (N, 3)
    face : ndarray of shape (N,), int
        Truth plane index per point (``-1`` on chimneys).
    """
    rng = np.random.default_rng(seed)
    g = 1.0 / np.sqrt(density)
    loc_ring = model.to_local(np.asarray(model.outline.exterior.coords)[:, :2])
    (x0, y0), (x1, y1) = loc_ring.min(axis=0), loc_ring.max(axis=0)
    gx, gy = np.meshgrid(np.arange(x0 + g / 2, x1, g), np.arange(y0 + g / 2, y1, g))
    loc = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-g / 2, g / 2, (gx.size, 2))
    xy = model.to_world(loc)
    keep = shapely.contains_xy(model.outline, xy[:, 0], xy[:, 1])
    xy = xy[keep]
    z, face = model.height(xy)
    ok = np.isfinite(z)
    xy, z, face = xy[ok], z[ok], face[ok]
    z = z + rng.normal(0.0, noise, len(z))
    return np.column_stack([xy, z]), face


#: the four scenes of the benchmark target (gable, hip, L-shaped hip, flat with annex)
BENCHMARK_MODELS = {
    "gable": lambda **kw: gable(chimney=True, **kw),
    "hip": lambda **kw: hip(chimney=True, **kw),
    "l_hip": l_hip,
    "flat_annex": flat_annex,
}

