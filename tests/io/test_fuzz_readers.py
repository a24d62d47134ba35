"""Hypothesis fuzz of the readers: any bytes give a PointCloud or an InputError, nothing else (issue 10)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import laspy
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rooftrace.errors import InputError
from rooftrace.io.points import read_points


def _valid_las_bytes() -> bytes:
    import io

    header = laspy.LasHeader(version="1.2", point_format=1)
    header.scales = [0.01] * 3
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    las.x, las.y, las.z = rng.uniform(0, 10, (3, 50))
    buf = io.BytesIO()
    las.write(buf)
    return buf.getvalue()


VALID = _valid_las_bytes()
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _read(data: bytes, suffix: str):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"f{suffix}"
        p.write_bytes(data)
        try:
            cloud = read_points(p)
        except InputError:
            return None
        assert np.isfinite(cloud.xyz).all()
        return cloud


@SETTINGS
@given(st.binary(max_size=600), st.sampled_from([".las", ".laz", ".ply", ".xyz"]))
def test_random_bytes(data, suffix):
    _read(data, suffix)


@SETTINGS
@given(st.integers(0, len(VALID) - 1), st.integers(0, 255), st.integers(1, len(VALID)))
def test_mutated_las(pos, value, cut):
    data = bytearray(VALID)
    data[pos] = value
    _read(bytes(data[:cut]), ".las")


@SETTINGS
@given(st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=0, max_size=4), max_size=20))
def test_text_rows(rows):
    text = "\n".join(" ".join(repr(v) for v in row) for row in rows)
    _read(text.encode(), ".xyz")
