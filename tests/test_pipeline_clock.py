"""The pipeline's clock: wall seconds per step (the ``--json`` timings) and the process's CPU seconds."""

from __future__ import annotations

import time

from rooftrace.cloud import PointCloud
from rooftrace.pipeline import run_pipeline
from tests.cli.badfiles import scene_xyz


def test_every_step_has_its_cpu_seconds_within_the_calls():
    c0 = time.process_time()
    result = run_pipeline(PointCloud(scene_xyz(), sources=["scene.las"]))
    total = time.process_time() - c0
    assert set(result.cpu_seconds) == {"detect", "layers", *result.timings}
    assert {"outline", "roof_planes", "parts", "models"} <= set(result.timings)
    assert all(v >= 0 for v in result.cpu_seconds.values())
    # the steps follow one another: together no more than the whole call
    assert sum(result.cpu_seconds.values()) <= total + 1e-6
    assert result.cpu_seconds["detect"] > 0
