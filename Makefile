# Two entry points for a fresh machine: `make demo` (the main job) and `make test`.
# Both create the virtual environment they need.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
PYTEST_ARGS ?=

.PHONY: demo test test-slow bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/jaxocean demo --out out/demo --real experiments/data/ship_pacific_2014_clip

# Two workers share one XLA compilation cache, fresh for the run and removed after it (the
# same programs compile in many tests and in both workers). `make test` runs the quick tier
# and the notebooks (nbmake, shrunk by JAXOCEAN_SMALL); `make test-slow` the long checks
# (full fits, the reconstruct pipeline end to end); CI (.ci/run) runs both.
RUN_PYTEST = cache=$$(mktemp -d) && trap 'rm -rf "$$cache"' EXIT && \
	JAX_COMPILATION_CACHE_DIR="$$cache" JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0.3 JAXOCEAN_SMALL=1 \
	$(PY) -m pytest -q -n 2

test: $(STAMP)
	$(RUN_PYTEST) -m "not slow" --nbmake tests notebooks $(PYTEST_ARGS)

test-slow: $(STAMP)
	$(RUN_PYTEST) -m slow tests $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) experiments/bench_surface.py

clean:
	rm -rf $(VENV) out .pytest_cache
