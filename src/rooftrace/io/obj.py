"""Wavefront OBJ of the models, for 3D viewers (MeshLab, Blender, online viewers), streamed.

One object (``o``) per building, one group (``g``) per semantic surface type
inside it; each building's best level of detail (2.2, else 1.3, else 1.2).
Surfaces with holes or more than four vertices are triangulated
(constrained Delaunay in their plane, :func:`shapely.constrained_delaunay_triangles`),
since viewers fan-triangulate polygons and would fill concave ones wrongly.
Coordinates are written relative to a translation (the first model's lowest
corner rounded down to 100 m, given in the file's first lines), because
viewers work in single precision.
"""

from __future__ import annotations

import os

import numpy as np
import shapely

from rooftrace.io.streamed import StreamedOutput
from rooftrace.model.types import LODS, SURFACE_KINDS
from rooftrace.model.validity import surface_normal

__all__ = ["OBJWriter", "surface_triangles"]


def surface_triangles(rings: list[np.ndarray]) -> list[tuple[int, int, int]]:
    """Triangles of a planar surface as index triples into its stacked ring vertices, same orientation."""
    pts = np.vstack(rings)
    n = surface_normal(rings)
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(a, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    c = pts.mean(axis=0)
    flat = np.column_stack([(pts - c) @ u, (pts - c) @ v])
    index = {tuple(p): i for i, p in enumerate(flat.tolist())}
    bounds = np.cumsum([0] + [len(r) for r in rings])
    poly = shapely.Polygon(flat[bounds[0]:bounds[1]], [flat[bounds[k]:bounds[k + 1]] for k in range(1, len(rings))])
    out = []
    for tri in shapely.get_parts(shapely.constrained_delaunay_triangles(poly)):
        xy = np.asarray(tri.exterior.coords)[:3]
        ids = [index.get(tuple(p)) for p in xy.tolist()]
        if None in ids:
            continue
        # counter-clockwise in the (u, v) plane is outward
        d = (xy[1, 0] - xy[0, 0]) * (xy[2, 1] - xy[0, 1]) - (xy[1, 1] - xy[0, 1]) * (xy[2, 0] - xy[0, 0])
        out.append(tuple(ids) if d > 0 else (ids[0], ids[2], ids[1]))
    return out


class OBJWriter(StreamedOutput):
    """Write models to an OBJ file one building at a time; atomic on :meth:`close`."""

    def __init__(self, path: str | os.PathLike, crs=None, *, overwrite: bool = False):
        super().__init__(path, overwrite)
        self._out = self._stack.enter_context(open(self._final, "w", encoding="utf-8"))  # noqa: SIM115
        self._n = 0

    def add(self, model) -> None:
        """Append one building (its best level of detail per part)."""
        solids = []
        for part in model.parts:
            lod = next((k for k in LODS[::-1] if k in part.lods), None)
            if lod is not None:
                solids.append(part.lods[lod])
        if not solids:
            return
        if self.translate is None:
            self._origin(solids)
            self._out.write("# rooftrace 3D buildings\n# translate {:.3f} {:.3f} {:.3f}\n".format(*self.translate))
        self._out.write(f"o building_{model.building_id}\n")
        for kind in SURFACE_KINDS:
            faces = [f for s in solids for f in s.surfaces if f.kind == kind]
            if not faces:
                continue
            self._out.write(f"g {kind}\n")
            lines = []
            for f in faces:
                pts = np.vstack(f.rings) - self.translate
                lines.extend("v {:.3f} {:.3f} {:.3f}".format(*p) for p in pts)
                if len(f.rings) == 1 and (len(pts) == 3 or kind == "WallSurface"):  # walls are convex
                    tris = [tuple(range(len(pts)))]
                else:
                    tris = surface_triangles(f.rings)
                lines.extend("f " + " ".join(str(self._n + i + 1) for i in t) for t in tris)
                self._n += len(pts)
            self._out.write("\n".join(lines) + "\n")
        self.count += 1
