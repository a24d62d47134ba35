"""The detection flow: outliers → spacing → ground → features → segmentation → building/vegetation.

Stages and where they follow the thesis (Santos 2019, ch. 3):

1. cell-histogram outliers (§3.1) → class 7;
2. s_avg, d_avg, sigma_H from the data (§6.1, Table 6.1), and the scan
   pattern: the widest common gap (0.99 quantile of the Delaunay edges)
   and the neighbourhood size reaching across the scan lines
   (:func:`rooftrace.lidar.spacing.spanning_neighbours`), so every
   threshold follows the data from 1.5 to 40 pts/m²;
3. progressive TIN densification (§3.2) → class 2 and the height above
   ground (HAG) of every point;
4. eigen-features (L, P, S, entropy; N = Ar_min·d_avg neighbours, or by
   default the size up to N of lowest entropy, :mod:`rooftrace.lidar.features`)
   and a surface normal for every non-ground point (§3.4);
5. region growing of the points above ``segment.min_height`` into roof-level
   clusters (§3.3; the height test is measured along the normals; beyond
   the thesis each point is also linked to its nearest point per direction,
   so roofs hold together across scan lines farther apart than L_Dxy,
   :func:`rooftrace.lidar.segment.sector_pairs`);
6. k-means on the mean entropy of the clusters of at least T_Np points
   (§3.4) with the guards of :mod:`rooftrace.lidar.classify`, and by
   default (``classify.decision``) the plane residual of each cluster
   beside it; building clusters that touch in plan, or lie within the
   widest scan gap, are merged into buildings.

Beyond the thesis, linear clusters beside a building cluster join it (narrow
roof strips cut into scan lines, ``classify.linear_joins``); a building then
takes in the non-ground points next to it whose own entropy is on the
building side (walls, roof edges, dormers cut off by the height test), and
drops out when it is narrower than ``segment.min_width`` or when the laser
went through it (``classify.max_penetration``, counted away from roof edges
where pulses split); patches of it the laser went through leave it
(``classify.max_patch_penetration``); see :mod:`rooftrace.lidar.buildings`.

Class rules (first match wins):

1. noise (outlier filter) → 7;
2. ground (height above the TIN at most ``ground.ground_tolerance``) → 2,
   whatever stands on it;
3. a point of a building → 6, with its ``building_id`` (1..B, by each
   building's lowest (x, y) point) and ``roof_level_id`` (0 for absorbed
   wall points that belong to no roof level);
4. a point of another cluster of at least T_Np points, not linear → 5 (high
   vegetation);
5. anything else (low objects, small or linear clusters) → 1.

The input's own classification is never read.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from rooftrace.cloud import ASPRS, PointCloud
from rooftrace.errors import GeometryError, InputError
from rooftrace.lidar._kernels import column_max, column_min, union_pairs
from rooftrace.lidar.buildings import assemble_buildings, group_widths, split_patches
from rooftrace.lidar.classify import ClassifyOptions, cluster_means, cluster_medians, separate_buildings
from rooftrace.lidar.derived import DerivedParams
from rooftrace.lidar.features import eigen_features
from rooftrace.lidar.ground import GroundOptions, progressive_tin
from rooftrace.lidar.outliers import OutlierOptions, histogram_outliers
from rooftrace.lidar.segment import SegmentOptions, join_strips, link_pairs, order_labels, region_growing, sector_pairs
from rooftrace.lidar.spacing import edge_spacing, height_precision, point_density, spanning_neighbours
from rooftrace.options import make_options, options_dict
from rooftrace.progress import Reporter

__all__ = ["DetectOptions", "DerivedParams", "Detection", "detect_buildings"]

log = logging.getLogger(__name__)

#: mean Delaunay edge of random (Poisson) points of unit density, 32/(9 pi) (Miles 1970)
POISSON_EDGE = 32.0 / (9.0 * np.pi)



@dataclass(frozen=True)
class DetectOptions:
    """Options of every detection stage, one frozen dataclass per stage."""

    outliers: OutlierOptions = field(default_factory=OutlierOptions)
    ground: GroundOptions = field(default_factory=GroundOptions)
    segment: SegmentOptions = field(default_factory=SegmentOptions)
    classify: ClassifyOptions = field(default_factory=ClassifyOptions)

    @classmethod
    def from_config(cls, config: dict | None = None, **overrides: Any) -> DetectOptions:
        """Build from a TOML config dict (:func:`rooftrace.config.load_config`) and per-stage overrides.

        ``overrides`` maps a section name (``"segment"`` ...) to a dict of
        option overrides, e.g. from CLI flags; ``None`` values are ignored.
        """
        parts = {}
        for name, opt_cls in (("outliers", OutlierOptions), ("ground", GroundOptions),
                              ("segment", SegmentOptions), ("classify", ClassifyOptions)):
            parts[name] = make_options(opt_cls, config, **overrides.get(name, {}))
        return cls(**parts)


@dataclass
class Detection:
    """Result of :func:`detect_buildings`.

    Attributes
    ----------
    classification : ndarray of shape (N,), uint8
        ASPRS classes: 2 ground, 6 building, 5 high vegetation, 7 noise, 1 other.
    building_id : ndarray of shape (N,), int32
        1..B, numbered by each building's lowest (x, y) point; 0 = none.
    roof_level_id : ndarray of shape (N,), int32
        Roof-level cluster of building points, 1..R, numbered the same way; 0 = none.
    hag : ndarray of shape (N,), float64
        Height above the ground TIN (m).
    mean_spacing, density, sigma_h : float
        s_avg (m), d_avg (pts/m²), sigma_H (m).
    params : dict
        Every resolved threshold, per stage.
    timings : dict
        Seconds per stage.
    derived : DerivedParams
        The data-derived parameters this detection used, all resolved.
    """

    classification: np.ndarray
    building_id: np.ndarray
    roof_level_id: np.ndarray
    hag: np.ndarray
    mean_spacing: float
    density: float
    sigma_h: float
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    derived: DerivedParams = field(default_factory=DerivedParams)

    @property
    def n_buildings(self) -> int:
        return int(self.building_id.max(initial=0))


@contextlib.contextmanager
def _timed(timings: dict[str, float], reporter: Reporter, name: str) -> Iterator[None]:
    """Report a stage and add its wall time to ``timings``."""
    with reporter.stage(name):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0


def _check_cloud(cloud: PointCloud) -> None:
    where = ", ".join(cloud.sources) or "point cloud"
    if len(cloud) < 3:
        raise InputError(f"{where}: {len(cloud)} points; detection needs a LiDAR cloud with at least 3 points")
    if not np.isfinite(cloud.xyz).all():
        raise InputError(f"{where}: NaN or infinite coordinates; clean the file first")
    if cloud.crs is not None and cloud.crs.is_geographic:
        raise InputError(
            f"{where}: CRS {cloud.crs.name} is geographic (degrees); reproject to a projected CRS in metres"
        )
    span = column_max(cloud.xyz[:, :2]) - column_min(cloud.xyz[:, :2])
    if not (span > 0).all():
        raise InputError(f"{where}: all points lie on one line; detection needs an area")


def _penetration(cloud: PointCloud, index: np.ndarray) -> np.ndarray | None:
    """1.0 where a point is not the last return of its pulse, from the LAS return numbers; None without them."""
    rn = cloud.fields.get("return_number")
    nr = cloud.fields.get("number_of_returns")
    if rn is None or nr is None or not np.any(nr[index] > 1):
        return None
    return (rn[index] < nr[index]).astype(np.float64)


def detect_buildings(
    cloud: PointCloud,
    options: DetectOptions | None = None,
    *,
    config: dict | None = None,
    reporter: Reporter | None = None,
    derived: DerivedParams | None = None,
) -> Detection:
    """Classify a LiDAR cloud into ground, buildings, vegetation and noise.

    Parameters
    ----------
    cloud : PointCloud
        Points in a projected CRS (metres).  Its ``classification`` field is
        ignored.
    options : DetectOptions, optional
        Stage options; when omitted they come from ``config`` (a dict from
        :func:`rooftrace.config.load_config`) or the defaults.
    config : dict, optional
        TOML config, used when ``options`` is None.
    reporter : Reporter, optional
        Progress reporter (silent by default).
    derived : DerivedParams, optional
        Data-derived parameters to use instead of measuring them on
        ``cloud`` (each ``None`` field is still measured).  Tiled runs pass
        the values of the whole input.

    Returns
    -------
    Detection

    Raises
    ------
    InputError
        Fewer than 3 points, non-finite coordinates, geographic CRS, or all
        points on one line.

    Examples
    --------
    >>> from rooftrace.synth import SceneOptions, simulate_scene
    >>> scene = simulate_scene(SceneOptions(seed=1, size=40.0, density=8.0, image=False, trees=False))
    >>> detection = detect_buildings(scene.cloud)
    >>> np.unique(detection.building_id).tolist()
    [0, 1]
    """
    _check_cloud(cloud)
    opt = options or DetectOptions.from_config(config)
    # small per-facet / per-point LAPACK calls (Qhull, eigh): one BLAS thread
    with threadpool_limits(limits=1, user_api="blas"):
        return _detect(cloud, opt, reporter, derived or DerivedParams())


def _detect(cloud: PointCloud, opt: DetectOptions, reporter: Reporter | None, fixed: DerivedParams) -> Detection:
    timings: dict[str, float] = {}
    clock = functools.partial(_timed, timings, reporter or Reporter())
    xyz = cloud.xyz
    n = len(xyz)
    cls = np.full(n, ASPRS.UNCLASSIFIED, np.uint8)
    params: dict[str, Any] = {}
    lo, hi = column_min(xyz[:, :2]), column_max(xyz[:, :2])
    origin = tuple(float(v) for v in lo) if fixed.origin is None else fixed.origin
    extent = (tuple(float(v) for v in (*lo, *hi))
              if fixed.extent is None else fixed.extent)
    # local frames are shifted by this fixed corner only (not by the
    # data's own minimum), so a tile rounds exactly like the whole cloud
    shift = np.array([origin[0], origin[1], 0.0])

    with clock("outliers"):
        noise = histogram_outliers(xyz, opt.outliers, origin=origin)
        params["outliers"] = {**options_dict(opt.outliers), "n_noise": int(noise.sum())}
    clean = xyz[~noise]
    if len(clean) < 3:
        raise InputError(f"{', '.join(cloud.sources) or 'point cloud'}: every point is an outlier")

    with clock("spacing"):
        try:
            s_avg, gap = fixed.mean_spacing, fixed.scan_gap
            if s_avg is None or gap is None:
                measured = edge_spacing(clean[:, :2])
                s_avg = measured[0] if s_avg is None else s_avg
                gap = measured[1] if gap is None else gap
            s_avg, gap = float(s_avg), float(gap)
            d_avg = point_density(clean[:, :2]) if fixed.density is None else float(fixed.density)
            sigma_h = height_precision(clean) if fixed.sigma_h is None else float(fixed.sigma_h)
            k_span = (spanning_neighbours(clean[:, :2], d_avg) if fixed.spanning_neighbours is None
                      else int(fixed.spanning_neighbours))
        except ValueError as exc:
            raise InputError(f"{', '.join(cloud.sources) or 'point cloud'}: {exc}") from None
        params["spacing"] = {"mean_spacing": s_avg, "density": d_avg, "sigma_h": sigma_h, "origin": list(origin),
                             "scan_gap": gap, "spanning_neighbours": k_span}

    with clock("ground"):
        try:
            ground, hag, gparams = progressive_tin(xyz, s_avg, sigma_h, opt.ground, exclude=noise, origin=origin,
                                                   bounds=extent)
        except GeometryError as exc:
            raise InputError(f"{', '.join(cloud.sources) or 'point cloud'}: {exc}") from None
        params["ground"] = {**options_dict(opt.ground), **gparams}

    so = opt.segment
    # s_avg, the mean Delaunay edge, grows with the gaps between scan lines
    # (1.15-1.35 times that of random points of the same density, 1.132/sqrt(d_avg),
    # where the lines lie far apart); where the sector links bridge those gaps
    # L_Dxy follows the density, or it links crowns into roofs over 1.5 m
    spacing = min(s_avg, POISSON_EDGE / np.sqrt(d_avg)) if so.link_sectors else s_avg
    link_d = so.link_distance or so.link_factor * spacing
    # roof levels split by a gap between scan lines are one building
    merge_d = so.merge_distance or max(link_d, gap)
    # along the normals the pair test must also absorb the normals' own
    # error (about 17 deg over L_Dxy), more than sigma_H on tiled roofs
    link_h = so.link_height or (max(2.0 * sigma_h, 0.3 * link_d) if so.height_test == "normal" else 2.0 * sigma_h)
    min_pts = so.min_points or max(1, int(round(so.min_area * d_avg)))
    # paired scan lines lie up to twice the widest common gap apart
    reach = max(link_d, 2.0 * gap) if so.link_sectors else None
    co = opt.classify
    k_nb = co.neighbours or int(np.clip(round(so.min_area * d_avg), co.min_neighbours, co.max_neighbours))
    # the plane of a normal must rest on more than one scan line (lines far
    # apart: low density, older surveys), or it turns freely about the line
    k_normal = max(so.normal_neighbours, k_span)
    # every non-ground point gets eigen-features (walls and low annexes may
    # join a building later); only those above min_height are segmented
    above = np.flatnonzero(~noise & ~ground)
    pts = xyz[above] - shift if len(above) else np.empty((0, 3))
    high = np.flatnonzero(hag[above] >= so.min_height)
    with clock("features"):
        adaptive = co.neighbourhood == "adaptive"
        # the linear-object guard looks at N points: at the smallest adaptive
        # sizes a roof scanned in lines looks linear too (low entropy either way)
        feats, lin_n = eigen_features(pts, k_nb, normal_neighbours=k_normal,
                                      min_neighbours=min(co.min_neighbours, k_nb) if adaptive else None,
                                      neighbour_step=co.neighbour_step, return_linearity=True)
    with clock("segment"):
        pairs = link_pairs(pts[high, :2], link_d)
        if so.link_sectors:
            # every other point blocks a link: ground between a roof and a crown
            clean_idx = np.flatnonzero(~noise)
            where = np.full(n, -1, np.int64)
            where[clean_idx] = np.arange(len(clean_idx))
            across = sector_pairs(xyz[clean_idx, :2] - shift[:2], where[above[high]], reach, so.link_sectors,
                                  normals=feats[high, 4:7], max_angle=so.sector_max_angle,
                                  smooth=feats[high, 7] <= so.sector_max_residual * sigma_h)
            pairs = union_pairs(pairs, across, len(high))
        normals = feats[high, 4:7] if so.height_test == "normal" else None
        levels = region_growing(pts[high], link_d, link_h, so.max_slope, pairs=pairs, normals=normals,
                                max_normal_angle=so.max_normal_angle)
        returns = _penetration(cloud, above)
        split = (co.split_patches_from is not None and link_d >= co.split_patches_from
                 and co.max_penetration is not None and co.max_patch_penetration is not None)
        if split and returns is not None and len(levels):
            # at low density L_Dxy reaches into a crown over the eaves: the
            # roof is judged on its own points, the crown on its own
            levels = split_patches(pts[high, :2], levels, returns[high], co.patch_factor * link_d,
                                   co.max_patch_penetration, min_pts, co.max_penetration * co.building_penetration)
        sizes = np.bincount(levels, minlength=int(levels.max(initial=-1)) + 1)
        params["segment"] = {
            **options_dict(so), "link_distance": link_d, "sector_reach": reach, "link_height": link_h,
            "merge_distance": merge_d,
            "normal_neighbours": k_normal, "min_points": min_pts,
            "n_clusters": int(len(sizes)), "n_kept": int((sizes >= min_pts).sum()),
        }

    with clock("classify"):
        big = sizes >= min_pts
        ent = cluster_means(levels, feats[high, 3], len(sizes))
        lin = cluster_means(levels, lin_n[high], len(sizes))
        if fixed.entropy_threshold is None:
            _, cparams = separate_buildings(ent[big], lin[big], co)
        else:
            cent = None if fixed.entropy_centroids is None else list(fixed.entropy_centroids)
            cparams = {"method": "fixed", "entropy_threshold": float(fixed.entropy_threshold), "centroids": cent}
        threshold = cparams["entropy_threshold"]
        # a linear object is linear at every scale: its points look linear
        # and the cluster is narrow in plan.  A roof scanned in lines farther
        # apart than the points along them looks linear point by point at
        # low density, but it is wide
        width = group_widths(pts[high, :2], levels, len(sizes))
        linear_width = co.linear_width or link_d
        linear_level = (lin > co.max_linearity) & (width < linear_width)
        # small clusters (ridges, dormers, roof edges cut off by the height
        # test) take the threshold learnt on the big ones; the building size
        # filter below drops those that do not touch a building
        building_level = (ent <= threshold) & ~linear_level
        if co.decision == "residual":
            # a roof face is smooth at any density and scan pattern, a crown is not
            residual = cluster_medians(levels, feats[high, 7], len(sizes))
            smooth = residual <= co.max_residual * sigma_h
            centroids = cparams["centroids"]
            if centroids is None or centroids[1] - centroids[0] < co.min_gap:
                # one population (only houses, or only trees): the entropy
                # has nothing to split, and single-return crowns look as
                # planar as roofs to it; the residual alone decides
                building_level = smooth & ~linear_level
            else:
                building_level |= smooth & ~linear_level
            cparams["n_smooth"] = int((big & smooth).sum())
        linear = big & linear_level
        penetrated = np.zeros(len(sizes), bool)
        if co.max_penetration is not None and returns is not None:
            share = cluster_means(levels, returns[high], len(sizes))
            allowed = co.max_penetration
            if co.edge_allowance:
                # pulses split on roof edges: the band a spacing wide along a
                # level's edge is a larger part of it the fewer points it has
                # (2·sqrt(pi/n) of a disc of n points).  Measured from the
                # level's shape instead, ragged crowns would get the allowance
                edge = np.minimum(1.0, 2.0 * np.sqrt(np.pi / np.maximum(sizes, 1)))
                allowed = co.max_penetration + co.edge_allowance * edge
            penetrated = share > allowed
            beside = building_level & penetrated
            building_level &= ~penetrated
            cparams["n_penetrated"] = int((big & penetrated).sum())
            if co.penetrated_joins and len(pairs):
                building_level = join_strips(levels, pairs, pts[high, 2], beside, building_level, 2.0 * link_d)
        if co.linear_joins and len(pairs):
            # a narrow roof strip the height test cut into scan lines is a
            # row of linear levels along the roof or wall beside it
            strips = linear_level & (ent <= threshold) & ~penetrated
            building_level = join_strips(levels, pairs, pts[high, 2], strips, building_level, 2.0 * link_d)
        params["classify"] = {**options_dict(co), "neighbours": k_nb, **cparams, "linear_width": linear_width,
                              "n_building_levels": int(building_level.sum())}

    with clock("buildings"):
        group_all, levels_all = assemble_buildings(
            pts, hag[above], feats[:, 3], high, levels, pairs, building_level, big, returns,
            min_points=min_pts, link_distance=link_d, mean_spacing=s_avg, threshold=threshold,
            merge_distance=merge_d,
            centroids=cparams["centroids"], segment=so, classify=co)
        bid_local = order_labels(pts, group_all)
        level_local = order_labels(pts, np.where(bid_local >= 0, levels_all, -1))
        building_id = np.zeros(n, np.int32)
        roof_level_id = np.zeros(n, np.int32)
        building_id[above] = bid_local + 1
        roof_level_id[above] = level_local + 1
        veg = big[levels] & ~linear[levels] & (bid_local[high] < 0) if len(levels) else np.zeros(0, bool)
        cls[above[high[veg]]] = ASPRS.HIGH_VEGETATION
        cls[building_id > 0] = ASPRS.BUILDING
        cls[ground] = ASPRS.GROUND
        cls[noise] = ASPRS.NOISE
        building_id[cls != ASPRS.BUILDING] = 0
        roof_level_id[cls != ASPRS.BUILDING] = 0
        params["buildings"] = {"n_buildings": int(building_id.max(initial=0))}

    log.info("detected %d buildings in %d points", int(building_id.max(initial=0)), n)
    return Detection(
        classification=cls,
        building_id=building_id,
        roof_level_id=roof_level_id,
        hag=hag,
        mean_spacing=s_avg,
        density=d_avg,
        sigma_h=sigma_h,
        params=params,
        timings=timings,
        derived=DerivedParams(
            origin=origin, extent=extent, mean_spacing=s_avg, density=d_avg, sigma_h=sigma_h, entropy_threshold=float(threshold),
            entropy_centroids=None if cparams["centroids"] is None else tuple(float(c) for c in cparams["centroids"]),
            scan_gap=gap, spanning_neighbours=k_span,
        ),
    )
