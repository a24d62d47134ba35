"""Small simulated scenes shared by the synth tests (simulated once per session)."""

from __future__ import annotations

import pytest

from rooftrace.synth import SceneOptions, simulate_scene


@pytest.fixture(scope="session")
def small_scene():
    """60 m, 8 pts/m², frame image at 0.2 m, trees, power line and outliers."""
    return simulate_scene(SceneOptions(size=60.0, density=8.0, seed=3, power_line=True, outlier_fraction=0.002))


@pytest.fixture(scope="session")
def ortho_scene():
    return simulate_scene(SceneOptions(size=60.0, density=4.0, seed=5, orthophoto=True))
