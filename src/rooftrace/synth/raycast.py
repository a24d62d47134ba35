"""Ray casting against the scene's surface model (numba kernels).

The surface is the terrain (analytic) plus the visible roof faces: a raster
of face indices (``cell`` metres, north-up, row 0 at ``ymax``) says which
exact plane is the surface in each cell.  Below a roof face everything is
solid, so walls are where the face index changes.  A ray is marched in
steps of half a cell (and at most 1 m vertically); the crossing is refined
by bisection, which lands on the exact plane inside a face and on the cell
boundary at a wall.  Tree crowns are ellipsoids intersected analytically.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["SurfaceModel", "cast_rays", "shadow_rays", "crown_chords", "terrain_z"]


class SurfaceModel:
    """Arrays the kernels need: face raster, face planes, terrain coefficients, height range.

    Parameters
    ----------
    labels : ndarray of shape (ny, nx), int32
        Face index per cell, −1 for terrain.
    x0, y1, cell : float
        West edge, north edge and cell size (m).
    planes : ndarray of shape (F, 3)
        Absolute planes z = a x + b y + c per face (for normals).
    support : ndarray of shape (F, K, 3), optional
        Per face, the planes whose minimum is the roof there (the face's
        block; rows (0, 0, +inf) pad); default each face's own plane.  The
        kernels use it so heights stay exact where a ridge or hip crosses a
        raster cell.
    terrain : ndarray
        :meth:`rooftrace.synth.scene.Terrain.coefficients`.
    z_top, z_bot : float
        Heights above every surface and below all terrain (m).
    coarse : ndarray of shape (my, mx)
        Upper bound of the surface height within one coarse cell of each
        coarse cell (a dilated block maximum); a ray above it may advance one
        coarse cell without testing.
    cx0, cy1, ccell : float
        West edge, north edge and cell of the coarse grid (m).
    """

    def __init__(self, labels, x0, y1, cell, planes, terrain, z_top, z_bot, coarse, cx0, cy1, ccell, support=None):
        self.labels = np.ascontiguousarray(labels, np.int32)
        self.x0, self.y1, self.cell = float(x0), float(y1), float(cell)
        self.planes = np.ascontiguousarray(planes, np.float64).reshape(-1, 3)
        support = self.planes[:, None, :] if support is None else support
        self.support = np.ascontiguousarray(support, np.float64).reshape(len(self.planes), -1, 3)
        self.terrain = np.ascontiguousarray(terrain, np.float64)
        self.z_top, self.z_bot = float(z_top), float(z_bot)
        self.coarse = np.ascontiguousarray(coarse, np.float64)
        self.cx0, self.cy1, self.ccell = float(cx0), float(cy1), float(ccell)

    def args(self):
        return (self.labels, self.x0, self.y1, self.cell, self.support, self.terrain, self.coarse, self.cx0,
                self.cy1, self.ccell)


@njit(cache=True)
def _bound(x, y, coarse, cx0, cy1, ccell, z_top):
    ix = int(math.floor((x - cx0) / ccell))
    iy = int(math.floor((cy1 - y) / ccell))
    if 0 <= ix < coarse.shape[1] and 0 <= iy < coarse.shape[0]:
        return coarse[iy, ix]
    return z_top


@njit(cache=True)
def terrain_z(tc, x, y):
    dx = x - tc[0]
    dy = y - tc[1]
    z = tc[2] + tc[3] * dx + tc[4] * dy
    k = (tc.shape[0] - 5) // 4
    for i in range(k):
        j = 5 + 4 * i
        z += tc[j] * math.sin(tc[j + 1] * dx + tc[j + 2] * dy + tc[j + 3])
    return z


@njit(cache=True)
def _surface(x, y, labels, x0, y1, cell, planes, tc):
    ix = int(math.floor((x - x0) / cell))
    iy = int(math.floor((y1 - y) / cell))
    f = -1
    if 0 <= ix < labels.shape[1] and 0 <= iy < labels.shape[0]:
        f = labels[iy, ix]
    if f >= 0:
        z = np.inf
        for k in range(planes.shape[1]):
            z = min(z, planes[f, k, 0] * x + planes[f, k, 1] * y + planes[f, k, 2])
        return z, f
    return terrain_z(tc, x, y), -1


@njit(cache=True)
def _refine(ox, oy, oz, dx, dy, dz, lo, hi, f_hi, labels, x0, y1, cell, planes, tc):
    """Crossing inside [lo, hi]: exact on one plane, secant on terrain, bisection across a label change."""
    h, f_lo = _surface(ox + lo * dx, oy + lo * dy, labels, x0, y1, cell, planes, tc)
    if f_lo == f_hi and f_hi >= 0:
        # below the minimum of the planes <=> past every plane the ray descends through
        t = -np.inf
        ok = True
        for k in range(planes.shape[1]):
            a, b, c = planes[f_hi, k, 0], planes[f_hi, k, 1], planes[f_hi, k, 2]
            if c == np.inf:
                continue
            den = dz - a * dx - b * dy
            if den < 0.0:
                t = max(t, (a * ox + b * oy + c - oz) / den)
            elif a * (ox + lo * dx) + b * (oy + lo * dy) + c < oz + lo * dz:
                ok = False  # the ray rises against a plane it is above of: not a simple crossing
        if ok and lo - 1e-9 <= t <= hi + 1e-9:
            return t, f_hi, False
    elif f_lo == f_hi:
        g_lo = oz + lo * dz - h
        h_hi, _ = _surface(ox + hi * dx, oy + hi * dy, labels, x0, y1, cell, planes, tc)
        g_hi = oz + hi * dz - h_hi
        for _ in range(8):
            if g_lo == g_hi:
                break
            t = hi - g_hi * (hi - lo) / (g_hi - g_lo)
            t = min(max(t, lo), hi)
            ht, _ = _surface(ox + t * dx, oy + t * dy, labels, x0, y1, cell, planes, tc)
            g = oz + t * dz - ht
            if abs(g) < 1e-7:
                return t, -1, False
            if g > 0:
                lo, g_lo = t, g
            else:
                hi, g_hi = t, g
        return hi, -1, False
    for _ in range(34):
        mid = 0.5 * (lo + hi)
        hm, fm = _surface(ox + mid * dx, oy + mid * dy, labels, x0, y1, cell, planes, tc)
        if oz + mid * dz <= hm:
            hi = mid
        else:
            lo = mid
    h, f = _surface(ox + hi * dx, oy + hi * dy, labels, x0, y1, cell, planes, tc)
    return hi, f, (h - (oz + hi * dz)) > 0.02


@njit(cache=True, parallel=True)
def cast_rays(orig, dirs, labels, x0, y1, cell, planes, tc, coarse, cx0, cy1, ccell, z_top, z_bot):
    """First intersection of each ray with the surface.

    Parameters
    ----------
    orig, dirs : ndarray of shape (N, 3)
        Origins and unit directions (pointing down, d_z < 0).

    Returns
    -------
    t : ndarray (N,)
        Distance along the ray (NaN: no hit).
    face : ndarray (N,) int32
        Face index, −1 terrain.
    wall : ndarray (N,) bool
        The hit is on a wall (a vertical jump of the surface) of ``face``.
    """
    n = orig.shape[0]
    out_t = np.full(n, np.nan)
    out_f = np.full(n, -1, np.int32)
    out_w = np.zeros(n, np.bool_)
    for i in prange(n):
        ox, oy, oz = orig[i, 0], orig[i, 1], orig[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        if dz >= -1e-9:
            continue
        t = 0.0
        if oz > z_top:
            t = (z_top - oz) / dz
        t_end = (z_bot - oz) / dz
        hl = math.sqrt(dx * dx + dy * dy)
        dt = 1.0 / -dz
        big = np.inf
        if hl > 1e-12:
            dt = min(dt, 0.5 * cell / hl)
            big = ccell / hl
        while t < t_end:
            zb = _bound(ox + t * dx, oy + t * dy, coarse, cx0, cy1, ccell, z_top)
            z = oz + t * dz
            if z > zb + 1e-6:  # safe: stay above the bound while moving at most one coarse cell
                t = min(t + min(big, (z - zb) / -dz), t_end)
                if z - zb > 1e-3:
                    continue
            tn = min(t + dt, t_end)
            h, f = _surface(ox + tn * dx, oy + tn * dy, labels, x0, y1, cell, planes, tc)
            if oz + tn * dz <= h:
                th, fh, wl = _refine(ox, oy, oz, dx, dy, dz, t, tn, f, labels, x0, y1, cell, planes, tc)
                out_t[i] = th
                out_f[i] = fh
                out_w[i] = wl
                break
            t = tn
    return out_t, out_f, out_w


@njit(cache=True)
def _ellipsoid(ox, oy, oz, dx, dy, dz, cx, cy, cz, rh, rv):
    s = rh / rv
    px, py, pz = ox - cx, oy - cy, (oz - cz) * s
    ex, ey, ez = dx, dy, dz * s
    a = ex * ex + ey * ey + ez * ez
    b = 2.0 * (px * ex + py * ey + pz * ez)
    c = px * px + py * py + pz * pz - rh * rh
    disc = b * b - 4 * a * c
    if disc <= 0:
        return np.inf, np.inf
    q = math.sqrt(disc)
    return (-b - q) / (2 * a), (-b + q) / (2 * a)


@njit(cache=True)
def crown_chords(orig, dirs, trees, t_max, k_max):
    """Up to ``k_max`` crown chords (t_in, t_out, tree) per ray before ``t_max``, nearest first."""
    n = orig.shape[0]
    tin = np.full((n, k_max), np.inf)
    tout = np.full((n, k_max), np.inf)
    tid = np.full((n, k_max), -1, np.int32)
    for i in prange(n):
        for j in range(trees.shape[0]):
            a, b = _ellipsoid(orig[i, 0], orig[i, 1], orig[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2],
                              trees[j, 0], trees[j, 1], trees[j, 2], trees[j, 3], trees[j, 4])
            if a == np.inf or b <= 0 or a >= t_max[i]:
                continue
            a = max(a, 0.0)
            # insert sorted
            pos = k_max
            for m in range(k_max):
                if a < tin[i, m]:
                    pos = m
                    break
            if pos == k_max:
                continue
            for m in range(k_max - 1, pos, -1):
                tin[i, m] = tin[i, m - 1]
                tout[i, m] = tout[i, m - 1]
                tid[i, m] = tid[i, m - 1]
            tin[i, pos] = a
            tout[i, pos] = min(b, t_max[i])
            tid[i, pos] = j
    return tin, tout, tid


@njit(cache=True, parallel=True)
def shadow_rays(points, sun, labels, x0, y1, cell, planes, tc, coarse, cx0, cy1, ccell, z_top, trees,
                crown_transmission):
    """Light reaching each point along ``sun`` (unit, upward): 1 lit, 0 in a surface's shadow.

    Crowns let ``crown_transmission`` through.  Points start 3 cm along the
    sun vector to leave their own surface.
    """
    n = points.shape[0]
    light = np.ones(n)
    sx, sy, sz = sun[0], sun[1], sun[2]
    hl = math.sqrt(sx * sx + sy * sy)
    dt = 1.0 / sz
    big = 1.0 / sz
    if hl > 1e-12:
        dt = min(dt, 0.5 * cell / hl)
        big = min(big, ccell / hl)
    for i in prange(n):
        ox, oy, oz = points[i, 0], points[i, 1], points[i, 2]
        if ox != ox:  # NaN
            continue
        t = 0.03
        t_end = (z_top - oz) / sz
        while t < t_end:
            px, py, pz = ox + t * sx, oy + t * sy, oz + t * sz
            if pz > _bound(px, py, coarse, cx0, cy1, ccell, z_top):
                t += big
                continue
            h, f = _surface(px, py, labels, x0, y1, cell, planes, tc)
            if pz < h - 1e-3:
                light[i] = 0.0
                break
            t += dt
        if light[i] > 0:
            for j in range(trees.shape[0]):
                a, b = _ellipsoid(ox, oy, oz, sx, sy, sz, trees[j, 0], trees[j, 1], trees[j, 2], trees[j, 3],
                                  trees[j, 4])
                if b > 0 and a != np.inf:
                    light[i] *= crown_transmission
    return light


@njit(cache=True)
def pulse_returns(t_surf, tin, tout, tid, t_wire, u, max_returns):
    """Returns of each pulse along its ray: wire, crown interactions, then the surface.

    ``u`` (N, 8) uniform numbers drive the random parts: the depth of the
    first and later crown interactions (exponential, 0.9 m and 1.6 m mean),
    a 1.0 m dead zone between returns, and whether the pulse still reaches
    the surface after crossing crowns (probability 0.25 + 0.6 exp(−0.35 L)
    for a total chord length L).

    Returns
    -------
    t : ndarray (N, R)   distances (inf when unused)
    kind : ndarray (N, R) int8   1 surface, 2 vegetation, 3 wire
    tree : ndarray (N, R) int32  crown index of vegetation returns
    """
    n = t_surf.shape[0]
    k_max = tin.shape[1]
    rt = np.full((n, max_returns), np.inf)
    rk = np.zeros((n, max_returns), np.int8)
    rtree = np.full((n, max_returns), -1, np.int32)
    for i in prange(n):
        cnt = 0
        last = -np.inf
        ts = t_surf[i]
        if t_wire[i] < ts - 1.0:
            rt[i, 0] = t_wire[i]
            rk[i, 0] = 3
            cnt = 1
            last = t_wire[i]
        chord = 0.0
        ui = 0
        for m in range(k_max):
            if tin[i, m] == np.inf or cnt >= max_returns - 1:
                break
            a, b = tin[i, m], tout[i, m]
            chord += b - a
            depth = a - 0.9 * math.log(max(u[i, ui % 6], 1e-12))
            ui += 1
            while depth < b and cnt < max_returns - 1 and ui < 7:
                if depth - last >= 1.0 and ts - depth >= 1.0:
                    rt[i, cnt] = depth
                    rk[i, cnt] = 2
                    rtree[i, cnt] = tid[i, m]
                    cnt += 1
                    last = depth
                depth = depth + 1.0 - 1.6 * math.log(max(u[i, ui % 6], 1e-12))
                ui += 1
        p_through = 1.0 if chord == 0.0 else 0.25 + 0.6 * math.exp(-0.35 * chord)
        if (cnt == 0 or u[i, 7] < p_through) and ts == ts and ts - last >= 1.0:
            rt[i, cnt] = ts
            rk[i, cnt] = 1
            cnt += 1
    return rt, rk, rtree
