# tdacm: two commands that work on a fresh machine (Python 3.11, no GPU).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ENGINE_STAMP := $(VENV)/.engine-cached

.PHONY: demo test docs lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[all,dev]"
	$(PY) -m tdacm.loop.precompile --install   # numba's cache: the first run loads, not compiles
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tdacm run paper-in-fov --out out/paper-in-fov

# the batched engine's, the vector env's and identification's kernels: the tests use them,
# the demo does not (so `make demo` does not wait for them)
$(ENGINE_STAMP): $(STAMP)
	$(PY) -m tdacm.loop.precompile --install-engine
	touch $(ENGINE_STAMP)

test: $(ENGINE_STAMP)
	$(VENV)/bin/lint-imports --no-cache   # the layers of [tool.importlinter] in pyproject.toml
	$(PY) -m pytest -q --durations=15   # includes the strict docs build (tests/test_docs.py) and the layers; lists the slowest tests (the 10-minute budget)

docs: $(STAMP)
	$(PY) -m mkdocs build --strict -d site

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks examples
	$(VENV)/bin/ruff format --check src tests benchmarks examples

bench: $(STAMP)
	$(VENV)/bin/tdacm bench

clean:
	rm -rf $(VENV) out build site *.egg-info
