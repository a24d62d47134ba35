"""Semi-automatic roof outline from seed points: an object-space polygon snake
minimised by dynamic programming (Dal Poz & Fazan)."""

from rooftrace.snake.dp import brute_force_cycle, cycle_dp, cycle_energy
from rooftrace.snake.energy import EdgeField, angle_energy, edge_field, height_energy, side_energy, spacing_energy
from rooftrace.snake.seeds import pixel_seeds_to_object
from rooftrace.snake.snake import SnakeOptions, SnakeResult, snake_outline
from rooftrace.snake.surface import RasterSurface, Tin, roof_surface, vertex_heights

__all__ = [
    "SnakeOptions", "SnakeResult", "snake_outline", "pixel_seeds_to_object",
    "cycle_dp", "cycle_energy", "brute_force_cycle",
    "EdgeField", "edge_field", "side_energy", "height_energy", "spacing_energy", "angle_energy",
    "Tin", "RasterSurface", "roof_surface", "vertex_heights",
]
