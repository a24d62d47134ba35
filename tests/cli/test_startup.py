"""Start-up: the command line imports the library when a command runs, not to parse arguments or print help."""

import subprocess
import sys

import pytest


def _modules_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(sys.modules)))"
    return set(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split())


def test_the_command_line_imports_no_stage_and_no_heavy_library_before_a_command_runs():
    loaded = _modules_after("import rooftrace.cli.main")
    assert "typer" in loaded and "rooftrace.cli.cmd_run" in loaded
    heavy = {"scipy", "numba", "shapely", "pyproj", "laspy", "pyogrio", "geopandas", "pandas", "rasterio", "cv2",
             "matplotlib", "rooftrace.config", "rooftrace.pipeline", "rooftrace.lidar", "rooftrace.contour"}
    assert not heavy & loaded


@pytest.mark.parametrize("module", ["rooftrace.io.vector", "rooftrace.io.footprints"])
def test_pyogrio_and_geopandas_are_imported_only_to_read_or_write_a_vector_file(module):
    loaded = _modules_after(f"import {module}")
    assert not {"pyogrio", "geopandas", "pandas"} & loaded
