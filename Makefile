# The two commands a fresh machine needs: `make demo` and `make test` (lint, tests, doctests).
# Each creates (or updates) .venv from pyproject.toml with the pinned versions
# in constraints.txt, then runs.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_DIR ?= demo-output

.PHONY: demo test bench clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(PY) -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/rooftrace demo -o $(DEMO_DIR) --overwrite

# ruff (configured in pyproject.toml), then the tests and the docstrings' doctests
test: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks docs
	$(PY) -m pytest -n 2 --dist loadfile -q

clean:
	rm -rf $(VENV) $(DEMO_DIR) .pytest_cache
