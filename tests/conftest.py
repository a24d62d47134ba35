"""Shared fixtures: paths to the real data beside the repository and small clouds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DATA = SHARED / "data"
DELFT = DATA / "3dfier_delft_ahn3_bgt"
CITY3D = DATA / "city3d_ahn3_single_buildings"
IGN = DATA / "ign_montpellier_lidarhd_bdortho"


def need(path: Path) -> Path:
    """Skip a test when a real dataset is absent (it lives outside the repository)."""
    if not path.exists():
        pytest.skip(f"real data not available: {path}")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
