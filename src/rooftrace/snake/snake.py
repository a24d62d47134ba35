"""Object-space polygon snake from seed points (Dal Poz & Fazan).

Why our own: no library moves a polygon's vertices in object space (X, Y),
takes Z from a LiDAR TIN, reads the image through the collinearity equations
and minimises exactly with dynamic programming.  Steps:

1. a TIN of the LiDAR points around the seeds (:mod:`.tin`); its dilated
   raster gives the roof height used to project samples into the image;
2. candidates: a ``grid x grid`` lattice of half-width ``window`` around each
   vertex, in object space;
3. energy tables over candidate pairs (image gradient across each side,
   evenness of spacing) and triplets (right angles) (:mod:`.energy`);
4. exact DP on the cycle (:mod:`.dp`); the lattice is re-centred on the
   result, and shrunk by ``shrink`` once no vertex lands on its border (or
   after four re-centrings at one scale);
   the Gaussian scale of the image gradient follows the lattice step
   (coarse to fine), so coarse lattices see edges between their nodes;
5. stop when the lattice step is at most ``min_step`` and nothing moved to the
   border, or after ``max_iterations``; vertex heights by inward
   extrapolation on the TIN.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from rooftrace.errors import GeometryError, InputError
from rooftrace.snake.dp import cycle_dp
from rooftrace.snake.energy import EdgeField, angle_energy, edge_field, height_energy, side_energy, spacing_energy
from rooftrace.snake.surface import RasterSurface, Tin, roof_surface, vertex_heights

__all__ = ["SnakeOptions", "SnakeResult", "snake_outline"]

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class SnakeOptions:
    """Options of the object-space snake (TOML table ``[snake]``).

    Parameters
    ----------
    w_image : float, default 1.0
        Weight of the external energy (image gradient across the sides).
    w_angle : float, default 0.5
        Weight of the right-angle term cos^2 (the paper's modification).
    w_spacing : float, default 0.05
        Weight of the evenness term ((|s| - L)/L)^2 (Williams & Shah).
    w_height : float, default 1.0
        Weight of the LiDAR height step across the sides (beyond the paper;
        0 gives the paper's image-only external energy).
    height_step : float, default 2.0
        Height step (m) across a side that counts fully in the height term.
    height_offset : float or None
        Distance (m) either side of a side where the height term compares
        the TIN; None: 1.5 x the local point spacing.
    window : float, default 1.5
        Initial half-width (m) of the candidate lattice around each seed;
        cover the seeds' distance to the true corners.
    grid : int, default 5
        Candidates per axis at the first (coarsest) scale (odd, >= 3); the DP
        costs O(n grid^10).
    fine_grid : int, default 3
        Candidates per axis at the finer scales (odd, >= 3): once the coarse
        lattice has found the edges, Amini's 3 x 3 neighbourhood, re-centred
        until stable, refines them at 1/400 of the cost of 5 x 5.
    shrink : float, default 0.5
        Factor applied to the lattice step once the solution is inside the
        lattice.
    min_step : float or None
        Final lattice step (m); None: half the image GSD at the seeds.
    max_iterations : int, default 40
        DP runs at most.
    sigma_px : float, default 1.0
        Finest Gaussian scale (pixels) of the image gradient; coarser
        lattices use max(sigma_px, step / (2 GSD)).
    sample_step : float or None
        Spacing (m) of the samples along a side; None: the GSD.  Between 8
        and 64 samples per side.
    z_radius : float or None
        Radius (m) of the dilation giving the roof height at eaves; None:
        2.5 x the local point spacing (median TIN edge): enough to reach
        clean roof triangles from a convex corner.
    z_offset : float or None
        Step (m) of the TIN samples along each corner's inward bisector for
        the output heights (1 to 5 steps in); None: the local point spacing.
    margin : float, default 5.0
        LiDAR points within this distance (m) of the lattice's extent enter
        the TIN.
    """

    section = "snake"

    w_image: float = 1.0
    w_angle: float = 0.5
    w_spacing: float = 0.05
    w_height: float = 1.0
    height_step: float = 2.0
    height_offset: float | None = None
    window: float = 1.5
    grid: int = 5
    fine_grid: int = 3
    shrink: float = 0.5
    min_step: float | None = None
    max_iterations: int = 40
    sigma_px: float = 1.0
    sample_step: float | None = None
    z_radius: float | None = None
    z_offset: float | None = None
    margin: float = 5.0

    def __post_init__(self) -> None:
        for name in ("w_image", "w_angle", "w_spacing", "w_height"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not self.window > 0:
            raise ValueError(f"window must be > 0 m, got {self.window}")
        for name in ("grid", "fine_grid"):
            g = getattr(self, name)
            if not (isinstance(g, int) and g >= 3 and g % 2 == 1):
                raise ValueError(f"{name} must be an odd integer >= 3, got {g}")
        if not 0 < self.shrink < 1:
            raise ValueError(f"shrink must be in (0, 1), got {self.shrink}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations must be an integer >= 1, got {self.max_iterations}")
        if not self.sigma_px > 0:
            raise ValueError(f"sigma_px must be > 0, got {self.sigma_px}")
        if not self.height_step > 0:
            raise ValueError(f"height_step must be > 0 m, got {self.height_step}")
        for name in ("min_step", "sample_step", "z_radius", "z_offset", "height_offset"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"{name} must be > 0 m or unset, got {v}")
        if not self.margin >= 0:
            raise ValueError(f"margin must be >= 0 m, got {self.margin}")


@dataclass
class SnakeResult:
    """A snake's outline and how it got there.

    ``xyz`` (n, 3) float64: the open ring (X, Y, Z) in the seeds' order;
    ``energy``: total energy E at the final lattice; ``terms``: its parts
    (image, angle, spacing, unweighted); ``iterations``: DP runs;
    ``converged``: False when ``max_iterations`` stopped it; ``resolved``:
    the derived option values used.
    """

    xyz: np.ndarray
    energy: float
    terms: dict[str, float]
    iterations: int
    converged: bool
    resolved: dict[str, float] = field(default_factory=dict)


@dataclass
class _Context:
    """Everything the energy needs about one building's surroundings."""

    camera: object
    image: np.ndarray
    surface: RasterSurface
    plain: RasterSurface
    height_offset: float
    interior: int
    window: tuple[int, int, int, int]
    gsd: float
    sample_step: float
    fields: dict[float, EdgeField] = field(default_factory=dict)

    def field(self, sigma: float) -> EdgeField:
        sigma = round(float(sigma), 2)  # few distinct scales, each computed once
        if sigma not in self.fields:
            self.fields[sigma] = edge_field(self.image, sigma, self.window)
        return self.fields[sigma]


def _gsd_at(camera, xyz: np.ndarray) -> float:
    """Object metres per pixel at a point (mean of the X and Y directions)."""
    p = np.array([xyz, xyz + [1.0, 0, 0], xyz + [0, 1.0, 0]])
    cr = camera.project(p)
    d = np.linalg.norm(cr[1:] - cr[0], axis=1)
    return float(1.0 / d.mean())


def _tables(ring: np.ndarray, cands: np.ndarray, ctx: _Context, sigma: float, opt: SnakeOptions):
    """Energy tables (n, K), (n, K, K), (n, K, K, K) over the candidates (n, K, 2)."""
    n, k, _ = cands.shape
    fld = ctx.field(sigma)
    lengths = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)
    mean_len = float(lengths.mean())
    pair = np.zeros((n, k, k))
    parts = {"image": np.zeros((n, k, k)), "height": np.zeros((n, k, k)), "spacing": np.zeros((n, k, k)),
             "angle": np.zeros((n, k, k, k))}
    for i in range(n):
        j = (i + 1) % n
        ns = int(np.clip(np.ceil(lengths[i] / ctx.sample_step), 8, 64))
        parts["image"][i] = side_energy(fld, ctx.camera.project, ctx.surface, cands[i], cands[j], ns)
        if opt.w_height > 0:
            parts["height"][i] = height_energy(ctx.plain, cands[i], cands[j], ctx.height_offset, opt.height_step,
                                               ns, ctx.interior)
        parts["spacing"][i] = spacing_energy(cands[i], cands[j], mean_len)
        parts["angle"][i] = angle_energy(cands[i - 1], cands[i], cands[j])
    pair = opt.w_image * parts["image"] + opt.w_height * parts["height"] + opt.w_spacing * parts["spacing"]
    triple = opt.w_angle * parts["angle"]
    return np.zeros((n, k)), pair, triple, parts


def _polygon_energy(ring: np.ndarray, ctx: _Context, sigma: float, opt: SnakeOptions) -> tuple[float, dict[str, float]]:
    """Total energy of one polygon (n, 2) and its unweighted parts, with the tables the DP uses."""
    ring = np.asarray(ring, float)
    _, pair, triple, parts = _tables(ring, ring[:, None, :], ctx, sigma, opt)
    terms = {name: float(v.sum()) for name, v in parts.items()}
    return float(pair.sum() + triple.sum()), terms


def _lattice(grid: int, half: float) -> np.ndarray:
    """Offsets (grid^2, 2) of a square lattice of half-width ``half``; centre first."""
    t = np.linspace(-half, half, grid)
    off = np.stack(np.meshgrid(t, t), axis=-1).reshape(-1, 2)
    order = np.argsort(np.hypot(off[:, 0], off[:, 1]), kind="stable")  # ties resolved towards no move
    return off[order]


def _check_inputs(seeds: np.ndarray, image: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    seeds = np.asarray(seeds, float)
    if seeds.ndim != 2 or seeds.shape[1] < 2:
        raise ValueError(f"seeds must have shape (n, 2), got {seeds.shape}")
    seeds = seeds[:, :2]
    if len(seeds) < 3:
        raise InputError(f"a roof outline needs at least 3 seed points, got {len(seeds)}")
    if not np.isfinite(seeds).all():
        raise InputError("seed coordinates must be finite")
    if np.min(np.linalg.norm(np.roll(seeds, -1, axis=0) - seeds, axis=1)) < 1e-6:
        raise InputError("two consecutive seed points coincide; remove the duplicate")
    image = np.asarray(image, float)
    if image.ndim != 2:
        raise ValueError(f"image must be a (H, W) grey image, got shape {image.shape}")
    xyz = np.asarray(xyz, float)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
    return seeds, image, xyz


def _context(seeds: np.ndarray, image: np.ndarray, camera, xyz: np.ndarray, opt: SnakeOptions, reach: float):
    """Local TIN, roof surface and image window around the seeds (``reach`` m beyond them)."""
    lo = seeds.min(axis=0) - reach
    hi = seeds.max(axis=0) + reach
    keep = np.all((xyz[:, :2] >= lo - opt.margin) & (xyz[:, :2] <= hi + opt.margin), axis=1)
    local = xyz[keep]
    if len(local) < 3:
        centre = seeds.mean(axis=0).round(2).tolist()
        raise InputError(f"only {len(local)} LiDAR points near the seeds around {centre}; "
                         "are the seeds in the cloud's CRS and area?")
    try:
        tin = Tin(local)
    except GeometryError as exc:
        raise InputError(f"the LiDAR points near the seeds cannot be triangulated ({exc})") from None
    spacing = tin.spacing()
    zr = opt.z_radius if opt.z_radius is not None else 2.5 * spacing
    zc = float(np.median(local[:, 2]))
    gsd = _gsd_at(camera, np.array([*seeds.mean(axis=0), zc]))
    cell = float(np.clip(gsd, 0.05, 0.5))
    surface = roof_surface(tin, (*lo, *hi), cell=cell, radius=zr)
    plain = roof_surface(tin, (*lo, *hi), cell=cell, radius=0.0)
    h_off = opt.height_offset if opt.height_offset is not None else 1.5 * spacing
    x, y = seeds[:, 0], seeds[:, 1]
    interior = 1 if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0 else -1
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (surface.grid.min(), surface.grid.max())])
    cr = camera.project(corners)
    w = (int(np.floor(cr[:, 0].min())) - 1, int(np.floor(cr[:, 1].min())) - 1,
         int(np.ceil(cr[:, 0].max())) + 2, int(np.ceil(cr[:, 1].max())) + 2)
    ctx = _Context(camera, image, surface, plain, h_off, interior, w, gsd, opt.sample_step or gsd)
    return tin, ctx, {"spacing": spacing, "z_radius": zr, "gsd": gsd, "height_offset": h_off}


def snake_outline(seeds: np.ndarray, image: np.ndarray, camera, xyz: np.ndarray,
                  options: SnakeOptions | None = None) -> SnakeResult:
    """3D roof outline from seed points near a roof's corners.

    Parameters
    ----------
    seeds : ndarray of shape (n, 2)
        Object-space (X, Y) of the seeds (m, the cloud's CRS), n >= 3, in
        order around the roof (either direction).
    image : ndarray of shape (H, W)
        Grey image of the camera.
    camera : FrameCamera or OrthoCamera
        Maps object (X, Y, Z) to pixel (column, row).
    xyz : ndarray of shape (N, 3)
        LiDAR points (m); only those near the seeds are used.
    options : SnakeOptions, optional

    Returns
    -------
    SnakeResult
        One vertex per seed, same order.

    Raises
    ------
    InputError
        Fewer than 3 seeds, duplicated consecutive seeds, no LiDAR points
        near the seeds, seeds projecting outside the image.
    """
    opt = options or SnakeOptions()
    seeds, image, xyz = _check_inputs(seeds, image, xyz)
    reach = 2 * opt.window + 1.0  # the lattice may drift while it re-centres
    tin, ctx, resolved = _context(seeds, image, camera, xyz, opt, reach)
    h, w = image.shape
    seed_cr = camera.project(np.column_stack([seeds, ctx.surface(seeds)]))
    outside = ~(np.isfinite(seed_cr).all(axis=1) & (seed_cr[:, 0] >= -0.5) & (seed_cr[:, 0] <= w - 0.5)
                & (seed_cr[:, 1] >= -0.5) & (seed_cr[:, 1] <= h - 0.5))
    if outside.any():
        raise InputError(f"seed(s) {np.flatnonzero(outside).tolist()} project outside the image "
                         f"({w} x {h} px); check the seeds' CRS and the camera")
    min_step = opt.min_step if opt.min_step is not None else 0.5 * ctx.gsd
    resolved["min_step"] = min_step
    ring = seeds.copy()
    grid = opt.grid
    step = 2 * opt.window / (grid - 1)
    converged = False
    it = 0
    repeats, max_repeats = 0, 4
    prev = None
    lo, hi = seeds.min(axis=0) - reach, seeds.max(axis=0) + reach
    while it < opt.max_iterations:
        half = step * (grid - 1) / 2
        sigma = max(opt.sigma_px, 0.5 * step / ctx.gsd)
        off = _lattice(grid, half)
        cands = np.clip(ring[:, None, :] + off[None, :, :], lo, hi)
        unary, pair, triple, _ = _tables(ring, cands, ctx, sigma, opt)
        labels, energy = cycle_dp(unary, pair, triple)
        it += 1
        chosen = off[labels]
        ring = cands[np.arange(len(ring)), labels]
        # an energy that no longer drops counts as stable even on the border:
        # at the finest steps two near-equal solutions can alternate
        stalled = prev is not None and energy > prev - 1e-4 * abs(prev)
        prev = energy
        on_border = bool(np.any(np.abs(chosen) >= half - 1e-9)) and not stalled
        repeats += 1
        log.debug("snake iteration %d: %dx%d step %.3f m, sigma %.2f px, E = %.4f, border %s",
                  it, grid, grid, step, sigma, energy, on_border)
        # re-centre while a vertex sits on the lattice border, but at most
        # ``max_repeats`` times per scale: a vertex on a weak edge can walk
        # along it (or two solutions alternate) for ever
        if not on_border or repeats >= max_repeats:
            repeats = 0
            if step <= min_step + 1e-12:
                converged = not on_border
                break
            step = max(step * opt.shrink, min_step)
            grid = opt.fine_grid
            prev = None
    if not converged:
        log.info("snake stopped after %d iterations, still moving", it)
    energy, terms = _polygon_energy(ring, ctx, max(opt.sigma_px, 0.5 * min_step / ctx.gsd), opt)
    z_offset = opt.z_offset if opt.z_offset is not None else resolved["spacing"]
    resolved["z_offset"] = z_offset
    z = vertex_heights(tin, ring, z_offset, fallback=ctx.surface)
    return SnakeResult(np.column_stack([ring, z]), energy, terms, it, converged, resolved)
