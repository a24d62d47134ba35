"""Line grouping (Marcato & Dal Poz): roof topology, MRF energy, genetic algorithm, exact check, reconstruction."""

from rooftrace.grouping.exact import ExactResult, brute_force_minimise, exact_minimise
from rooftrace.grouping.ga import GAOptions, GAResult, genetic_minimise
from rooftrace.grouping.mrf import GroupingProblem, MRFOptions, build_problem
from rooftrace.grouping.reconstruct import (
    ImageReconstruction,
    junction_planes,
    reconstruct_image,
    ridge_lines,
    to_object_space,
)
from rooftrace.grouping.topology import Junction, RoofTopology, roof_topology

__all__ = [
    "ExactResult", "brute_force_minimise", "exact_minimise",
    "GAOptions", "GAResult", "genetic_minimise",
    "GroupingProblem", "MRFOptions", "build_problem",
    "ImageReconstruction", "junction_planes", "reconstruct_image", "ridge_lines", "to_object_space",
    "Junction", "RoofTopology", "roof_topology",
]
