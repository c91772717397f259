# histostudy: two commands set everything up on a fresh machine.
#   make reproduce   create .venv, install, run the study in the smoke profile -> reports/
#   make test        create .venv if missing, run the whole test suite (papermill smoke run included)
#   make test-avx2   the same suite with the libraries held to AVX2, as on a CPU without AVX-512,
#                    AMX or native bfloat16 (docs/testing.md, "Every CPU")
#
# Torch is installed first as a CPU build, so that the package's own `torch` requirement is already
# satisfied and pip does not pull gigabytes of CUDA packages. Choose another build with, e.g.
#   make test TORCH_SPEC="torch==2.13.0" TORCH_PIP_ARGS="--index-url https://download.pytorch.org/whl/cu128"

PYTHON ?= python3
VENV ?= .venv
TORCH_SPEC ?= torch==2.13.0
TORCH_PIP_ARGS ?=
PROFILE ?= smoke
REPORTS ?= reports
PYTEST_ARGS ?=

BIN := $(VENV)/bin
STAMP := $(VENV)/.histostudy-installed

# histostudy.core.machine.AVX2_RESTRICTION: oneDNN, ATen and numba at an AVX2-only CPU's level.
AVX2_ENV := ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 NUMBA_CPU_NAME=haswell

.PHONY: all env reproduce test test-avx2 lab bench clean-reports

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
	$(BIN)/histostudy reproduce --profile $(PROFILE) --output $(REPORTS)

test: $(STAMP)
	$(BIN)/python -m pytest $(PYTEST_ARGS)

test-avx2: $(STAMP)
	$(AVX2_ENV) $(BIN)/python -m pytest $(PYTEST_ARGS)

lab: $(STAMP)
	$(BIN)/jupyter lab --notebook-dir=notebooks

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean-reports:
	find $(REPORTS) -mindepth 1 ! -name .gitkeep -exec rm -rf {} +
