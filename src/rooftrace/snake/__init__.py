"""Semi-automatic roof outline from seed points: an object-space polygon snake
minimised by dynamic programming (DESIGN.md stage 10, seed 004)."""

from rooftrace.snake.dp import brute_force_cycle, cycle_dp, cycle_energy
from rooftrace.snake.energy import EdgeField, angle_energy, edge_field, side_energy, spacing_energy
from rooftrace.snake.snake import SnakeOptions, SnakeResult, pixel_seeds_to_object, polygon_energy, snake_outline
from rooftrace.snake.tin import RasterSurface, Tin, roof_surface, vertex_heights

__all__ = [
    "SnakeOptions", "SnakeResult", "snake_outline", "pixel_seeds_to_object", "polygon_energy",
    "cycle_dp", "cycle_energy", "brute_force_cycle",
    "EdgeField", "edge_field", "side_energy", "spacing_energy", "angle_energy",
    "Tin", "RasterSurface", "roof_surface", "vertex_heights",
]
