"""The README's first commands, as a new user meets them (issue 21)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

from rooftrace.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
BLOCKS = re.findall(r"^```[a-z]*\n(.*?)^```", README, flags=re.S | re.M)


def test_readme_starts_with_the_two_commands():
    assert README.startswith("# rooftrace\n\n```\nmake demo\nmake test\n```\n")
    makefile = (ROOT / "Makefile").read_text()
    assert "$(VENV)/bin/rooftrace demo" in makefile and "-m pytest" in makefile
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci and "ROOFTRACE_REQUIRE_DATA=1" in ci


def test_readme_says_how_to_call_rooftrace_and_which_python():
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert pyproject["project"]["scripts"]["rooftrace"] == "rooftrace.cli.entry:main"
    requires = pyproject["project"]["requires-python"]
    assert f'`requires-python = "{requires}"`' in README
    minimum = requires.removeprefix(">=")
    assert f"Python {minimum} or newer" in README and f"tested on CPython {minimum}" in README
    assert "pipx install ." in README and "pip install ." in README
    after = BLOCKS[1]
    assert ".venv/bin/rooftrace" in after and "source .venv/bin/activate" in after


def test_the_commands_after_make_demo_run_as_written(tmp_path, capsys):
    """The block after the two commands, on a (small) scene where ``make demo`` leaves its files."""
    assert main(["simulate", "-o", str(tmp_path / "demo-output"), "--size", "40", "--density", "4", "--seed", "1",
                 "-q"]) == 0
    capsys.readouterr()
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    ran = 0
    for line in BLOCKS[1].strip().splitlines():
        words = shlex.split(line)
        if words[:1] == ["source"]:
            assert words[1] == ".venv/bin/activate"
            continue
        assert words[0] in (".venv/bin/rooftrace", "rooftrace"), line
        done = subprocess.run([sys.executable, "-m", "rooftrace", *words[1:]], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, (line, done.stderr)
        ran += 1
    assert ran == 2 and (tmp_path / "roofs.gpkg").is_file()
