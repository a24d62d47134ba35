"""The point cloud that flows between stages.

A :class:`PointCloud` is a thin dataclass of numpy arrays: coordinates as an
``(N, 3) float64`` array in the file's CRS, every other dimension (LAS
standard and extra-byte dimensions alike) in ``fields`` keyed by its laspy
name, and the CRS itself.  Stages read and add fields; they never drop the
CRS.  ``template`` keeps the LAS header of the first input file so that a
writer can keep every input dimension, scale and offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["PointCloud", "ASPRS"]


class ASPRS:
    """ASPRS LAS classification codes used by rooftrace."""

    UNCLASSIFIED = 1
    GROUND = 2
    HIGH_VEGETATION = 5
    BUILDING = 6
    NOISE = 7


@dataclass
class PointCloud:
    """Points with their dimensions and CRS.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Coordinates in the CRS units (metres for projected CRSs).
    fields : dict of str to ndarray of shape (N,)
        Other per-point dimensions (``intensity``, ``return_number``,
        ``classification``, extra bytes ...).
    crs : pyproj.CRS or None
        Coordinate reference system; ``None`` when the file has none and the
        user gave no ``--crs``.
    template : laspy.LasHeader or None
        Header of the source LAS/LAZ file, used to write the same point
        format, scales, offsets and extra dimensions back.
    sources : list of str
        Source file names, for messages and attributes.
    """

    xyz: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    crs: Any = None
    template: Any = None
    sources: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.xyz = np.ascontiguousarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        n = len(self.xyz)
        for name, values in self.fields.items():
            if len(values) != n:
                raise ValueError(f"field {name!r} has {len(values)} values for {n} points")

    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def x(self) -> np.ndarray:
        return self.xyz[:, 0]

    @property
    def y(self) -> np.ndarray:
        return self.xyz[:, 1]

    @property
    def z(self) -> np.ndarray:
        return self.xyz[:, 2]

    def subset(self, mask_or_index: np.ndarray) -> PointCloud:
        """Return the points selected by a boolean mask or an index array."""
        return PointCloud(
            self.xyz[mask_or_index],
            {k: v[mask_or_index] for k, v in self.fields.items()},
            crs=self.crs,
            template=self.template,
            sources=list(self.sources),
        )

    @classmethod
    def concatenate(cls, clouds: list[PointCloud]) -> PointCloud:
        """Join clouds; fields missing in one cloud are filled with zeros."""
        if not clouds:
            raise ValueError("no point clouds to concatenate")
        if len(clouds) == 1:
            return clouds[0]
        names: dict[str, np.dtype] = {}
        for c in clouds:
            for k, v in c.fields.items():
                names.setdefault(k, v.dtype)
        fields = {
            k: np.concatenate([c.fields.get(k, np.zeros(len(c), dt)).astype(dt, copy=False) for c in clouds])
            for k, dt in names.items()
        }
        return cls(
            np.concatenate([c.xyz for c in clouds]),
            fields,
            crs=clouds[0].crs,
            template=clouds[0].template,
            sources=[s for c in clouds for s in c.sources],
        )
