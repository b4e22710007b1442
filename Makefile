# admm_dolfinx: two commands on a fresh machine.
#   make demo   Example 1 of the paper, end to end (creates/refreshes .venv first)
#   make test   lint and types (ruff, mypy), the test suite serially and under mpiexec -n 2
#               (and -n 3, -n 4), every demo under mpiexec -n 2, a quick `reproduce all`,
#               every benchmark at its smallest size, and the book (every demo executed)
# and, for reproduction:
#   make reproduce OUT=dir   the paper's Tables 1-6 and figures (the Dockerfiles run this)
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
# What `make venv` installs. The PyPI wheel `dolfinx-solver-real` (extra `fenics`) brings
# DOLFINx, PETSc, SLEPc, MUMPS and MPICH; in a FEniCSx image use
#   make venv VENV_FLAGS=--system-site-packages EXTRAS=scenes,plot,test,bench
EXTRAS ?= fenics,scenes,plot,test,bench,dev,docs
VENV_FLAGS ?=
# mpiexec of the venv (from the MPICH wheel) unless the environment provides one
MPIEXEC ?= $(if $(wildcard $(VENV)/bin/mpiexec),$(VENV)/bin/mpiexec,mpiexec)
export MPIEXEC
OUT ?= out_reproduce
PYTEST := -m pytest -q -p no:cacheprovider
export PYVISTA_OFF_SCREEN ?= true
export OMP_NUM_THREADS ?= 1

.PHONY: docs venv demo test test-serial test-mpi test-demos test-benchmarks reproduce reproduce-quick lint clean

# The venv is rebuilt when the project's metadata changes (or was never built).
$(VENV)/.installed: pyproject.toml tools/find-python.sh
	@python=$$(tools/find-python.sh) && echo "using $$python" && "$$python" -m venv $(VENV_FLAGS) $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[$(EXTRAS)]"
	@touch $@

venv: $(VENV)/.installed

demo: venv
	$(PY) demos/example1.py

test: lint test-serial test-mpi reproduce-quick test-demos test-benchmarks docs

test-serial: venv
	$(PY) $(PYTEST) --durations=20

# -n 2: everything; -n 3 and -n 4 (oversubscribed on two cores): the tests marked
# mpi3 and mpi4 (the parallel comparisons and the partition matrix; pyproject.toml).
test-mpi: venv
	$(MPIEXEC) -n 2 $(PY) -m mpi4py $(PYTEST)
	$(MPIEXEC) -n 3 $(PY) -m mpi4py $(PYTEST) -m mpi3
	$(MPIEXEC) -n 4 $(PY) -m mpi4py $(PYTEST) -m mpi4

test-demos: venv
	$(PY) $(PYTEST) -m demos tests/test_demos.py

# Every benchmark still runs (smallest sizes; the MPI-capable ones also under -n 2).
test-benchmarks: venv
	tools/bench-smoke.sh $(PY) $(MPIEXEC)

reproduce: venv
	$(PY) -m admm_dolfinx.cli reproduce all --out $(OUT)

reproduce-quick: venv
	$(PY) -m admm_dolfinx.cli reproduce all --quick --out $(OUT)_quick

lint: venv
	$(VENV)/bin/ruff check src tests demos benchmarks
	$(VENV)/bin/ruff format --check src tests demos benchmarks
	$(VENV)/bin/mypy

# The book: every demo executed (with its default sizes), the API from the docstrings.
docs: venv
	$(PY) -m sphinx -q -b html -W --keep-going docs docs/_build/html
	@echo "the book: docs/_build/html/index.html"

clean:
	rm -rf $(VENV) out_* .pytest_cache
