"""The method as a flowchart: detect → outline → roof planes and ridges → 3D models → (image refinement).

Each step is one call into a stage package; this module only wires them,
groups points per building and turns the results into the output layers
(``roof_outlines``, ``ridges``, ``roof_faces``, ...).  It does no I/O:
the CLI reads the inputs and writes what :func:`run_pipeline` returns.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely
from threadpoolctl import threadpool_limits

from rooftrace.cloud import PointCloud
from rooftrace.config import RunOptions
from rooftrace.errors import GeometryError
from rooftrace.footprints import FootprintAssignment, Footprints
from rooftrace.io.vector import Layer
from rooftrace.progress import Reporter

if TYPE_CHECKING:
    from rooftrace.contour.outline import RoofOutline
    from rooftrace.image.camera import FrameCamera, OrthoCamera
    from rooftrace.lidar.detect import DerivedParams, Detection
    from rooftrace.model import BuildingModel, ModelOptions
    from rooftrace.parts import PartOptions
    from rooftrace.refine import LidarRoofs, RefineResult
    from rooftrace.roof import RoofOptions, RoofStructure

__all__ = ["RunResult", "run_pipeline", "points_by_building", "building_layers", "lidar_roofs", "refined_layers"]

log = logging.getLogger(__name__)


@dataclass
class RunResult:
    """Everything a run produced (:func:`run_pipeline`).

    Attributes
    ----------
    detection : rooftrace.lidar.detect.Detection
        Per-point classes, building ids, height above ground.
    outlines : list of RoofOutline
        One per building, sorted by building id.
    structures : list of RoofStructure
        Roof planes, faces and ridges per building (empty when disabled).
    refined : RefineResult or None
        Image refinement, when an image and a camera were given.
    layers : dict of str to Layer
        ``roof_outlines``, ``ridges``, ``roof_faces`` ready to write, and
        the models' 3D layers ``lod12``, ``lod13``, ``lod22`` when they were built.
    timings : dict of str to float
        Wall-clock seconds per step (the detection's steps too, in the
        ``--json`` summary).
    models : list of BuildingModel
        LoD 1.2 / 1.3 / 2.2 solids and attributes of every outlined
        building, in building-id order (empty when disabled).
    building_id : ndarray of shape (N,), int32 or None
        The building of every point (0 = none) the outlines and planes were
        made from: the detection's, or with footprints the footprint's index
        + 1.  None means ``detection.building_id``.
    footprints : Footprints or None
        The footprints given to the run (one building each, in order).
    assignment : FootprintAssignment or None
        Per footprint its status, reason and point counts.
    parts : list of BuildingParts
        Per building with an outline (in building-id order), its parts: a
        part id per point of ``members[building_id]`` and a polygon per part
        partitioning the outline.  Without footprints, LiDAR buildings split
        where the roof shows a boundary (:func:`rooftrace.parts.split_parts`);
        a footprint building is one part.
    cpu_seconds : dict of str to float
        CPU seconds of the process (all its threads) per step: ``detect``,
        the keys of ``timings`` and ``layers`` (the output layers).  On a shared machine the wall time
        grows with the load, this much less (benchmarks/bench_run_time.py).
    """

    detection: Detection
    outlines: list[RoofOutline]
    structures: list[RoofStructure]
    refined: RefineResult | None
    layers: dict[str, Layer]
    timings: dict[str, float] = field(default_factory=dict)
    models: list[BuildingModel] = field(default_factory=list)
    building_id: np.ndarray | None = None
    footprints: Footprints | None = None
    assignment: FootprintAssignment | None = None
    parts: list = field(default_factory=list)
    cpu_seconds: dict[str, float] = field(default_factory=dict)

    def point_labels(self) -> tuple[np.ndarray, np.ndarray]:
        """Class and building id of every point, in input order, as the layers number the buildings.

        With footprints the building of a point is its footprint's (the
        outlines were made from those points); else the detection's.
        """
        ids = self.building_id if self.footprints is not None else self.detection.building_id
        return self.detection.classification, ids

    def summary(self) -> dict[str, Any]:
        """A JSON-serialisable summary for ``--json``."""
        from rooftrace.contour.buildings import outline_statuses

        det = self.detection
        classes, counts = np.unique(det.classification, return_counts=True)
        return {
            "points": int(len(det.classification)),
            "classes": {int(c): int(n) for c, n in zip(classes, counts)},
            "buildings": len(self.outlines),
            "outline_status": outline_statuses(self.outlines),
            "ridges": len(self.layers["ridges"]),
            "roof_faces": len(self.layers["roof_faces"]),
            "building_parts": int(sum(p.n_parts for p in self.parts)),
            "refined": self.refined is not None,
            "models": {s: sum(m.attributes.get("status") == s for m in self.models)
                       for s in sorted({m.attributes.get("status") for m in self.models})},
            **({"footprints": {"count": len(self.footprints), "id_field": self.footprints.id_field,
                               "status": {k: self.assignment.status.count(k) for k in sorted(set(self.assignment.status))}}}
               if self.footprints is not None and self.assignment is not None else {}),
            "mean_spacing": float(det.mean_spacing),
            "density": float(det.density),
            "sigma_h": float(det.sigma_h),
            "parameters": det.params,
            "timings": {k: round(v, 3) for k, v in {**det.timings, **self.timings}.items()},
            # the camera's exterior orientation corrected from the refinement's line matches
            **({"orientation": self.refined.summary()["orientation"]}
               if self.refined is not None and getattr(self.refined, "orientation", None) is not None else {}),
        }


class _Clock:
    """Wall and process CPU seconds of the pipeline's steps, one step at a time."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._t0 = self._c0 = 0.0

    def start(self) -> None:
        self._t0, self._c0 = time.perf_counter(), time.process_time()

    def stop(self, step: str, *, wall: bool = True) -> None:
        if wall:
            self.wall[step] = time.perf_counter() - self._t0
        self.cpu[step] = time.process_time() - self._c0


def _went_through(cloud: PointCloud) -> np.ndarray | None:
    """Per point, whether its pulse had a later return (None without return numbers): the footprints' tree test."""
    rn, nr = cloud.fields.get("return_number"), cloud.fields.get("number_of_returns")
    if rn is None or nr is None:
        return None
    return np.asarray(rn) < np.asarray(nr)


def _last_returns(cloud: PointCloud) -> np.ndarray | None:
    """Per point, its pulse's last return (None without pulse times): the footprints' grazed chimney edges."""
    from rooftrace.footprints import last_returns

    names = ("gps_time", "point_source_id", "return_number", "number_of_returns")
    if any(cloud.fields.get(name) is None for name in names):
        return None
    return last_returns(*(np.asarray(cloud.fields[name]) for name in names))


def points_by_building(building_id: np.ndarray) -> dict[int, np.ndarray]:
    """Indices of the points of each building (ids > 0), without a Python loop over points."""
    building_id = np.asarray(building_id)
    idx = np.flatnonzero(building_id > 0)
    order = idx[np.argsort(building_id[idx], kind="stable")]
    ids, starts = np.unique(building_id[order], return_index=True)
    return {int(i): part for i, part in zip(ids, np.split(order, starts[1:]))}


def _roof_structures(cloud: PointCloud, members: dict[int, np.ndarray], outlines: list, options: RoofOptions,
                     mean_spacing: float, reporter: Reporter) -> list:
    from rooftrace.roof import roof_structure

    structures = []
    # one BLAS thread, as in the Dask workers (small calls: threads only
    # rendezvous; measured equal or faster on Delft)
    with reporter.stage("roof planes", total=len(outlines)), threadpool_limits(limits=1, user_api="blas"):
        for outline in outlines:
            idx = members.get(outline.building_id)
            reporter.advance()
            if idx is None or outline.polygon is None or outline.polygon.is_empty:
                continue
            try:
                structures.append(roof_structure(cloud.xyz[idx], outline.polygon, options,
                                                 mean_spacing=mean_spacing, building_id=outline.building_id))
            except GeometryError as exc:
                log.debug("building %d: no roof planes (%s)", outline.building_id, exc)
            except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                # a bug in one building (Qhull raises RuntimeError) must not stop a city
                log.warning("building %d: roof planes failed (%s: %s)", outline.building_id, type(exc).__name__, exc)
    return structures


def _building_parts(cloud: PointCloud, members: dict[int, np.ndarray], outlines: list, structures: list,
                    options: PartOptions, *, split: bool) -> list:
    """The parts of every outlined building; one part each unless ``split``."""
    from rooftrace.parts import split_parts

    by_id = {s.building_id: s for s in structures}
    parts = []
    for outline in outlines:
        if outline.polygon is None or outline.polygon.is_empty:
            continue
        bid = outline.building_id
        idx = members.get(bid, np.zeros(0, np.int64))
        st = by_id.get(bid)
        if not split or st is None or not st.faces:
            parts.append(split_parts(cloud.xyz[idx], outline.polygon, [], [], np.zeros((0, 4)), building_id=bid))
            continue
        try:
            parts.append(split_parts(cloud.xyz[idx], outline.polygon, st.faces, st.face_plane, st.planes, options,
                                     building_id=bid, plane_detail=st.plane_detail))
        except (ValueError, shapely.errors.GEOSException) as exc:  # one building must not stop a city
            log.warning("building %d: no part split (%s: %s)", bid, type(exc).__name__, exc)
            parts.append(split_parts(cloud.xyz[idx], outline.polygon, [], [], np.zeros((0, 4)), building_id=bid))
    return parts


def _building_models(cloud: PointCloud, hag: np.ndarray, members: dict[int, np.ndarray], outlines: list,
                     structures: list, options: ModelOptions, reporter: Reporter, *, parts: list | None = None,
                     footprints: Footprints | None = None, assignment: FootprintAssignment | None = None) -> list:
    """The 3D models of every outlined building: per part when it was split, with its footprint's id and status.

    A ``few_points`` footprint (:func:`rooftrace.footprints.assign_footprints`)
    is built from its fallback points: LoD 1.2 (and 1.3) from what there is.
    """
    from rooftrace.model import build_model, building_attributes, ground_height

    roofs = {s.building_id: s for s in structures}
    split = {p.building_id: p.polygons for p in parts or [] if p.n_parts > 1}
    models = []
    with reporter.stage("3D models", total=len(outlines)):
        for outline in outlines:
            reporter.advance()
            bid = outline.building_id
            idx = members.get(bid)
            if idx is None and assignment is not None and assignment.status[bid - 1] == "few_points":
                idx = assignment.fallback[bid - 1]
            if idx is None or not len(idx) or outline.polygon is None or outline.polygon.is_empty:
                continue  # no outline, no footprint: roof_outlines says why
            xyz = cloud.xyz[idx]
            ground = ground_height(xyz[:, 2] - hag[idx], options.ground_percentile)
            roof = roofs.get(bid)
            model = build_model(outline.polygon, roof, xyz, ground, parts=split.get(bid), building_id=bid,
                                options=options)
            model.attributes = building_attributes(model, roof, xyz, ground)
            if footprints is not None and assignment is not None:
                model.attributes.update(footprint_id=footprints.ids[bid - 1],
                                        footprint_status=assignment.status[bid - 1],
                                        footprint_reason=assignment.reason[bid - 1] or None)
            models.append(model)
    return models


def lidar_roofs(outlines: list[RoofOutline], structures: list[RoofStructure]) -> LidarRoofs:
    """What the image refinement takes of the LiDAR stages' results: outlines, ridges and roof planes.

    Parameters
    ----------
    outlines : list of RoofOutline
        One per building, in building-id order (failed ones without polygon).
    structures : list of RoofStructure
        Roof planes and ridges per building.

    Returns
    -------
    LidarRoofs
    """
    from rooftrace.refine import LidarRoofs

    ridges = [(g, int(st.building_id), k) for st in structures for g, k in zip(st.ridges, st.ridge_kind)]
    return LidarRoofs(building_ids=[int(o.building_id) for o in outlines], outlines=[o.polygon for o in outlines],
                      ridges=[g for g, _, _ in ridges], ridge_building_ids=[b for _, b, _ in ridges],
                      ridge_kinds=[k for _, _, k in ridges],
                      planes={int(s.building_id): s.planes for s in structures})


def refined_layers(layers: dict[str, Layer], refined: RefineResult) -> dict[str, Layer]:
    """The layers of a run with the image refinement's geometries and attributes.

    ``roof_outlines`` gets the refined geometries and the refinement's
    attributes, ``ridges`` are replaced by the refined ridges (attributes
    ``building_id``, ``kind``, ``refined``); the other layers stay.
    """
    outlines = layers["roof_outlines"]
    return {**layers,
            "roof_outlines": Layer(list(refined.outlines), {**outlines.attributes, **refined.attributes}, "PolygonZ"),
            "ridges": Layer(list(refined.ridges), dict(refined.ridge_attributes), "LineStringZ")}


def building_layers(outlines: list[RoofOutline], structures: list[RoofStructure],
                    refined: RefineResult | None = None, models: list[BuildingModel] | None = None, *,
                    parts: Layer | None = None, footprints: Footprints | None = None,
                    assignment: FootprintAssignment | None = None) -> dict[str, Layer]:
    """The output layers (docs/models.md) from the stage results, plus ``building_parts``.

    The 3D ``lodXX`` layers come when ``models`` is given.

    ``parts`` is the ``building_parts`` layer (:func:`rooftrace.parts.parts_layer`);
    without it the layer is written empty, with its schema.  With
    ``footprints`` (one outline per footprint, building id = index + 1)
    every layer gets the ``footprint_id`` column, and ``roof_outlines`` the
    footprint's status, reason and point counts
    (:func:`rooftrace.footprints.footprint_attributes`).
    """
    from rooftrace.contour.outline import outlines_layer
    from rooftrace.footprints import footprint_attributes
    from rooftrace.model.layers import model_layers
    from rooftrace.parts import parts_layer
    from rooftrace.roof import faces_layer, ridges_layer

    extra = footprint_attributes(footprints, assignment) if footprints is not None and assignment is not None else None
    layers = {"roof_outlines": outlines_layer(outlines, extra), "ridges": ridges_layer(structures),
              "roof_faces": faces_layer(structures), "building_parts": parts or parts_layer([], {}),
              **(model_layers(models) if models is not None else {})}
    if extra is not None:
        for name in [n for n in layers if n != "roof_outlines"]:
            layer = layers[name]
            ids = [footprints.ids[int(b) - 1] for b in layer.attributes["building_id"]]
            layers[name] = Layer(layer.geometries, {**layer.attributes, "footprint_id": ids}, layer.geometry_type)
    return layers if refined is None else refined_layers(layers, refined)


def run_pipeline(
    cloud: PointCloud,
    options: RunOptions | None = None,
    *,
    config: dict | None = None,
    alpha: str | None = None,
    planes: bool | None = None,
    image: np.ndarray | None = None,
    camera: FrameCamera | OrthoCamera | None = None,
    seed: int = 0,
    reporter: Reporter | None = None,
    derived: DerivedParams | None = None,
    buildings: Callable[[np.ndarray, Detection], np.ndarray] | None = None,
    models: bool = True,
    footprints: Footprints | None = None,
) -> RunResult:
    """Run the whole LiDAR method, and the image refinement when ``image`` and ``camera`` are given.

    Parameters
    ----------
    cloud : PointCloud
        Raw points in a projected CRS (metres); the input classification is ignored.
    options : RunOptions, optional
        Every option of the run (:class:`rooftrace.config.RunOptions`); by
        default built from ``config``, ``alpha`` and ``planes``.
    config : dict, optional
        Parsed TOML config, one table per stage, when ``options`` is not given
        (checked whole).
    alpha : {'global', 'building', 'point'}, optional
        Alpha-shape strategy (thesis S1, S2, S3), when ``options`` is not
        given; default from the config.
    planes : bool, optional
        Segment roof planes and derive ridges and faces, when ``options`` is
        not given; default from the config (True).
    image : ndarray of shape (H, W), optional
        Grey image in [0, 1] for the refinement.
    camera : FrameCamera or OrthoCamera, optional
        Orientation of ``image``.
    seed : int, default 0
        Seed of the genetic algorithm.
    reporter : Reporter, optional
        Progress callbacks.
    derived : rooftrace.lidar.detect.DerivedParams, optional
        Data-derived detection parameters fixed for this cloud (a tile of a
        tiled run gets those of the whole input); by default measured on
        ``cloud``.
    buildings : callable, optional
        ``buildings(xyz, detection)`` returns the ids of the buildings to
        outline; the others keep their detection but get no outline, planes
        or features (a tile of a tiled run outlines only the buildings it
        owns).  Default: all.
    models : bool, default True
        Build the LoD 1.2 / 1.3 / 2.2 models of every outlined building
        (LoD 2.2 needs roof planes; options ``options.model``) and their 3D layers.
    footprints : Footprints, optional
        Building footprints in the cloud's CRS: each becomes one building
        (its points inside and in the overhang band, ``options.footprints``),
        outlined and roofed on those points; footprints without usable
        points get a status and a fallback
        (:func:`rooftrace.footprints.assign_footprints`).  Without them the
        detected buildings are the buildings, split into parts where their
        roofs show a boundary (``options.parts``).

    Returns
    -------
    RunResult

    Examples
    --------
    >>> from rooftrace.synth import SceneOptions, simulate_scene
    >>> scene = simulate_scene(SceneOptions(seed=1, size=40.0, density=8.0, image=False, trees=False))
    >>> result = run_pipeline(scene.cloud)
    >>> len(result.outlines), sorted(result.layers)
    (1, ['building_parts', 'lod12', 'lod13', 'lod22', 'ridges', 'roof_faces', 'roof_outlines'])
    """
    from rooftrace.contour.outline import outline_buildings
    from rooftrace.footprints import assign_footprints, footprint_outlines
    from rooftrace.lidar.detect import detect_buildings
    from rooftrace.parts import parts_layer
    from rooftrace.refine import refine_roofs

    if options is None:
        options = RunOptions.from_config(config, alpha=alpha, planes=planes)
    elif config or alpha is not None or planes is not None:
        raise TypeError("run_pipeline: give options, or config, alpha and planes, not both")
    reporter = reporter or Reporter()
    clock = _Clock()

    clock.start()
    detection = detect_buildings(cloud, options.detect, reporter=reporter, derived=derived)
    clock.stop("detect", wall=False)  # the detection's own steps are in its timings
    building_id = detection.building_id
    assignment = None
    if footprints is not None:
        clock.start()
        with reporter.stage("footprints"):
            assignment = assign_footprints(cloud.xyz, detection.classification, detection.building_id, footprints,
                                           options.footprints, hag=detection.hag, density=detection.density,
                                           through=_went_through(cloud), last_return=_last_returns(cloud))
        building_id = assignment.building_id
        clock.stop("footprints")
    if buildings is not None:
        building_id = np.where(np.isin(building_id, np.asarray(buildings(cloud.xyz, detection))), building_id, 0)
    members = points_by_building(building_id)
    traced = building_id
    if assignment is not None and len(assignment.touching):
        traced = building_id.copy()
        traced[assignment.touching] = 0  # roof points, not the outline's (footprints.FootprintAssignment)

    clock.start()
    # the roof edge lies between the last roof point and the first that is not roof (noise aside)
    around = (traced <= 0) & (detection.classification != 7)
    outlines = outline_buildings(cloud.xyz, traced, options.outline, mean_spacing=detection.mean_spacing,
                                 reporter=reporter, context_xy=cloud.xyz[around])
    if assignment is not None:
        outlines = footprint_outlines(outlines, footprints, assignment, cloud.xyz)
    clock.stop("outline")

    structures: list = []
    if options.planes and outlines:
        clock.start()
        structures = _roof_structures(cloud, members, outlines, options.roof, detection.mean_spacing, reporter)
        clock.stop("roof_planes")

    clock.start()
    parts = _building_parts(cloud, members, outlines, structures, options.parts, split=footprints is None)
    clock.stop("parts")

    building_models = None
    if models:
        clock.start()
        building_models = _building_models(cloud, detection.hag, members, outlines, structures, options.model,
                                           reporter, parts=parts, footprints=footprints, assignment=assignment)
        clock.stop("models")

    refined = None
    if image is not None and camera is not None and outlines:
        clock.start()
        with reporter.stage("image refinement", total=None):
            refined = refine_roofs(lidar_roofs(outlines, structures), image, camera, points_xyz=cloud.xyz,
                                   options=options.refine, seed=seed)
        clock.stop("refine")
    clock.start()
    layers = building_layers(outlines, structures, refined, models=building_models, parts=parts_layer(parts, {
        p.building_id: cloud.xyz[members.get(p.building_id, np.zeros(0, np.int64)), 2] for p in parts}),
        footprints=footprints, assignment=assignment)
    clock.stop("layers", wall=False)

    return RunResult(detection, outlines, structures, refined, layers, clock.wall, building_models or [],
                     building_id=building_id, footprints=footprints, assignment=assignment, parts=parts,
                     cpu_seconds=clock.cpu)
