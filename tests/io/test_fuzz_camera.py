"""Hypothesis fuzz of camera.json: any JSON gives a camera or an InputError naming the file (issue 10)."""

from __future__ import annotations

import copy

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rooftrace.errors import InputError
from rooftrace.io.camera import camera_from_dict

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])

VALID = {
    "type": "frame",
    "crs": "EPSG:28992",
    "image_size": [400, 300],
    "pixel_size_mm": 0.012,
    "focal_length_mm": 120.0,
    "principal_point_mm": [0.0, 0.0],
    "distortion": {"k1": 0, "k2": 0, "k3": 0, "p1": 0, "p2": 0},
    "exterior": {"X0": 0.0, "Y0": 0.0, "Z0": 1000.0, "omega_deg": 0.0, "phi_deg": 0.0, "kappa_deg": 0.0},
    "exterior_covariance": np.eye(6).tolist(),
}

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=12) | st.sampled_from(["EPSG:4326", "frame", "orthophoto", "nan", "inf", "1e999"]),
    lambda children: st.lists(children, max_size=7) | st.dictionaries(st.text(max_size=8), children, max_size=5),
    max_leaves=20,
)
paths = st.sampled_from([
    ("type",), ("crs",), ("image_size",), ("pixel_size_mm",), ("focal_length_mm",), ("principal_point_mm",),
    ("distortion",), ("distortion", "k1"), ("exterior",), ("exterior", "X0"), ("exterior", "omega_deg"),
    ("exterior_covariance",), ("unknown",),
])


def _build(data):
    try:
        camera = camera_from_dict(data, "cam.json")
    except InputError as exc:
        assert str(exc).startswith("cam.json")
        return None
    # a camera that was accepted projects finite pixels for a point under it
    cr = camera.project(np.array([[0.0, 0.0, 0.0]]))
    assert cr.shape == (1, 2)
    return camera


@SETTINGS
@given(st.lists(st.tuples(paths, json_values), min_size=1, max_size=3))
def test_mutated_camera(changes):
    data = copy.deepcopy(VALID)
    for path, value in changes:
        target = data
        for key in path[:-1]:
            if not isinstance(target.get(key), dict):
                target[key] = {}
            target = target[key]
        target[path[-1]] = value
    _build(data)


@SETTINGS
@given(json_values)
def test_any_json_value(value):
    _build(value)


def test_valid_camera_is_accepted():
    assert _build(copy.deepcopy(VALID)) is not None
