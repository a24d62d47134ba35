"""rooftrace: 3D building roof outlines and ridges from airborne LiDAR (and an aerial image).

The main entry points are importable from the top level; each is loaded on
first use, so ``import rooftrace`` stays fast (and the command line installs
its signal handlers before numpy and the stages load).

======================  =====================================================
reading points          :func:`read_points` -> :class:`PointCloud`
the whole method        :func:`run_pipeline` -> :class:`RunResult`
building detection      :func:`detect_buildings`
roof outlines           :func:`outline_buildings`
roof planes and ridges  :func:`roof_structure`
image refinement        :func:`refine_buildings`
evaluation              :func:`evaluate`
simulation              :func:`simulate_scene`
writing outputs         :func:`write_layers`, :func:`write_las`
======================  =====================================================

Examples
--------
>>> import rooftrace
>>> scene = rooftrace.simulate_scene(rooftrace.SceneOptions(seed=1, size=40.0, density=8.0, image=False,
...                                                         trees=False))
>>> result = rooftrace.run_pipeline(scene.cloud)
>>> scores = rooftrace.evaluate(result.layers["roof_outlines"].geometries, scene.truth["roof_outlines"].geometries)
>>> scores["n_matched"], scores["f_score"] > 0.9
(1, True)
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> the module that defines it
_ENTRY_POINTS = {
    "read_points": "rooftrace.io.points",
    "run_pipeline": "rooftrace.pipeline",
    "detect_buildings": "rooftrace.lidar.detect",
    "outline_buildings": "rooftrace.contour.outline",
    "roof_structure": "rooftrace.roof.structure",
    "refine_buildings": "rooftrace.refine.buildings",
    "evaluate": "rooftrace.evaluate",
    "simulate_scene": "rooftrace.synth.simulate",
    "write_layers": "rooftrace.io.vector",
    "write_las": "rooftrace.io.las",
}
#: the types the entry points take and return
_TYPES = {
    "PointCloud": "rooftrace.cloud",
    "RunResult": "rooftrace.pipeline",
    "Layer": "rooftrace.io.vector",
    "SceneOptions": "rooftrace.synth.scene",
}

__all__ = [*_ENTRY_POINTS, *_TYPES, "__version__"]


def __getattr__(name: str) -> Any:
    module = _ENTRY_POINTS.get(name) or _TYPES.get(name)
    if module is None:
        raise AttributeError(f"module 'rooftrace' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next look-up does not come here
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
