"""Notebooks 02 and 03 are slow-tier tests: each runs a whole fitting workflow (nbmake,
shrunk by ``JAXOCEAN_SMALL=1``), so ``make test-slow`` executes them; ``make test`` runs
notebook 01, the forward model, alone."""

import pytest

QUICK_NOTEBOOKS = {"01_forward_model.ipynb"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.suffix == ".ipynb" and item.path.name not in QUICK_NOTEBOOKS:
            item.add_marker(pytest.mark.slow)
