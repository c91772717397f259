# histostudy: two commands set everything up on a fresh machine.
#   make reproduce   create .venv, install, run the study in the smoke profile -> reports/
#   make test        create .venv if missing, run the whole test suite (papermill smoke run included)
#   make lint        ruff over the package, tests, benchmarks and scripts (pyproject.toml, [tool.ruff])
#   make test-avx2   the same suite with the libraries held to AVX2, as on a CPU without AVX-512,
#                    AMX or native bfloat16 (docs/testing.md, "Every CPU")
#   make dist-check  sdist and wheel built, the wheel installed in a fresh venv away from the checkout,
#                    its networks, the README's lab block and notebook 01 run there (scripts/dist_check.py)
#   make lab         JupyterLab on notebooks/ (as root, as in a container, with --allow-root)
#   make typecheck   mypy over the whole package (settings: [tool.mypy] in pyproject.toml)
#   make docs        the documentation site in docs/_build/html, warnings as errors (docs/site.md)
#
# Torch is installed first as a CPU build, so that the package's own `torch` requirement is already
# satisfied and pip does not pull gigabytes of CUDA packages. Choose another build with, e.g.
#   make test TORCH_SPEC="torch==2.13.0" TORCH_PIP_ARGS="--index-url https://download.pytorch.org/whl/cu128"

PYTHON ?= python3
VENV ?= .venv
TORCH_SPEC ?= torch==2.13.0
TORCH_PIP_ARGS ?=
PROFILE ?= smoke
# notebooks `make reproduce` runs at once, each in its own kernel (the numbers do not depend on it):
# three for the smoke profile, whose short notebooks then overlap their serial parts; one otherwise
WORKERS ?= $(if $(filter smoke,$(PROFILE)),3,1)
REPORTS ?= reports
PYTEST_ARGS ?=
# pytest-xdist workers of `make test` (0: one process); docs/testing.md
TEST_WORKERS ?= 2

BIN := $(VENV)/bin
STAMP := $(VENV)/.histostudy-installed

# oneDNN, ATen, numba and numpy at an AVX2-only CPU's level (histostudy.core.machine.avx2_restriction:
# ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 NUMBA_CPU_NAME=haswell, and numpy's AVX-512 loops off)
AVX2_ENV = $(shell $(BIN)/python -c "from histostudy.core import avx2_env_words; print(avx2_env_words())")

.PHONY: all env reproduce lint typecheck test test-avx2 lab docs dist-check bench clean-reports

all: test

env: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade --quiet pip
	$(BIN)/python -m pip install --quiet $(TORCH_PIP_ARGS) "$(TORCH_SPEC)"
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	$(BIN)/python -m ipykernel install --sys-prefix --name histostudy --display-name "Python (histostudy)" >/dev/null
	touch $@

reproduce: $(STAMP)
	$(BIN)/histostudy reproduce --profile $(PROFILE) --output $(REPORTS) --workers $(WORKERS)

PYTEST := $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist worksteal

lint: $(STAMP)
	$(BIN)/ruff check histostudy tests benchmarks scripts

typecheck: $(STAMP)
	$(BIN)/python -m mypy

test: $(STAMP)
	$(PYTEST) $(PYTEST_ARGS)

test-avx2: $(STAMP)
	$(AVX2_ENV) $(PYTEST) $(PYTEST_ARGS)

# JupyterLab refuses to start as root unless told --allow-root: added, and said, when root runs it
lab: $(STAMP)
	@if [ "$$(id -u)" = 0 ]; then echo "make lab: running as root (a container?): adding --allow-root, which JupyterLab requires then"; fi
	$(BIN)/jupyter lab --notebook-dir=notebooks $(if $(filter 0,$(shell id -u)),--allow-root)

DOCS_STAMP := $(VENV)/.histostudy-docs-installed

$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e ".[dev,docs]"
	touch $@

docs: $(DOCS_STAMP)
	rm -rf docs/_build docs/api
	$(BIN)/python -m sphinx -b html -W --keep-going -q docs docs/_build/html
	@echo "docs: docs/_build/html/index.html"

dist-check: $(STAMP)
	TORCH_SPEC="$(TORCH_SPEC)" TORCH_PIP_ARGS="$(TORCH_PIP_ARGS)" $(BIN)/python scripts/dist_check.py

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean-reports:
	find $(REPORTS) -mindepth 1 ! -name .gitkeep -exec rm -rf {} +
