"""Synthetic scenes with exact ground truth .

Terrain, buildings of many kinds (flat, gable, hip, shed, split-level;
rectangles, L/T/U, courtyards, round, semicircular ends, arcs; overhangs,
annexes, dormers, terraced rows), trees and an optional power line; an
airborne laser scan by ray casting from a flight trajectory (thesis eq. 2.4);
an aerial frame image (or a true orthophoto) rendered from the same scene;
and the truth: 3D roof outlines, footprints, ridges, roof faces and
per-point labels.

>>> from rooftrace.synth import SceneOptions, simulate_scene
>>> scene = simulate_scene(SceneOptions(size=40, density=4, image=False, trees=False))
>>> sorted(scene.truth)
['footprints', 'ridges', 'roof_faces', 'roof_outlines']
"""

from rooftrace.synth.buildings import Building, RoofBlock
from rooftrace.synth.mix import default_buildings
from rooftrace.synth.scene import SceneOptions
from rooftrace.synth.simulate import Scene, simulate_scene, write_scene

__all__ = ["SceneOptions", "Scene", "Building", "RoofBlock", "simulate_scene", "write_scene", "default_buildings"]
