"""The data-derived detection parameters, measured once and fixed for every tile."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["DerivedParams"]


@dataclass(frozen=True)
class DerivedParams:
    """The detection parameters that come from the data, resolved or fixed.

    Every threshold of the detection follows from the options and these
    numbers.  Left ``None`` they are measured on the cloud being detected;
    a tiled run measures them once on the whole input (or a sample of it,
    see :func:`rooftrace.tiling.estimate_parameters`) and fixes them for
    every tile, so a tile detects its buildings exactly as the whole cloud
    would.  :attr:`Detection.derived` holds the values a run used, so
    ``detect_buildings(c, derived=detect_buildings(c).derived)`` gives the
    same result as ``detect_buildings(c)``.

    Attributes
    ----------
    origin : (float, float) or None
        Corner (m) the grids of the outlier filter and of the ground filter
        (candidate and seed cells) are anchored at, and the origin of the
        local frames.  ``None``: the lowest x and y of the cloud.
    extent : (float, float, float, float) or None
        xmin, ymin, xmax, ymax (m) the ground filter's border is laid
        around.  ``None``: the cloud's bounding box.  A tile uses its own
        extent clipped to the whole input's, so that along the true edges
        of the data its TIN ends where the whole cloud's does.
    mean_spacing : float or None
        s_avg (m), :func:`rooftrace.lidar.spacing.mean_spacing` of the points
        left by the outlier filter.
    density : float or None
        d_avg (pts/m²), :func:`rooftrace.lidar.spacing.point_density`.
    sigma_h : float or None
        sigma_H (m), :func:`rooftrace.lidar.spacing.height_precision`.
    entropy_threshold : float or None
        Building/vegetation boundary of the mean cluster entropy (k-means
        with k = 2, thesis §3.4; :func:`rooftrace.lidar.classify.separate_buildings`).
    entropy_centroids : (float, float) or None
        The two k-means centroids (building, vegetation), which bound the
        entropy of absorbed points (``segment.absorb_margin``); ``None`` with a
        fixed ``entropy_threshold`` means one population (no margin).
    """

    origin: tuple[float, float] | None = None
    extent: tuple[float, float, float, float] | None = None
    mean_spacing: float | None = None
    density: float | None = None
    sigma_h: float | None = None
    entropy_threshold: float | None = None
    entropy_centroids: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("mean_spacing", "density", "sigma_h"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"derived.{name} must be a finite number > 0, got {v}")
        if self.origin is not None and (len(self.origin) != 2 or not np.isfinite(self.origin).all()):
            raise ValueError(f"derived.origin must be two finite numbers, got {self.origin}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (floats round-trip exactly through :mod:`json`)."""
        return {
            "origin": None if self.origin is None else [float(v) for v in self.origin],
            "extent": None if self.extent is None else [float(v) for v in self.extent],
            "mean_spacing": self.mean_spacing,
            "density": self.density,
            "sigma_h": self.sigma_h,
            "entropy_threshold": self.entropy_threshold,
            "entropy_centroids": None if self.entropy_centroids is None else [float(v) for v in self.entropy_centroids],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DerivedParams:
        """Inverse of :meth:`to_dict`."""
        origin = d.get("origin")
        extent = d.get("extent")
        cent = d.get("entropy_centroids")
        return cls(
            origin=None if origin is None else (float(origin[0]), float(origin[1])),
            extent=None if extent is None else tuple(float(v) for v in extent),
            mean_spacing=d.get("mean_spacing"),
            density=d.get("density"),
            sigma_h=d.get("sigma_h"),
            entropy_threshold=d.get("entropy_threshold"),
            entropy_centroids=None if cent is None else (float(cent[0]), float(cent[1])),
        )
