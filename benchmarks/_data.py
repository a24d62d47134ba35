"""Where the real datasets are: ``$ROOFTRACE_DATA``, else ``../shared/data`` beside the repository.

The tests find them the same way (``tests/conftest.py``).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["DATA"]

DATA = Path(os.environ.get("ROOFTRACE_DATA") or Path(__file__).resolve().parents[1].parent / "shared" / "data")
