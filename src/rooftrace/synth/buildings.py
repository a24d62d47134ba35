"""Buildings of the synthetic scene: footprints and planar roofs with exact geometry.

A :class:`Building` is a footprint (its walls) plus one or more
:class:`RoofBlock` s.  A block is a roof extent (a polygon that includes the
overhang) over which the roof height is the *minimum* of a few planes: one
plane is a flat or shed roof, two planes a gable, four a hip.  The roof of
the building is the *maximum* over its blocks.  Min-of-planes gives convex
ridges and hips, max-of-blocks gives the valleys and steps where wings,
annexes and dormers meet, so L/T/U shapes, annexes at a lower level, dormers
and split-level roofs all come out exact, and :mod:`rooftrace.synth.truth`
derives the visible roof faces and ridge lines with half-plane clipping.

Heights in a block are *relative* to the terrain at the building
(``base_height``, set by :func:`rooftrace.synth.simulate_scene`); planes are
``z = a x + b y + c`` in map coordinates (metres).  Curved walls are densified
to segments of at most :data:`CURVE_STEP` metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import Polygon

__all__ = ["Building", "RoofBlock", "CURVE_STEP"]

#: longest segment of a densified curved wall (m)
CURVE_STEP = 0.5

KINDS = ("flat", "gable", "hip", "shed", "pyramid", "split", "round", "courtyard", "arc", "stadium",
         "l_shape", "t_shape", "u_shape", "terrace")


@dataclass
class RoofBlock:
    """One roof block: its extent and the planes whose minimum is its surface.

    Parameters
    ----------
    polygon : shapely.Polygon
        Roof extent seen from above, overhang included (map coordinates, m).
    planes : ndarray of shape (K, 3)
        Rows (a, b, c) of planes ``z = a x + b y + c``, z relative to the
        building's base height (m).
    """

    polygon: Polygon
    planes: np.ndarray

    def __post_init__(self) -> None:
        self.planes = np.atleast_2d(np.asarray(self.planes, float)).reshape(-1, 3)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Relative roof height (m) at map points; NaN outside the block (boundary included)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        z = np.min(self.planes[:, 0, None] * x.ravel() + self.planes[:, 1, None] * y.ravel() + self.planes[:, 2, None], axis=0)
        inside = shapely.dwithin(self.polygon, shapely.points(x.ravel(), y.ravel()), 1e-5)
        return np.where(inside, z, np.nan).reshape(x.shape)


def _frame(center, angle_deg):
    a = math.radians(angle_deg)
    u = np.array([math.cos(a), math.sin(a)])
    v = np.array([-math.sin(a), math.cos(a)])
    return np.asarray(center, float), u, v


def _local_plane(c, u, v, A, B, C):
    """Plane z = A s + B r + C in a local (s along u, r along v) frame -> map (a, b, c)."""
    a = A * u[0] + B * v[0]
    b = A * u[1] + B * v[1]
    return np.array([a, b, C - a * c[0] - b * c[1]])


def _rect(c, u, v, s0, s1, r0, r1) -> Polygon:
    pts = [c + s * u + r * v for s, r in ((s0, r0), (s1, r0), (s1, r1), (s0, r1))]
    return Polygon(pts)


def rect_block(center, length, width, angle_deg, kind, eave, ridge, overhang=(0.0, 0.0, 0.0, 0.0),
               hip_ends=(True, True)) -> tuple[RoofBlock, Polygon]:
    """A rectangular block and its wall rectangle.

    ``length`` runs along ``angle_deg`` (degrees counter-clockwise from east,
    the ridge direction of a gable), ``width`` across.  ``overhang`` is
    (+u end, -u end, +v side, -v side) in metres.  ``kind`` is ``flat``,
    ``shed`` (rising towards +v), ``gable``, ``hip`` (``hip_ends`` choose
    which ends are hipped) or ``pyramid``.
    """
    c, u, v = _frame(center, angle_deg)
    of, ob, ol, orr = overhang
    L2, W2 = length / 2.0, width / 2.0
    poly = _rect(c, u, v, -L2 - ob, L2 + of, -W2 - orr, W2 + ol)
    walls = _rect(c, u, v, -L2, L2, -W2, W2)
    rise = ridge - eave
    if kind == "flat" or rise <= 0:
        planes = [_local_plane(c, u, v, 0.0, 0.0, eave)]
    elif kind == "shed":
        k = rise / (width + ol + orr)
        planes = [_local_plane(c, u, v, 0.0, k, eave + k * (W2 + orr))]
    elif kind in ("gable", "hip", "pyramid"):
        k = rise / (W2 + max(ol, orr))
        planes = [_local_plane(c, u, v, 0.0, -k, ridge), _local_plane(c, u, v, 0.0, k, ridge)]
        ends = (True, True) if kind == "pyramid" else hip_ends if kind == "hip" else (False, False)
        if ends[0]:
            planes.append(_local_plane(c, u, v, -k, 0.0, eave + k * (L2 + of)))
        if ends[1]:
            planes.append(_local_plane(c, u, v, k, 0.0, eave + k * (L2 + ob)))
    else:
        raise ValueError(f"rectangular block kind must be flat, shed, gable, hip or pyramid, got {kind!r}")
    return RoofBlock(poly, np.array(planes)), walls


def _flat_block(footprint: Polygon, eave: float, overhang: float) -> RoofBlock:
    roof = footprint.buffer(overhang, join_style="mitre") if overhang > 0 else footprint
    return RoofBlock(roof, np.array([[0.0, 0.0, eave]]))


def _union(geoms) -> Polygon:
    """Union of touching polygons as one Polygon (snapped to 1e-6 m); parts that do not touch are an error."""
    geom = shapely.union_all(list(geoms))
    if geom.geom_type != "Polygon":
        geom = shapely.set_precision(geom, 1e-6)
    if geom.geom_type == "MultiPolygon" and len(geom.geoms) == 1:
        geom = geom.geoms[0]
    if geom.geom_type != "Polygon":
        raise ValueError("the parts of a building must touch (their union is not one polygon)")
    return geom


def _circle(center, radius: float) -> Polygon:
    n = max(16, int(math.ceil(2 * math.pi * radius / CURVE_STEP)))
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return Polygon(np.column_stack([center[0] + radius * np.cos(t), center[1] + radius * np.sin(t)]))


@dataclass
class Building:
    """A building with exact walls and roof.

    Parameters
    ----------
    building_id : int
        Positive identifier (the ``truth_building_id`` of its points).
    kind : str
        What it is: ``flat``, ``gable``, ``hip``, ``shed``, ``pyramid``,
        ``split`` (a step at the ridge), ``round``, ``stadium`` (semicircular
        ends), ``arc``, ``courtyard``, ``l_shape``, ``t_shape``, ``u_shape``,
        ``terrace`` (a house of a terraced row); a ``+annex`` / ``+dormers``
        suffix records additions.
    footprint : shapely.Polygon
        Walls in map coordinates (m), holes for courtyards.
    eave_height, ridge_height : float
        Heights of the roof edge and of the highest ridge above the terrain
        at the building (m); equal for a flat roof.
    overhang : float
        Roof overhang beyond the walls (m).
    blocks : list of RoofBlock
        Roof blocks (relative heights); the roof is their maximum.
    base_height : float or None
        Terrain height (absolute Z) the relative heights stand on; filled by
        :func:`~rooftrace.synth.simulate_scene`.
    roof_colour, wall_colour : tuple of 3 floats or None
        RGB albedo in [0, 1] for the image; None picks one from the seed.
    ridge_cap : bool
        Draw bright ridge caps (thin lines) in the image.
    """

    building_id: int
    kind: str
    footprint: Polygon
    eave_height: float
    ridge_height: float
    overhang: float = 0.0
    blocks: list[RoofBlock] = field(default_factory=list)
    base_height: float | None = None
    roof_colour: tuple[float, float, float] | None = None
    wall_colour: tuple[float, float, float] | None = None
    ridge_cap: bool = False

    @property
    def roof_outline(self) -> Polygon:
        """Roof edge seen from above (union of the blocks, overhang included), 2D."""
        return _union(b.polygon for b in self.blocks)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Relative roof height (m) at map points: the maximum over blocks; NaN outside."""
        hs = np.stack([b.height(x, y) for b in self.blocks])
        with np.errstate(all="ignore"):
            return np.where(np.isnan(hs).all(axis=0), np.nan, np.nanmax(np.where(np.isnan(hs), -np.inf, hs), axis=0))

    # ------------------------------------------------------------ constructors
    @classmethod
    def rectangle(cls, building_id: int, center, length: float, width: float, *, angle_deg: float = 0.0,
                  kind: str = "gable", eave_height: float = 6.0, ridge_height: float = 9.0,
                  overhang: float = 0.5, overhang_sides: tuple[float, float, float, float] | None = None,
                  **extra) -> Building:
        """A rectangle with a flat, shed, gable, hip, pyramid or split-level roof.

        ``length`` lies along ``angle_deg`` (the ridge direction), ``width``
        across.  ``overhang_sides`` = (+u end, -u end, +v side, -v side)
        overrides ``overhang`` per side (0 on shared walls of terraced houses).
        ``split`` makes two opposite shed halves meeting at the ridge line with
        a 0.25 × rise step (the ridge drawn as a ``step``).
        """
        ov = overhang_sides if overhang_sides is not None else (overhang,) * 4
        ridge = eave_height if kind == "flat" else ridge_height
        if kind == "split":
            c, u, v = _frame(center, angle_deg)
            rise = ridge - eave_height
            low = ridge - 0.25 * rise
            k1 = rise / (width / 2 + ov[3])
            k2 = (low - eave_height) / (width / 2 + ov[2])
            b1 = RoofBlock(_rect(c, u, v, -length / 2 - ov[1], length / 2 + ov[0], -width / 2 - ov[3], 0.0),
                           [_local_plane(c, u, v, 0.0, k1, ridge)])
            b2 = RoofBlock(_rect(c, u, v, -length / 2 - ov[1], length / 2 + ov[0], 0.0, width / 2 + ov[2]),
                           [_local_plane(c, u, v, 0.0, -k2, low)])
            walls = _rect(c, u, v, -length / 2, length / 2, -width / 2, width / 2)
            return cls(building_id, kind, walls, eave_height, ridge, max(ov), [b1, b2], **extra)
        block, walls = rect_block(center, length, width, angle_deg, kind, eave_height, ridge, ov)
        return cls(building_id, kind, walls, eave_height, ridge, max(ov), [block], **extra)

    @classmethod
    def wings(cls, building_id: int, center, main_length: float, width: float, wings: list[tuple[float, float]],
              *, angle_deg: float = 0.0, kind: str = "gable", eave_height: float = 6.0, ridge_height: float = 9.0,
              overhang: float = 0.5, shape: str = "l_shape", **extra) -> Building:
        """A main wing with perpendicular wings on its +v side (L, T, U shapes).

        ``wings`` lists (s, length) pairs: the wing's centre along the main
        wing (m from its centre) and how far it reaches beyond the main wall.
        Each wing starts at the main wing's ridge line so gables meet in
        valleys; ``kind`` is ``gable``, ``hip`` (free ends hipped) or ``flat``.
        """
        c, u, v = _frame(center, angle_deg)
        o = overhang
        main, walls = rect_block(c, main_length, width, angle_deg, kind, eave_height, ridge_height, (o,) * 4)
        blocks, polys = [main], [walls]
        for s, reach in wings:
            wl = width / 2 + reach  # wing length along v, from the main ridge line
            wc = c + s * u + (wl / 2) * v
            blk, wwalls = rect_block(wc, wl, width, angle_deg + 90.0, kind, eave_height, ridge_height,
                                     (o, 0.0, o, o), hip_ends=(True, False))
            blocks.append(blk)
            polys.append(wwalls)
        foot = _union(polys)
        ridge = eave_height if kind == "flat" else ridge_height
        return cls(building_id, shape, foot, eave_height, ridge, o, blocks, **extra)

    @classmethod
    def l_shape(cls, building_id: int, center, length: float, width: float, reach: float, **kw) -> Building:
        """An L: a wing at the +u end of the main wing reaching ``reach`` m beyond it."""
        return cls.wings(building_id, center, length, width, [(length / 2 - width / 2, reach)], shape="l_shape", **kw)

    @classmethod
    def t_shape(cls, building_id: int, center, length: float, width: float, reach: float, **kw) -> Building:
        """A T: a wing in the middle of the main wing."""
        return cls.wings(building_id, center, length, width, [(0.0, reach)], shape="t_shape", **kw)

    @classmethod
    def u_shape(cls, building_id: int, center, length: float, width: float, reach: float, **kw) -> Building:
        """A U: wings at both ends of the main wing."""
        s = length / 2 - width / 2
        return cls.wings(building_id, center, length, width, [(s, reach), (-s, reach)], shape="u_shape", **kw)

    @classmethod
    def from_polygon(cls, building_id: int, footprint: Polygon, *, kind: str = "flat", eave_height: float = 6.0,
                     overhang: float = 0.0, **extra) -> Building:
        """Any footprint (holes allowed) with a flat roof at ``eave_height``."""
        if not isinstance(footprint, Polygon) or footprint.is_empty or not footprint.is_valid:
            raise ValueError("footprint must be a valid, non-empty shapely Polygon")
        return cls(building_id, kind, footprint, eave_height, eave_height, overhang,
                   [_flat_block(footprint, eave_height, overhang)], **extra)

    @classmethod
    def round(cls, building_id: int, center, radius: float, *, eave_height: float = 8.0, overhang: float = 0.0,
              **extra) -> Building:
        """A round building (circle densified to :data:`CURVE_STEP`) with a flat roof."""
        return cls.from_polygon(building_id, _circle(center, radius), kind="round", eave_height=eave_height,
                                overhang=overhang, **extra)

    @classmethod
    def stadium(cls, building_id: int, center, length: float, width: float, *, angle_deg: float = 0.0,
                eave_height: float = 7.0, overhang: float = 0.0, **extra) -> Building:
        """A rectangle with semicircular ends (total ``length`` along ``angle_deg``), flat roof."""
        c, u, v = _frame(center, angle_deg)
        half = max(length / 2 - width / 2, 0.0)
        core = shapely.LineString([c - half * u, c + half * u])
        n = max(4, int(math.ceil(math.pi * width / 4 / CURVE_STEP)))
        foot = core.buffer(width / 2, quad_segs=n, cap_style="round")
        return cls.from_polygon(building_id, foot, kind="stadium", eave_height=eave_height, overhang=overhang, **extra)

    @classmethod
    def arc(cls, building_id: int, center, radius: float, width: float, sweep_deg: float, *, start_deg: float = 0.0,
            eave_height: float = 7.0, overhang: float = 0.0, **extra) -> Building:
        """A gently curved building: an annular sector of mid ``radius`` about ``center``."""
        r0, r1 = radius - width / 2, radius + width / 2
        n = max(8, int(math.ceil(math.radians(sweep_deg) * r1 / CURVE_STEP)))
        t = np.radians(start_deg + np.linspace(0.0, sweep_deg, n + 1))
        outer = np.column_stack([center[0] + r1 * np.cos(t), center[1] + r1 * np.sin(t)])
        inner = np.column_stack([center[0] + r0 * np.cos(t[::-1]), center[1] + r0 * np.sin(t[::-1])])
        return cls.from_polygon(building_id, Polygon(np.vstack([outer, inner])), kind="arc", eave_height=eave_height,
                                overhang=overhang, **extra)

    @classmethod
    def courtyard(cls, building_id: int, center, length: float, width: float, ring: float, *, angle_deg: float = 0.0,
                  eave_height: float = 9.0, overhang: float = 0.3, **extra) -> Building:
        """A rectangular block around an inner courtyard (a hole) of wing depth ``ring``, flat roof."""
        c, u, v = _frame(center, angle_deg)
        outer = _rect(c, u, v, -length / 2, length / 2, -width / 2, width / 2)
        inner = _rect(c, u, v, -length / 2 + ring, length / 2 - ring, -width / 2 + ring, width / 2 - ring)
        return cls.from_polygon(building_id, Polygon(outer.exterior.coords, [inner.exterior.coords]), kind="courtyard",
                                eave_height=eave_height, overhang=overhang, **extra)

    @classmethod
    def terrace(cls, first_id: int, center, widths: list[float], depth: float, *, angle_deg: float = 0.0,
                eave_heights: list[float], ridge_heights: list[float], kind: str = "gable",
                overhang: float = 0.4, **extra) -> list[Building]:
        """A row of adjacent houses sharing walls (one building each), ridges along the row.

        No overhang over shared walls; the row's ends and long sides have
        ``overhang``.  Different heights give steps between neighbours.
        """
        c, u, _ = _frame(center, angle_deg)
        total = float(sum(widths))
        out, s = [], -total / 2
        for i, (w, e, r) in enumerate(zip(widths, eave_heights, ridge_heights)):
            ov = (overhang if i == len(widths) - 1 else 0.0, overhang if i == 0 else 0.0, overhang, overhang)
            b = cls.rectangle(first_id + i, c + (s + w / 2) * u, w, depth, angle_deg=angle_deg, kind=kind,
                              eave_height=e, ridge_height=r, overhang_sides=ov, **extra)
            b.kind = "terrace"
            out.append(b)
            s += w
        return out

    # ------------------------------------------------------------- additions
    def with_annex(self, center, length: float, width: float, *, angle_deg: float = 0.0, eave_height: float = 3.0,
                   overhang: float = 0.3, wall_side: str = "-v") -> Building:
        """Add a lower flat-roofed annex (same building); ``wall_side`` is its side against the main wall."""
        ov = {"-v": (overhang, overhang, overhang, 0.0), "+v": (overhang, overhang, 0.0, overhang),
              "-u": (overhang, 0.0, overhang, overhang), "+u": (0.0, overhang, overhang, overhang)}[wall_side]
        block, walls = rect_block(center, length, width, angle_deg, "flat", eave_height, eave_height, ov)
        self.blocks.append(block)
        self.footprint = _union([self.footprint, walls])
        self.kind += "+annex"
        return self

    def with_dormers(self, positions: list[float], *, size: float = 2.4, depth: float = 2.2,
                     slope_deg: float = 8.0) -> Building:
        """Add shed dormers on the +v plane of a rectangular gable: ``positions`` along the ridge (m from the centre).

        A dormer starts 0.6 m below the ridge line and rises out of the main
        plane with a gentler slope; its front is a vertical step.
        """
        main = self.blocks[0]
        k = float(np.hypot(*main.planes[0][:2]))  # slope of the first plane, descending towards +v
        if k == 0:
            raise ValueError("dormers need a sloped main roof")
        c = np.array(main.polygon.centroid.coords[0])
        vdir = -np.array(main.planes[0][:2]) / k  # downhill of plane 0
        udir = np.array([-vdir[1], vdir[0]])
        ridge_z = self.ridge_height
        for s in positions:
            r0 = 0.6
            z0 = ridge_z - k * r0
            kd = math.tan(math.radians(slope_deg))
            cc = c + s * udir + (r0 + depth / 2) * vdir
            poly = _rect(cc, udir, vdir, -size / 2, size / 2, -depth / 2, depth / 2 + 0.2)
            A = np.array([-kd * vdir[0], -kd * vdir[1]])
            p0 = c + r0 * vdir
            plane = np.array([A[0], A[1], z0 - A[0] * p0[0] - A[1] * p0[1]])
            self.blocks.append(RoofBlock(poly, plane))
        self.kind += "+dormers"
        return self
