"""rooftrace: 3D building roof outlines and ridges from airborne LiDAR (and an aerial image).

The main entry points are importable from the top level; each is loaded on
first use, so ``import rooftrace`` stays fast (and the command line installs
its signal handlers before numpy and the stages load).

======================  =====================================================
reading points          :func:`read_points` -> :class:`PointCloud`
the whole method        :func:`run_pipeline` -> :class:`RunResult`
... in tiles            :func:`run_tiled` -> :class:`TiledRunResult`
options of a run        :class:`RunOptions`, :class:`TileOptions`
building detection      :func:`detect_buildings`
roof outlines           :func:`outline_buildings`
roof planes and ridges  :func:`roof_structure`
image refinement        :func:`refine_buildings`
evaluation              :func:`evaluate_outlines`
simulation              :func:`simulate_scene`
writing outputs         :func:`write_layers`, :func:`write_las`
======================  =====================================================

Examples
--------
>>> import rooftrace
>>> scene = rooftrace.simulate_scene(rooftrace.SceneOptions(seed=1, size=40.0, density=8.0, image=False,
...                                                         trees=False))
>>> result = rooftrace.run_pipeline(scene.cloud)
>>> truth = scene.truth["roof_outlines"].geometries
>>> scores = rooftrace.evaluate_outlines(result.layers["roof_outlines"].geometries, truth)
>>> scores["n_matched"], scores["f_score"] > 0.9
(1, True)
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> the module that defines it (and the name there, when another)
_ENTRY_POINTS = {
    "read_points": "rooftrace.io.points",
    "run_pipeline": "rooftrace.pipeline",
    "run_tiled": "rooftrace.tiling",
    "detect_buildings": "rooftrace.lidar.detect",
    "outline_buildings": "rooftrace.contour.outline",
    "roof_structure": "rooftrace.roof.structure",
    "refine_buildings": "rooftrace.refine.buildings",
    # not "evaluate": the subpackage of that name would replace it once imported
    "evaluate_outlines": ("rooftrace.evaluate", "evaluate"),
    "simulate_scene": "rooftrace.synth.simulate",
    "write_layers": "rooftrace.io.vector",
    "write_las": "rooftrace.io.las",
}
#: the types the entry points take and return
_TYPES = {
    "PointCloud": "rooftrace.cloud",
    "RunResult": "rooftrace.pipeline",
    "RunOptions": "rooftrace.config",
    "TileOptions": "rooftrace.tiling.split",
    "TiledRunResult": "rooftrace.tiling",
    "Layer": "rooftrace.io.vector",
    "SceneOptions": "rooftrace.synth.scene",
}

__all__ = [*_ENTRY_POINTS, *_TYPES, "__version__"]


def __getattr__(name: str) -> Any:
    where = _ENTRY_POINTS.get(name) or _TYPES.get(name)
    if where is None:
        raise AttributeError(f"module 'rooftrace' has no attribute {name!r}")
    module, attr = where if isinstance(where, tuple) else (where, name)
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value  # the next look-up does not come here
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
