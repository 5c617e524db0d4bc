"""Strict test configuration.

* Warnings are errors (pyproject's ``filterwarnings``); only jaxopt's own deprecation
  warning is filtered.
* ``key`` gives a fresh PRNG key per test; ``x64`` switches 64-bit floats on for one test
  (gradient checks run there); ``compilations()`` is a context manager listing the XLA
  programs compiled inside it.
* The command line's persistent XLA compilation cache is off: every worker compiles its own
  programs (hermetic runs).
* hypothesis: a small deterministic profile so `make test` stays fast and reproducible.
* JAX's compilation caches are cleared after every test module. Each compiled XLA:CPU
  program holds memory mappings of its own; a worker that keeps every program of a tier
  reaches the kernel's limit on mappings (``vm.max_map_count``, 65,530 by default) and
  XLA then aborts or segfaults inside the next compilation.
"""

import contextlib
import gc
import os

import jax
import pytest
from hypothesis import HealthCheck, settings

# the command line's persistent compilation cache stays off in tests (hermetic runs)
os.environ["JAXOCEAN_COMPILE_CACHE"] = "0"

settings.register_profile(
    "ci",
    max_examples=int(os.environ.get("HYPOTHESIS_MAX_EXAMPLES", "25")),
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("ci")


@pytest.fixture
def key():
    return jax.random.key(0)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


@pytest.fixture
def compilations():
    @contextlib.contextmanager
    def record():
        names = []

        def listen(event, duration, **kw):
            if event.endswith("backend_compile_duration"):
                names.append(kw.get("fun_name"))

        jax.monitoring.register_event_duration_secs_listener(listen)
        try:
            yield names
        finally:
            jax.monitoring.unregister_event_duration_listener(listen)

    return record


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    jax.clear_caches()
    gc.collect()
