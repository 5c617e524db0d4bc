"""The notebooks are slow-tier tests: each runs a whole workflow (nbmake, shrunk by
``JAXOCEAN_SMALL=1``), so ``make test-slow`` and CI execute them and ``make test`` does not."""

import pytest


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.suffix == ".ipynb":
            item.add_marker(pytest.mark.slow)
