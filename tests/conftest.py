"""Shared fixtures: paths to the real data and small clouds.

The real datasets are found in ``$ROOFTRACE_DATA``, else in ``../shared/data``
beside the repository.  A test whose dataset is missing is skipped, and the
skip names the variable; with ``ROOFTRACE_REQUIRE_DATA=1`` (set by ``.ci/run``)
it fails instead, so that CI never passes without the real-data tests.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("ROOFTRACE_DATA") or ROOT.parent / "shared" / "data")
DELFT = DATA / "3dfier_delft_ahn3_bgt"
CITY3D = DATA / "city3d_ahn3_single_buildings"
IGN = DATA / "ign_montpellier_lidarhd_bdortho"


def need(path: Path) -> Path:
    """Skip a test when a real dataset is absent (it lives outside the repository); fail if CI requires it."""
    if not path.exists():
        where = "ROOFTRACE_DATA" if os.environ.get("ROOFTRACE_DATA") else "ROOFTRACE_DATA unset, default ../shared/data"
        message = f"real data not found: {path} ({where}); set ROOFTRACE_DATA to the folder holding the datasets"
        if os.environ.get("ROOFTRACE_REQUIRE_DATA", "") not in ("", "0"):
            pytest.fail(f"{message} (ROOFTRACE_REQUIRE_DATA is set)", pytrace=False)
        pytest.skip(message)
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
