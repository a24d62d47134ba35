"""Whether a run fits in memory in one piece (by default, inputs that fit in memory run untiled).

An untiled ``rooftrace run`` holds the whole cloud with its features,
neighbour pairs and per-building results at once; its peak resident memory
grows with the point count.  Measured (``/usr/bin/time -f %M``):

=================================  ==========  =========
input                              points      peak RSS
=================================  ==========  =========
(imports only)                     0           0.21 GB
Delft AHN3, two tiles, 12 pts/m²   848 942     0.79 GB
simulated scene s0 of the block    1 207 873   0.68 GB
scenes s0-s2 of the block          3 623 619   1.18 GB
=================================  ==========  =========

that is about 0.2-0.7 kB a point above 0.2-0.4 GB; :data:`BYTES_PER_POINT`
takes the Delft figure, the densest and with the most vegetation, with a
margin.  An input whose estimate exceeds :data:`MEMORY_SHARE` of the memory
available now is run in tiles of the default size instead (the result is the
same: tiles give the buildings of one piece).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

__all__ = ["BASE_BYTES", "BYTES_PER_POINT", "MEMORY_SHARE", "available_bytes", "header_points", "untiled_bytes",
           "fits_in_memory"]

#: resident memory of the interpreter with rooftrace's libraries (bytes)
BASE_BYTES = 500 * 2**20
#: peak memory of an untiled run per input point (bytes)
BYTES_PER_POINT = 1000
#: share of the available memory an untiled run may plan to use
MEMORY_SHARE = 0.5


def available_bytes() -> int:
    """Memory available to a new allocation now (bytes), as the kernel reports it."""
    import psutil

    return int(psutil.virtual_memory().available)


def header_points(paths: Sequence[os.PathLike | str]) -> int | None:
    """Points the LAS/LAZ headers announce, summed; None when any input is not a readable LAS/LAZ."""
    import laspy

    total = 0
    try:
        for p in paths:
            with laspy.open(p) as reader:
                total += int(reader.header.point_count)
    except Exception:  # unreadable or not LAS: the reader of the run reports it with its own message
        return None
    return total


def untiled_bytes(n_points: int) -> int:
    """Planned peak memory of an untiled run over ``n_points`` points (bytes)."""
    return BASE_BYTES + BYTES_PER_POINT * int(n_points)


def fits_in_memory(n_points: int, available: int | None = None) -> bool:
    """True when an untiled run over ``n_points`` points plans to use at most ``MEMORY_SHARE`` of ``available``.

    Parameters
    ----------
    n_points : int
        Input points.
    available : int, optional
        Bytes available; by default :func:`available_bytes`.

    Examples
    --------
    >>> fits_in_memory(1_000_000, available=8 * 2**30), fits_in_memory(100_000_000, available=8 * 2**30)
    (True, False)
    """
    available = available_bytes() if available is None else available
    return untiled_bytes(n_points) <= MEMORY_SHARE * available
