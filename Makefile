# tdacm: two commands that work on a fresh machine (Python 3.11, no GPU).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEV := $(VENV)/.installed-dev
WARM := $(VENV)/.kernels

.PHONY: demo test docs lint bench wheel clean

# the package and what `tdacm run` needs (the demo); the extras and the tools come with DEV
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -e .
	touch $(STAMP)

# every extra (campaigns, env, RL, recording, live view) and the dev tools: the test suite
$(DEV): $(STAMP)
	$(PY) -m pip install --quiet -e ".[all,dev]"
	touch $(DEV)

# numba's cache of the checkout for the test suite: the kernels of `tdacm run`, the contact
# scenarios, the engine, the vector env, identification and the stiff integrators, compiled in
# two processes (tdacm.bench.compile.fill)
$(WARM): $(DEV)
	$(PY) -m tdacm.bench.compile fill
	touch $(WARM)

# the demo compiles only the kernels it runs, at their first use (a notice and a progress bar
# on stderr; half of them in a second process), then loads them from numba's cache
demo: $(STAMP)
	$(VENV)/bin/tdacm run paper-in-fov --out out/paper-in-fov

test: $(WARM)
	$(VENV)/bin/lint-imports --no-cache   # the layers of [tool.importlinter] in pyproject.toml
	$(PY) -m pytest -q --durations=15   # includes the strict docs build (tests/test_docs.py) and the layers; lists the slowest tests (the 10-minute budget)

# the wheel with its kernels compiled for a portable CPU (buildsys/tdacm_build.py): installing
# it needs no compiling on an x86-64 machine with the same Python and numba (docs/index.md)
wheel: $(DEV)
	$(PY) -m build --wheel --outdir dist

docs: $(DEV)
	$(PY) -m mkdocs build --strict -d site

lint: $(DEV)
	$(VENV)/bin/ruff check src tests benchmarks examples buildsys
	$(VENV)/bin/ruff format --check src tests benchmarks examples buildsys

bench: $(DEV)
	$(VENV)/bin/tdacm bench

clean:
	rm -rf $(VENV) out build dist site *.egg-info
