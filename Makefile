# admm_dolfinx: two commands on a fresh machine.
#   make demo   Example 1 of the paper, end to end (creates/refreshes .venv first)
#   make test   the test suite, serially and under mpiexec -n 2 and -n 3, plus the demos
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
MPIEXEC := $(VENV)/bin/mpiexec
EXTRAS ?= fenics,scenes,plot,test,dev
PYTEST := -m pytest -q -p no:cacheprovider
export PYVISTA_OFF_SCREEN ?= true
export OMP_NUM_THREADS ?= 1

.PHONY: venv demo test test-serial test-mpi test-demos lint reproduce clean

# The venv is rebuilt when the project's metadata changes (or was never built).
$(VENV)/.installed: pyproject.toml tools/find-python.sh
	@python=$$(tools/find-python.sh) && echo "using $$python" && "$$python" -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[$(EXTRAS)]"
	@touch $@

venv: $(VENV)/.installed

demo: venv
	$(PY) demos/example1.py

test: test-serial test-mpi test-demos

test-serial: venv
	$(PY) $(PYTEST)

test-mpi: venv
	$(MPIEXEC) -n 2 $(PY) -m mpi4py $(PYTEST)
	$(MPIEXEC) -n 3 $(PY) -m mpi4py $(PYTEST) tests/test_parallel.py

test-demos: venv
	$(PY) demos/run_all.py

lint: venv
	$(VENV)/bin/ruff check src tests demos benchmarks
	$(VENV)/bin/ruff format --check src tests demos benchmarks

clean:
	rm -rf $(VENV) out_* .pytest_cache
