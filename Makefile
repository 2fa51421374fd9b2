# Two commands do all the set-up: `make run` (every scenario + result table), `make test`
# (lint, then every test: slow, browser and notebook ones included). `make docs` builds the manual.
# The virtual environment uses the newest Python that drake supports here (3.13, 3.12,
# else python3); override with `make test PYTHON=python3 VENV=.venv-311`.
PYTHON ?= $(shell for v in 3.13 3.12; do \
	p=$$(ls -d $$(pyenv root 2>/dev/null)/versions/$$v*/bin/python 2>/dev/null | tail -n 1); [ -n "$$p" ] || p=$$(command -v python$$v 2>/dev/null); \
	if [ -n "$$p" ] && $$p -c 'import venv' 2>/dev/null; then echo $$p; exit 0; fi; done; echo python3)
VENV ?= .venv
BIN := $(VENV)/bin

# Tests run in parallel (pytest-xdist): one worker per core on 4 cores or more, two on 2 or 3
# (the same CPU as serial, measured paired, so about half the wall time on an idle machine;
# docs/measurements/test_times.md), serially on one. `make test TEST_JOBS=N` chooses.
TEST_JOBS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -ge 4 ] && echo auto || { [ $$n -ge 2 ] && echo 2 || echo 0; })

.PHONY: run test lint bench docs clean

# What running needs (`make run`): the package and its dependencies only.
$(VENV)/.installed: pyproject.toml
	@# Graphviz draws `quad-drake diagram`; installed where missing and we may (root + apt).
	@command -v dot >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
		apt-get update -qq && apt-get install -y -qq graphviz >/dev/null; } || \
		echo "note: Graphviz 'dot' missing; 'quad-drake diagram' needs it"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e .
	touch $@

# What testing adds (`make test`, `make lint`): the test extras (pytest, pytest-xdist, ruff, ...).
$(VENV)/.installed-test: $(VENV)/.installed
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $@

# What the manual adds (`make docs`): Sphinx, MyST, myst-nb, sphinx-autoapi, sphinx-argparse.
$(VENV)/.installed-docs: $(VENV)/.installed
	$(BIN)/python -m pip install -q -e '.[docs]'
	touch $@

run: $(VENV)/.installed
	$(BIN)/quad-drake run --all

lint: $(VENV)/.installed-test
	$(BIN)/python -m ruff check .
	$(BIN)/python -m ruff format --check .

# With workers, numba's kernels are compiled once first (`quad-drake warmup`; about 2 s of CPU
# when an earlier warm-up's stamp says the kernels' sources are unchanged): on an empty cache each
# worker would compile every kernel it is the first to use, twice the compiling. Byte code is
# written (the checkout's __pycache__ folders, git-ignored) even where PYTHONDONTWRITEBYTECODE is
# set: without it every pytest process rewrites every test module's asserts again (3-4 s of CPU
# per process, three processes with two workers) and every quad-drake a test starts compiles the
# package's modules again.
test: lint
	$(if $(filter 0,$(TEST_JOBS)),,$(BIN)/quad-drake warmup >/dev/null && )PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -n $(TEST_JOBS)

# The manual into docs/_build/html, every warning an error (a broken link or anchor, a notebook
# cell that raises); notebooks execute in their quick mode, kept in docs/_build/notebooks until
# the notebook, the package or the interpreter change (tests/test_notebooks.py reads them there).
DOCS_OUT ?= docs/_build/html
docs: $(VENV)/.installed-docs
	$(BIN)/python -m sphinx -b html -W --keep-going -q docs $(DOCS_OUT)
	@echo "the manual: $(DOCS_OUT)/index.html"

bench: $(VENV)/.installed
	$(BIN)/python benchmarks/bench_closed_loop.py

clean:
	rm -rf $(VENV) out build dist *.egg-info docs/_build docs/gallery docs/api
