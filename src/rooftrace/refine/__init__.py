"""Image refinement of LiDAR roofs (Marcato & Dal Poz): candidates -> MRF grouping -> reconstruction -> 3D.

:func:`refine_buildings` refines many buildings with one image (and corrects
the camera's exterior orientation from all of them); :func:`refine_building`
refines one roof; :class:`RefineOptions` (section ``[refine]``) holds every
option.  The line grouping itself (topology, MRF energy, genetic algorithm)
is in :mod:`rooftrace.grouping`.
"""

from rooftrace.refine.building import fuse_positions, refine_building
from rooftrace.refine.buildings import (
    RefineResult,
    assign_ridges,
    correct_from_matches,
    orientation_summary,
    refine_buildings,
)
from rooftrace.refine.options import BuildingRefinement, RefineOptions, keep_input

__all__ = ["RefineOptions", "RefineResult", "BuildingRefinement", "refine_building", "refine_buildings",
           "assign_ridges", "correct_from_matches", "orientation_summary", "fuse_positions", "keep_input"]
