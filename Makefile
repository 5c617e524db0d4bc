# Two entry points for a fresh machine: `make demo` (the main job) and `make test`.
# Both create the virtual environment they need.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
PYTEST_ARGS ?=

.PHONY: demo test test-slow test-extended bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/jaxocean demo --out out/demo --real experiments/data/ship_pacific_2014_clip

# `make test` runs the quick tier and notebook 01 on two workers; `make test-slow` the long
# checks (full fits, training, the reconstruct pipeline end to end, float64 gradient checks
# through whole images, notebooks 02 and 03 through nbmake, shrunk by JAXOCEAN_SMALL). CI
# (.ci/run) runs the quick tier, then the slow one when the machine is fast enough for both.
# `make test-extended` runs three full-scale regression checks of one to two minutes each
# that CI leaves out for its time limit. Each test module runs on one worker (--dist
# loadscope), so its fixtures are built and its programs compiled once: on a 2-core CPU
# make test took 7.5 min and make test-slow 22.4 min. No persistent XLA
# cache is shared between the workers: it is the one state a worker crash inside XLA could
# come from, and it saved no time measurable here.
RUN_PYTEST = JAXOCEAN_SMALL=1 $(PY) -m pytest -q -n 2 --dist loadscope

test: $(STAMP)
	$(RUN_PYTEST) -m "not slow and not extended" --nbmake tests notebooks $(PYTEST_ARGS)

test-slow: $(STAMP)
	$(RUN_PYTEST) -m slow --nbmake tests notebooks $(PYTEST_ARGS)

test-extended: $(STAMP)
	$(RUN_PYTEST) -m extended tests $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) experiments/bench_surface.py

clean:
	rm -rf $(VENV) out .pytest_cache
