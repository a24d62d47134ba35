"""Airborne laser scanning of the scene by ray casting from a flight trajectory.

Every pulse follows the thesis' ALS point equation (Santos 2019, eq. 2.4)::

    X_i = X_o(t) + R_{κφω}(t) P_G + R_{κφω}(t) R_{ΔκΔφΔω} R_{αβ}(t) [0, 0, −ρ_i]^T

with the GNSS/INS position ``X_o(t)`` along a straight strip (plus a small
drift and altitude wobble), the platform attitude ``R(t)`` (heading plus
roll/pitch/yaw oscillations), a lever arm ``P_G`` and boresight angles
``Δ``, and the scan angle ``β(t)`` of an oscillating mirror (a triangle wave
softened towards a sine, so points crowd a little at the swath edges).  The
range ``ρ`` is the first intersection of the ray with the scene, plus
Gaussian range noise; crowns give multiple returns; some pulses give
outliers above or below the surface.  Parallel strips with side overlap
cover the scene; the pulse rate is set so that the mean density over the
scene is the requested one, and the mirror frequency so that along- and
across-track spacings match (1/√density per strip), or so that the scan
lines lie ``line_spacing`` apart along track (the points along a line are
then closer or farther apart than the lines, as in most real surveys).

Scan patterns (``SceneOptions.scan_pattern``): ``'zigzag'`` the oscillating
mirror above (lines alternate in direction, two per mirror period, and
converge towards the swath edges); ``'parallel'`` a rotating polygon mirror
(a sawtooth: parallel lines swept in one direction, one per period);
``'random'`` each pulse at a random time and a random scan angle (no line
structure; the pulses of a strip are still in time order).  With
``single_return`` only the first return of each pulse is recorded.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from rooftrace.cloud import PointCloud
from rooftrace.synth.raycast import SurfaceModel, cast_rays, crown_chords, pulse_returns

__all__ = ["scan_scene", "strip_layout", "ASPRS_WIRE"]

log = logging.getLogger(__name__)

#: ASPRS class of wire conductors
ASPRS_WIRE = 14
_MAX_RETURNS = 5
_LEVER_ARM = np.array([0.05, -0.12, -0.35])  # m, body frame
_BORESIGHT = np.radians([0.015, -0.01, 0.02])  # rad (omega, phi, kappa)
_MIRROR_SINE = 0.35  # share of sine in the mirror's triangle wave


def _rot(v, axis, angle):
    """Rotate vectors v (N, 3) about a coordinate axis by angles (N,) or a scalar (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    out = v.copy()
    out[:, i] = c * v[:, i] - s * v[:, j]
    out[:, j] = s * v[:, i] + c * v[:, j]
    return out


def _attitude(v, roll, pitch, yaw_total):
    """R(t) v with R = R_z(yaw) R_y(pitch) R_x(roll) (body -> map)."""
    return _rot(_rot(_rot(v, "x", roll), "y", pitch), "z", yaw_total)


def _mirror(x: np.ndarray, pattern: str) -> np.ndarray:
    """Scan angle as a fraction of the largest one (−1..1) at mirror phase ``x`` (periods)."""
    if pattern == "zigzag":
        return (1 - _MIRROR_SINE) * _triangle(x) + _MIRROR_SINE * np.sin(2 * np.pi * x)
    # parallel (and, on average, random): every scan angle equally often
    return 2.0 * (x - np.floor(x)) - 1.0


def strip_layout(options, heading_deg: float = 10.0) -> dict:
    """Strips over the scene: offsets across track (m), swath (m), mean coverage and pulse rates.

    Strip centre lines are spaced ``swath (1 − overlap)`` apart and placed
    symmetrically about the scene centre, so the overlap zone runs through
    the middle; the mean number of strips over a scene point is ``coverage``
    and each strip gets about ``density / coverage``.  The pulse rate is set
    so that the mean density over the scene, with the mirror's across-track
    pattern, is exactly ``density``.
    """
    h = math.radians(heading_deg)
    along = np.array([math.sin(h), math.cos(h)])
    across = np.array([math.cos(h), -math.sin(h)])
    swath = 2.0 * options.flying_height * math.tan(math.radians(options.scan_angle_deg))
    spacing = swath * (1.0 - options.strip_overlap)
    g = np.linspace(-options.size / 2, options.size / 2, 81)
    gx, gy = np.meshgrid(g, g)
    a = gx.ravel() * across[0] + gy.ravel() * across[1]
    half = np.abs(a).max()
    offsets = [(k + 0.5) * spacing for k in range(-int(half / spacing) - 3, int(half / spacing) + 3)]
    offsets = [o for o in offsets if abs(o) - swath / 2 < half]
    count = sum((np.abs(a - o) <= swath / 2).astype(float) for o in offsets)
    coverage = float(count.mean())
    # across-track density of one strip per unit pulse rate: the mirror's pattern crowds the swath edges
    x = (np.arange(20000) + 0.5) / 20000
    theta = math.radians(options.scan_angle_deg)
    pattern = options.scan_pattern
    pos = options.flying_height * np.tan(theta * _mirror(x, pattern))
    edges = np.linspace(-swath / 2, swath / 2, 201)
    pdf = np.histogram(pos, edges)[0] / (len(x) * np.diff(edges))
    mids = (edges[1:] + edges[:-1]) / 2
    per_rate = sum(float(np.interp(a - o, mids, pdf, left=0.0, right=0.0).mean()) for o in offsets)
    rate = options.density * options.flight_speed / per_rate
    d_strip = options.density / coverage
    # lines per second = speed / line spacing; a zigzag sweeps two lines a period
    sweeps = 2.0 if pattern == "zigzag" else 1.0
    if options.line_spacing is None:
        line_spacing = 1.0 / math.sqrt(d_strip)
        mirror = math.sqrt(d_strip) * options.flight_speed / sweeps
    else:
        line_spacing = float(options.line_spacing)
        mirror = options.flight_speed / line_spacing / sweeps
    length = float(np.abs(gx.ravel() * along[0] + gy.ravel() * along[1]).max())
    return dict(along=along, across=across, swath=swath, offsets=offsets, coverage=coverage, strip_density=d_strip,
                pulse_rate=rate, mirror_hz=mirror, half_length=length, line_spacing=line_spacing,
                point_spacing=1.0 / (d_strip * line_spacing), pattern=pattern)


def _triangle(x):
    return (2.0 / np.pi) * np.arcsin(np.sin(2.0 * np.pi * x))


def _strip_pulses(options, layout, k, z_ref, rng):
    """Origins, unit directions, times and scan angles of strip ``k``'s pulses."""
    along, across = layout["along"], layout["across"]
    direction = 1.0 if k % 2 == 0 else -1.0
    fwd = along * direction
    margin = 25.0
    length = 2.0 * (layout["half_length"] + margin)
    duration = length / options.flight_speed
    rate = layout["pulse_rate"]
    n = int(duration * rate)
    t = np.arange(n) / rate
    c = np.asarray(options.center)
    start = c + layout["offsets"][k] * across - fwd * (layout["half_length"] + margin)
    ph = rng.uniform(0, 2 * np.pi, 8)
    if layout["pattern"] == "random":
        t = np.sort(rng.uniform(0.0, duration, n))
    drift = 1.5 * np.sin(2 * np.pi * t / 11.0 + ph[0])
    pos = np.empty((n, 3))
    pos[:, :2] = start + np.outer(t * options.flight_speed, fwd) + np.outer(drift, across)
    pos[:, 2] = z_ref + options.flying_height + 2.0 * np.sin(2 * np.pi * t / 9.0 + ph[1])
    roll = np.radians(0.35 * np.sin(2 * np.pi * t / 6.5 + ph[2]) + 0.1 * np.sin(2 * np.pi * t / 1.7 + ph[3]))
    pitch = np.radians(0.25 * np.sin(2 * np.pi * t / 8.0 + ph[4]))
    yaw = np.radians(0.3 * np.sin(2 * np.pi * t / 12.0 + ph[5]))
    heading = math.atan2(fwd[1], fwd[0])  # body x axis = flight direction
    phase = rng.uniform()
    if layout["pattern"] == "random":
        fraction = rng.uniform(-1.0, 1.0, n)
    else:
        fraction = _mirror(layout["mirror_hz"] * t + phase, layout["pattern"])
    beta = math.radians(options.scan_angle_deg) * fraction
    beam = np.column_stack([np.zeros(n), np.sin(beta), -np.cos(beta)])  # R_{alpha,beta} [0, 0, -1]
    beam = _rot(_rot(_rot(beam, "x", _BORESIGHT[0]), "y", _BORESIGHT[1]), "z", _BORESIGHT[2])  # R_delta
    dirs = _attitude(beam, roll, pitch, heading + yaw)  # R(t) R_delta R_ab [0, 0, -1]
    origins = pos + _attitude(np.tile(_LEVER_ARM, (n, 1)), roll, pitch, heading + yaw)  # X_o(t) + R(t) P_G
    dbeta = np.gradient(beta) if n > 1 else np.zeros(n)
    return origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True), t, beta, dbeta


def _wire_hits(origins, dirs, wires, t_max, rng):
    """Distance to the first conductor each ray passes within the laser footprint of (inf: none)."""
    t_hit = np.full(len(origins), np.inf)
    for x0, y0, x1, y1, z0, z1, sag in wires:
        a = np.array([x0, y0])
        u = np.array([x1 - x0, y1 - y0])
        length = np.hypot(*u)
        u /= length
        nrm = np.array([-u[1], u[0]])
        den = dirs[:, :2] @ nrm
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((a - origins[:, :2]) @ nrm) / den
        p = origins + t[:, None] * dirs
        s = ((p[:, :2] - a) @ u) / length
        zw = z0 + (z1 - z0) * s - 4 * sag * s * (1 - s)
        # the ray passes the (locally horizontal) wire at the wire's height, missing it by |dz| x |den|
        t = (zw - origins[:, 2]) / dirs[:, 2]
        hit = (np.abs(den) > 1e-9) & (s >= 0) & (s <= 1) & (np.abs(p[:, 2] - zw) * np.abs(den) < 0.15) & (t > 0) & (t < t_max)
        hit &= rng.random(len(t)) < 0.7
        t_hit = np.where(hit & (t < t_hit), t, t_hit)
    return t_hit


def _edge_returns(o, d, model: SurfaceModel, t_s, face, rt, rk, return_face, radius: float) -> None:
    """Split the returns of the pulses whose beam straddles a height step (in place).

    The beam is sampled by its axis and four parallel rays ``radius`` off
    it; a pulse with one surface return whose nearest and farthest samples
    lie the 1 m dead zone apart (as in :func:`pulse_returns`) returns twice
    along its axis: first at the nearest range (the upper surface's face),
    last at the farthest.
    """
    alone = (rk[:, 0] == 1) & (rk[:, 1] == 0) & np.isfinite(t_s)
    idx = np.flatnonzero(alone)
    if not len(idx):
        return
    dd = d[idx]
    side = np.cross(dd, [0.0, 0.0, 1.0])
    norm = np.linalg.norm(side, axis=1, keepdims=True)
    side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-12), [1.0, 0.0, 0.0])  # a beam straight down: any
    other = np.cross(dd, side)
    t_all, f_all = [t_s[idx]], [face[idx]]
    for offset in (side, -side, other, -other):
        t, f, _ = cast_rays(np.ascontiguousarray(o[idx] + radius * offset), np.ascontiguousarray(dd),
                            *model.args(), model.z_top, model.z_bot)
        t_all.append(np.where(np.isfinite(t), t, np.nan))
        f_all.append(f)
    t_all, f_all = np.column_stack(t_all), np.column_stack(f_all)
    near, far = np.nanargmin(t_all, axis=1), np.nanargmax(t_all, axis=1)
    rows = np.arange(len(idx))
    split = t_all[rows, far] - t_all[rows, near] >= 1.0
    i, near, far, rows = idx[split], near[split], far[split], rows[split]
    rt[i, 0], rt[i, 1] = t_all[rows, near], t_all[rows, far]
    rk[i, 1] = 1
    return_face[i, 0], return_face[i, 1] = f_all[rows, near], f_all[rows, far]


def scan_scene(options, model: SurfaceModel, trees: np.ndarray, wires: np.ndarray | None, face_building: np.ndarray,
               face_reflectance: np.ndarray, z_ref: float, rng: np.random.Generator) -> tuple[PointCloud, dict]:
    """Simulate the ALS survey of the scene.

    Parameters
    ----------
    options : SceneOptions
    model : SurfaceModel
    trees : ndarray of shape (T, 5)
        Crowns (cx, cy, cz, rh, rv).
    wires : ndarray of shape (W, 7) or None
        Conductors (:meth:`PowerLine.as_array`).
    face_building : ndarray of shape (F,) int32
        Building id of each face.
    face_reflectance : ndarray of shape (F,)
        Near-infrared reflectance of each face (0-1).
    z_ref : float
        Mean terrain height (m); the aircraft flies ``flying_height`` above it.
    rng : numpy.random.Generator

    Returns
    -------
    cloud : PointCloud
        Points inside the scene, in time order, with fields ``return_number``,
        ``number_of_returns``, ``intensity``, ``gps_time``,
        ``point_source_id`` (strip), ``scan_angle`` (LAS 1.4 units of
        0.006°), ``scan_direction_flag``, ``edge_of_flight_line``,
        ``classification`` (1), ``truth_class`` (uint8) and
        ``truth_building_id`` (int32).
    info : dict
        Strip layout and counts.
    """
    layout = strip_layout(options)
    x0, y0, x1, y1 = options.bounds
    parts = []
    for k in range(len(layout["offsets"])):
        o, d, t, beta, dbeta = _strip_pulses(options, layout, k, z_ref, rng)
        s = (z_ref - o[:, 2]) / d[:, 2]
        fx, fy = o[:, 0] + s * d[:, 0], o[:, 1] + s * d[:, 1]
        keep = (fx > x0 - 1) & (fx < x1 + 1) & (fy > y0 - 1) & (fy < y1 + 1)
        if keep.any():
            parts.append((k, o[keep], d[keep], t[keep] + 3.0e8 + 200.0 * k, beta[keep], dbeta[keep]))
    strip = np.concatenate([np.full(len(p[1]), p[0] + 1, np.uint16) for p in parts])
    o = np.concatenate([p[1] for p in parts])
    d = np.concatenate([p[2] for p in parts])
    gps = np.concatenate([p[3] for p in parts])
    beta = np.concatenate([p[4] for p in parts])
    dbeta = np.concatenate([p[5] for p in parts])
    n = len(o)
    t_s, face, wall = cast_rays(o, d, *model.args(), model.z_top, model.z_bot)
    t_max = np.where(np.isfinite(t_s), t_s, np.inf)
    trees = np.ascontiguousarray(trees, np.float64).reshape(-1, 5)
    tin, tout, tid = crown_chords(o, d, trees, t_max, 3)
    t_wire = _wire_hits(o, d, wires, t_max, rng) if wires is not None and len(wires) else np.full(n, np.inf)
    u = rng.random((n, 8))
    rt, rk, rtree = pulse_returns(t_s, tin, tout, tid, t_wire, u, _MAX_RETURNS)
    return_face = np.repeat(face[:, None], rt.shape[1], axis=1)
    if options.beam_radius > 0:
        _edge_returns(o, d, model, t_s, face, rt, rk, return_face, options.beam_radius)
    if options.single_return:
        # a single-return scanner records the first echo only
        rt[:, 1:] = np.inf
        rk[:, 1:] = 0
    nret = (rk > 0).sum(axis=1)
    # outliers: the pulse gives one spurious echo high above (birds, haze) or below (multipath) the surface
    out = rng.random(n) < options.outlier_fraction
    out &= nret > 0
    if out.any():
        high = rng.random(out.sum()) < 0.6
        first = rt[out, 0]
        tt = np.where(high, first - rng.uniform(15.0, 150.0, out.sum()),
                      t_max[out] + rng.uniform(1.5, 10.0, out.sum()) / np.abs(d[out, 2]))
        rt[out] = np.inf
        rk[out] = 0
        rt[out, 0] = np.where(np.isfinite(tt), tt, first)
        rk[out, 0] = 4
        nret[out] = 1
    pulse, slot = np.nonzero(rk > 0)
    kind = rk[pulse, slot]
    rng_noise = rng.normal(0.0, options.range_noise, len(pulse))
    rho = rt[pulse, slot] + rng_noise
    xyz = o[pulse] + rho[:, None] * d[pulse]
    inside = (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    pulse, slot, kind, rho, xyz = pulse[inside], slot[inside], kind[inside], rho[inside], xyz[inside]
    f = return_face[pulse, slot]
    truth = np.select([kind == 4, kind == 3, kind == 2, f >= 0], [7, ASPRS_WIRE, 5, 6], 2).astype(np.uint8)
    bid = np.where((kind == 1) & (f >= 0), face_building[np.maximum(f, 0)], 0).astype(np.int32)
    # intensity: reflectance x incidence / range^2, shared among the returns
    refl = np.select([kind == 4, kind == 3, kind == 2, f >= 0], [0.2, 0.25, 0.5, face_reflectance[np.maximum(f, 0)]], 0.42)
    pl = model.planes[np.maximum(f, 0)]
    nrm = np.column_stack([-pl[:, 0], -pl[:, 1], np.ones(len(f))])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    cos_i = np.where((kind == 1) & (f >= 0), np.abs(np.einsum("ij,ij->i", nrm, d[pulse])), 0.95)
    cos_i = np.where(wall[pulse] & (kind == 1), 0.3, cos_i)
    share = 1.0 / nret[pulse]
    inten = 900.0 * refl * cos_i * (options.flying_height / rho) ** 2 * np.sqrt(share) + rng.normal(0, 12, len(rho))
    fields = {
        "return_number": (slot + 1).astype(np.uint8),
        "number_of_returns": nret[pulse].astype(np.uint8),
        "intensity": np.clip(inten, 0, 65535).astype(np.uint16),
        "gps_time": gps[pulse].astype(np.float64),
        "point_source_id": strip[pulse],
        "scan_angle": np.round(np.degrees(beta[pulse]) / 0.006).astype(np.int16),
        "scan_direction_flag": (dbeta[pulse] > 0).astype(np.uint8),
        "edge_of_flight_line": (np.abs(beta[pulse]) > 0.995 * math.radians(options.scan_angle_deg)).astype(np.uint8),
        "classification": np.ones(len(pulse), np.uint8),
        "truth_class": truth,
        "truth_building_id": bid,
    }
    info = {
        "strips": len(parts),
        "swath_m": layout["swath"],
        "strip_coverage": layout["coverage"],
        "pulse_rate_hz": layout["pulse_rate"],
        "mirror_hz": layout["mirror_hz"],
        "scan_pattern": layout["pattern"],
        "line_spacing_m": layout["line_spacing"],
        "point_spacing_m": layout["point_spacing"],
        "pulses": int(n),
        "points": int(len(pulse)),
    }
    log.info("ALS: %d strips, %.0f kHz, %d pulses, %d points", len(parts), layout["pulse_rate"] / 1e3, n, len(pulse))
    return PointCloud(xyz, fields), info
