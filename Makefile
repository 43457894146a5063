# Two commands for a new machine: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test

.PHONY: run test lint docs clean constraints portability

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip

# The versions CI tested (constraints.txt); pyproject.toml itself keeps lower bounds.
CONSTRAINTS := -c constraints.txt

$(STAMP): pyproject.toml constraints.txt | $(BIN)/python
	$(BIN)/python -m pip install $(CONSTRAINTS) -e .
	touch $@

$(TEST_STAMP): pyproject.toml constraints.txt | $(BIN)/python
	$(BIN)/python -m pip install $(CONSTRAINTS) -e ".[test,ray,docs,cnn,ycb]"
	touch $(STAMP) $@

run: $(STAMP)
	$(BIN)/graspsim run $(ARGS)

test: $(TEST_STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest $(PYTEST_ARGS)

lint: $(TEST_STAMP)
	$(BIN)/ruff check .

# The documentation site (Sphinx, docs/conf.py) into docs/_build/html; warnings are errors.
# tests/test_docs.py runs the same build in make test, so a broken reference fails CI.
docs: $(TEST_STAMP)
	$(BIN)/python -m sphinx -b html -W --keep-going -q docs docs/_build/html

# The whole test suite once per BLAS kernel set the CPU supports (OPENBLAS_CORETYPE=Prescott,
# Haswell, SkylakeX where /proc/cpuinfo has avx512f) and once with numba's kernels compiled for
# a generic CPU in a fresh cache; one line per configuration, non-zero exit if any fails.
# PORTABILITY_ARGS: other test paths, and/or "-- PYTEST_ARGS". Not part of .ci/run.
portability: $(TEST_STAMP)
	$(BIN)/python scripts/portability.py $(PORTABILITY_ARGS)

clean:
	rm -rf $(VENV) runs .pytest_cache docs/_build

# Refresh constraints.txt: the newest releases the lower bounds admit, in a scratch venv.
constraints:
	rm -rf .venv-constraints
	$(PYTHON) -m venv .venv-constraints
	.venv-constraints/bin/python -m pip install --upgrade pip
	.venv-constraints/bin/python -m pip install -e ".[test,ray,docs,cnn,ycb]"
	{ sed -n '/^#/p' constraints.txt; \
	  .venv-constraints/bin/python -m pip freeze --exclude-editable; } > constraints.txt.new
	mv constraints.txt.new constraints.txt
	rm -rf .venv-constraints
