"""Image refinement of LiDAR roofs (Marcato & Dal Poz): candidates -> MRF grouping -> reconstruction -> 3D.

:func:`refine_roofs` refines the :class:`LidarRoofs` of a run with one image
and corrects the camera's exterior orientation from all of them
(:func:`refine_buildings` takes the roofs as separate sequences);
:func:`refine_building` refines one roof; :class:`RefineOptions` (section ``[refine]``) holds every
option.  The line grouping itself (topology, MRF energy, genetic algorithm)
is in :mod:`rooftrace.grouping`.
"""

from rooftrace.refine.building import fuse_positions, refine_building
from rooftrace.refine.buildings import (
    LidarRoofs,
    RefineResult,
    assign_ridges,
    correct_from_matches,
    orientation_summary,
    refine_buildings,
    refine_roofs,
)
from rooftrace.refine.options import BuildingRefinement, RefineOptions, keep_input

__all__ = ["RefineOptions", "RefineResult", "BuildingRefinement", "LidarRoofs", "refine_roofs", "refine_building",
           "refine_buildings",
           "assign_ridges", "correct_from_matches", "orientation_summary", "fuse_positions", "keep_input"]
