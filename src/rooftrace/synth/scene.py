"""The scene's geometry: options, terrain, trees, a power line (the building mix is in :mod:`rooftrace.synth.mix`).

Everything is a function of ``SceneOptions.seed`` through
``numpy.random.default_rng``.  Terrain is analytic (a gentle plane plus a few
long sinusoids), so the ALS and the image see exactly the same ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from rooftrace.errors import InputError, OptionError
from rooftrace.synth.buildings import Building
from rooftrace.synth.mix import ROOF_PALETTE, WALL_PALETTE, default_buildings

__all__ = ["SceneOptions", "Terrain", "Trees", "PowerLine", "default_buildings", "make_terrain", "place_trees",
           "make_power_line", "ROOF_PALETTE", "WALL_PALETTE"]


#: the building layouts of ``SceneOptions.scene``
SCENES = ("default", "blocks")


@dataclass(frozen=True)
class SceneOptions:
    """Options of ``rooftrace simulate`` (config table ``[simulate]``).

    Parameters
    ----------
    seed : int
        Seed of everything random.
    size : float
        Side of the square scene (m).
    density : float
        Mean ALS pulse density over open ground and roofs (pts/m²), strip
        overlap included.
    gsd : float
        Ground sample distance of the image (m/pixel).
    origin : (float, float)
        South-west corner of the scene in ``crs`` (m).
    crs : str
        Projected CRS of the scene.
    flying_height : float
        ALS flying height above the terrain (m).
    scan_angle_deg : float
        Largest scan angle off nadir (half the field of view, degrees).
    strip_overlap : float
        Side overlap of adjacent strips (fraction of the swath, 0-0.9).
    flight_speed : float
        Aircraft speed (m/s); sets the along-track line spacing.
    range_noise : float
        Standard deviation of the range (m).
    outlier_fraction : float
        Fraction of pulses that give an outlier above or below the surface.
    image, orthophoto : bool
        Render an aerial frame image; render a true orthophoto GeoTIFF instead.
    camera_offnadir_deg, camera_azimuth_deg, camera_kappa_deg : float
        Where the camera stands: the angle between the vertical and the line
        from the projection centre to the scene centre, the azimuth (degrees
        clockwise from north) of the projection centre seen from the scene
        centre, and the kappa rotation of the frame.
    focal_length_mm, pixel_size_mm : float
        Interior orientation; the flying height of the camera follows from
        ``gsd``.
    sun_azimuth_deg, sun_elevation_deg : float
        Direction of the sun (degrees, azimuth clockwise from north).
    blur_sigma_px, image_noise : float
        Gaussian blur (pixels) and noise (standard deviation in [0, 1] units).
    trees : bool
        Add trees (ellipsoid crowns; over roof edges with ``overhanging_trees``).
    tree_density : float
        Trees per hectare of open ground.
    overhanging_trees : float
        Share of the low buildings (ridge under 12 m) that get a crown over
        a roof edge.  Default 0: until this option the crowns meant to
        overhang roofs were never placed (each was tested against its own
        roof), and every scene and figure so far has none.
    crowns_to_eaves : bool
        Those crowns hang down to the eaves (crown bottom 0.3 m above the
        eave height, standing at the wall) instead of clearing the ridge by
        1 m: the harshest case for detection, a crown touching the roof.
    power_line : bool
        Add a three-conductor power line across the scene (ASPRS class 14).
    scan_pattern : {'zigzag', 'parallel', 'random'}
        How the pulses fall on the ground (:mod:`rooftrace.synth.als`):
        ``'zigzag'`` an oscillating mirror (lines alternate in direction and
        converge at the swath edges), ``'parallel'`` a rotating polygon
        mirror (parallel lines, one direction), ``'random'`` no line
        structure (each pulse at a random time and scan angle).
    line_spacing : float or None
        Along-track distance between successive scan lines at nadir (m);
        the point spacing along a line follows from the density.  ``None``:
        both spacings equal (1/√(density per strip)).  Older and
        low-density surveys have lines 2-5 times farther apart than the
        points along them.
    single_return : bool
        Record one (the first) return per pulse, as older scanners and
        archives (AHN2) do: no ground under the crowns, no return numbers
        above 1.
    beam_radius : float
        Radius (m) of the laser beam where it meets the scene: a pulse
        whose beam straddles a height step (a chimney's top, an eave, a
        wall's top) returns first from the upper surface and last from the
        lower one when they lie more than the 1 m dead zone apart, both
        along the beam's axis (the first hangs in the air beside the
        step).  0: a thin beam, one surface return per pulse.
    cell : float
        Cell of the roof-face raster used by the ray caster (m); faces are
        exact planes, only their boundaries are rasterised.  Raised to
        size / 6000 for large scenes (memory).
    scene : {'default', 'blocks'}
        The buildings: ``default`` the mix of :func:`default_buildings`,
        ``blocks`` city blocks of terraced houses around courtyards joined by
        low garages (:func:`rooftrace.synth.blocks.block_buildings`).
    """

    section = "simulate"

    seed: int = 1
    size: float = 160.0
    density: float = 12.0
    gsd: float = 0.2
    origin: tuple[float, float] = (85000.0, 447000.0)
    crs: str = "EPSG:28992"
    flying_height: float = 500.0
    scan_angle_deg: float = 12.0
    strip_overlap: float = 0.3
    flight_speed: float = 60.0
    range_noise: float = 0.03
    outlier_fraction: float = 0.0005
    image: bool = True
    orthophoto: bool = False
    camera_offnadir_deg: float = 6.0
    camera_azimuth_deg: float = 215.0
    camera_kappa_deg: float = 4.0
    focal_length_mm: float = 100.0
    pixel_size_mm: float = 0.012
    sun_azimuth_deg: float = 140.0
    sun_elevation_deg: float = 42.0
    blur_sigma_px: float = 0.7
    image_noise: float = 0.012
    trees: bool = True
    tree_density: float = 14.0
    overhanging_trees: float = 0.0
    crowns_to_eaves: bool = False
    power_line: bool = False
    scan_pattern: str = "zigzag"
    line_spacing: float | None = None
    single_return: bool = False
    beam_radius: float = 0.0
    cell: float = 0.05
    scene: str = "default"

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise InputError(f"simulate: scene must be one of {', '.join(SCENES)}, got {self.scene!r}")
        positive = ("size", "density", "gsd", "flying_height", "flight_speed", "focal_length_mm", "pixel_size_mm", "cell")
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise InputError(f"simulate: {name} must be a positive number, got {value!r}")
        if self.size < 20 or self.size > 2000:
            raise InputError(f"simulate: size must be between 20 and 2000 m, got {self.size!r}")
        if self.density > 200:
            raise InputError(f"simulate: density must be at most 200 pts/m², got {self.density!r}")
        if not 0.02 <= self.gsd <= 2.0:
            raise InputError(f"simulate: gsd must be between 0.02 and 2 m, got {self.gsd!r}")
        if (self.image or self.orthophoto) and self.size * 1.1 / self.gsd > 4000:
            raise OptionError(f"simulate: a {self.size:g} m scene at gsd {self.gsd:g} m needs an image over 4000 "
                              "pixels wide; raise {gsd} or lower {size}", "gsd", "size")
        if self.size**2 * self.density > 1.2e7:
            raise OptionError(f"simulate: {self.size:g} m at {self.density:g} pts/m² is over 12 million pulses; "
                              "lower {size} or {density}", "size", "density")
        if not 1.0 <= self.scan_angle_deg <= 40.0:
            raise InputError(f"simulate: scan_angle_deg must be between 1 and 40, got {self.scan_angle_deg!r}")
        if not 0.0 <= self.strip_overlap <= 0.9:
            raise InputError(f"simulate: strip_overlap must be between 0 and 0.9, got {self.strip_overlap!r}")
        if not 0.0 <= self.range_noise <= 1.0:
            raise InputError(f"simulate: range_noise must be between 0 and 1 m, got {self.range_noise!r}")
        if not 0.0 <= self.outlier_fraction <= 0.1:
            raise InputError(f"simulate: outlier_fraction must be between 0 and 0.1, got {self.outlier_fraction!r}")
        if not 0.0 <= self.camera_offnadir_deg <= 30.0:
            raise InputError(f"simulate: camera_offnadir_deg must be between 0 and 30, got {self.camera_offnadir_deg!r}")
        if not 5.0 <= self.sun_elevation_deg <= 90.0:
            raise InputError(f"simulate: sun_elevation_deg must be between 5 and 90, got {self.sun_elevation_deg!r}")
        if self.scan_pattern not in ("zigzag", "parallel", "random"):
            raise InputError(f"simulate: scan_pattern must be 'zigzag', 'parallel' or 'random', got {self.scan_pattern!r}")
        if self.line_spacing is not None and not (isinstance(self.line_spacing, (int, float))
                                                  and 0.05 <= self.line_spacing <= 20.0):
            raise InputError(f"simulate: line_spacing must be between 0.05 and 20 m, got {self.line_spacing!r}")
        if not (isinstance(self.overhanging_trees, (int, float)) and 0.0 <= self.overhanging_trees <= 1.0):
            raise InputError(f"simulate: overhanging_trees must be between 0 and 1, got {self.overhanging_trees!r}")
        if not (isinstance(self.beam_radius, (int, float)) and 0.0 <= self.beam_radius <= 1.0):
            raise InputError(f"simulate: beam_radius must be between 0 and 1 m, got {self.beam_radius!r}")
        if self.cell > 0.25:
            raise InputError(f"simulate: cell must be at most 0.25 m, got {self.cell!r}")
        if len(tuple(self.origin)) != 2:
            raise InputError(f"simulate: origin must be [x, y], got {self.origin!r}")
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))

    @property
    def center(self) -> np.ndarray:
        return np.array(self.origin) + self.size / 2.0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        x0, y0 = self.origin
        return (x0, y0, x0 + self.size, y0 + self.size)


@dataclass(frozen=True)
class Terrain:
    """Analytic terrain z = z0 + g · (p − c) + Σ A_k sin(k_k · (p − c) + φ_k) (m)."""

    center: tuple[float, float]
    z0: float
    gradient: tuple[float, float]
    amplitude: np.ndarray  # (K,)
    wavevector: np.ndarray  # (K, 2) rad/m
    phase: np.ndarray  # (K,)

    def height(self, x, y) -> np.ndarray:
        dx, dy = np.asarray(x, float) - self.center[0], np.asarray(y, float) - self.center[1]
        z = self.z0 + self.gradient[0] * dx + self.gradient[1] * dy
        for a, (kx, ky), p in zip(self.amplitude, self.wavevector, self.phase):
            z = z + a * np.sin(kx * dx + ky * dy + p)
        return z

    def coefficients(self) -> np.ndarray:
        """Flat float64 array for the numba kernels: cx, cy, z0, gx, gy, then (A, kx, ky, phase) per term."""
        terms = np.column_stack([self.amplitude, self.wavevector, self.phase]).ravel()
        return np.concatenate([[*self.center, self.z0, *self.gradient], terms]).astype(np.float64)


def make_terrain(options: SceneOptions, rng: np.random.Generator) -> Terrain:
    """A gentle slope (1-2 %) in a random direction with three long undulations (0.15-0.4 m)."""
    slope = rng.uniform(0.008, 0.02)
    ang = rng.uniform(0, 2 * np.pi)
    waves = rng.uniform(45.0, 140.0, 3)
    dirs = rng.uniform(0, 2 * np.pi, 3)
    kvec = np.column_stack([np.cos(dirs), np.sin(dirs)]) * (2 * np.pi / waves)[:, None]
    return Terrain(tuple(options.center), float(rng.uniform(2.0, 12.0)), (slope * math.cos(ang), slope * math.sin(ang)),
                   rng.uniform(0.15, 0.4, 3), kvec, rng.uniform(0, 2 * np.pi, 3))


@dataclass
class Trees:
    """Tree crowns as ellipsoids: centres (N, 3) absolute, horizontal and vertical radii (N,), m."""

    centers: np.ndarray
    radius_h: np.ndarray
    radius_v: np.ndarray

    def __len__(self) -> int:
        return len(self.centers)

    def as_array(self) -> np.ndarray:
        """(N, 5) float64: cx, cy, cz, rh, rv (for the numba kernels)."""
        return np.column_stack([self.centers, self.radius_h, self.radius_v]).astype(np.float64).reshape(-1, 5)


@dataclass(frozen=True)
class PowerLine:
    """Conductors hanging between two pylons: catenaries in vertical planes (m).

    ``ends`` (2, 2) are the pylon positions; ``offsets`` the conductors'
    lateral offsets; ``height`` the attachment height above the terrain;
    ``sag`` the sag at mid-span.
    """

    ends: np.ndarray
    offsets: tuple[float, ...]
    z_ends: tuple[float, float]
    sag: float

    def as_array(self) -> np.ndarray:
        """Rows per conductor: x0, y0, x1, y1, z0, z1, sag."""
        (x0, y0), (x1, y1) = self.ends
        d = np.array([x1 - x0, y1 - y0])
        n = np.array([-d[1], d[0]]) / np.hypot(*d)
        return np.array([[x0 + o * n[0], y0 + o * n[1], x1 + o * n[0], y1 + o * n[1], *self.z_ends, self.sag]
                         for o in self.offsets], np.float64)


def place_trees(options: SceneOptions, buildings: list[Building], terrain: Terrain,
                rng: np.random.Generator) -> Trees:
    """Trees on open ground (``tree_density`` per hectare) plus, on request, crowns over roof edges.

    Free trees keep their crown clear of every roof; overhanging trees
    (``overhanging_trees`` of the low buildings, none by default) stand beside a wall with the
    crown bottom 1 m above that roof's ridge, or with ``crowns_to_eaves``
    0.3 m above its eaves, the crown reaching over the roof.
    """
    roofs = [b.roof_outline for b in buildings]
    union = shapely.union_all(roofs) if roofs else shapely.Polygon()
    x0, y0, x1, y1 = options.bounds
    open_area = options.size**2 - union.area
    n_free = int(round(options.tree_density * open_area / 1e4))
    cs, rh, rv = [], [], []
    tries = 0
    while len(cs) < n_free and tries < 50 * max(n_free, 1):
        tries += 1
        p = rng.uniform([x0 + 2, y0 + 2], [x1 - 2, y1 - 2])
        r = rng.uniform(1.8, 4.0)
        if union.distance(shapely.Point(p)) < r + 0.8:
            continue
        if cs and np.min(np.hypot(*(np.array(cs)[:, :2] - p).T) - np.array(rh)) < 0.6 * r:
            continue
        v = r * rng.uniform(0.9, 1.4)
        cs.append([p[0], p[1], float(terrain.height(*p)) + rng.uniform(2.0, 4.0) + v])
        rh.append(r)
        rv.append(v)
    # crowns over roof edges, beside the first few low buildings; their own
    # stream, so the free trees and the power line do not depend on them
    over_rng = np.random.default_rng([int(options.seed), 0x0E1A])
    n_over = min(len(buildings), int(round(len(buildings) * options.overhanging_trees)))
    low = [i for i, b in enumerate(buildings) if b.ridge_height < 12][:n_over]
    for i in low:
        b = buildings[i]
        ring = roofs[i].exterior
        p = np.asarray(ring.interpolate(over_rng.uniform(0, ring.length)).coords[0])
        r = over_rng.uniform(2.8, 3.8)
        away = p - np.asarray(roofs[i].centroid.coords[0])
        p = p + away / max(np.hypot(*away), 1e-9) * r * 0.45
        if not (x0 + r < p[0] < x1 - r and y0 + r < p[1] < y1 - r):
            continue
        others = roofs[:i] + roofs[i + 1:]
        if others and shapely.union_all(others).distance(shapely.Point(p)) < r + 0.5:
            continue
        v = r * over_rng.uniform(1.0, 1.3)
        ground = float(terrain.height(*p))
        cz = ground + (b.eave_height + 0.3 if options.crowns_to_eaves else b.ridge_height + 1.0) + v
        cs.append([p[0], p[1], cz])
        rh.append(r)
        rv.append(v)
    return Trees(np.array(cs, float).reshape(-1, 3), np.array(rh, float), np.array(rv, float))


def make_power_line(options: SceneOptions, terrain: Terrain, rng: np.random.Generator) -> PowerLine:
    """Three conductors 1.8 m apart crossing the scene west to east, 14-16 m high, 1.5 m sag.

    The line follows the gap between the first two rows of building slots so
    it passes between buildings, as lines do.
    """
    x0, y0, x1, _ = options.bounds
    n = max(1, int(options.size // 30.0))
    y = y0 + (options.size - n * 30.0) / 2 + 30.0 if n >= 2 else y0 + 0.1 * options.size
    dy = rng.uniform(-0.5, 0.5)
    ends = np.array([[x0 - 20.0, y - dy], [x1 + 20.0, y + dy]])
    h = rng.uniform(14.0, 16.0)
    z = tuple(float(terrain.height(*e)) + h for e in ends)
    return PowerLine(ends, (-1.8, 0.0, 1.8), z, 1.5)
