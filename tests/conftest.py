"""Shared fixtures of the test suite.

- ``eha``: the real command line in a subprocess (``helpers.run_eha``).
- the residual loop's null cache, in a temporary folder for the session (autouse).
- ``slow``: marker of the end-to-end tests that take more than a few seconds
  (``pytest -m "not slow"`` skips them; CI runs everything; markers are strict).

Plain helper functions (``run_eha``, ``invoke_eha``, ``error_line``, ``write_campaign``,
``close``, ``files_under``) are in tests/helpers.py: tests import them from there, never
from this file (pytest imports conftest itself).
"""

from __future__ import annotations

import os

import pytest

from helpers import run_eha

# Rich sizes tables to the terminal: a wide one in every process of the suite (pytest-xdist's
# workers have none), so that no check of printed text depends on where the tests run.
os.environ["COLUMNS"] = "200"


@pytest.fixture(autouse=True, scope="session")
def _explain_null_cache(tmp_path_factory):
    """The residual loop's healthy nulls (eha.explain.null) are cached for the session in a
    temporary folder: never in the user's cache, shared by the tests of one command. Under
    pytest-xdist (CI's ``-n 2``) the workers share one folder (the run's base folder, above
    each worker's own): a null one worker calibrated is read by the other (the cache file is
    written atomically, so two calibrating alike both succeed)."""
    old = os.environ.get("EHA_CACHE_DIR")
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = tmp_path_factory.getbasetemp().parent / "eha-cache"
        shared.mkdir(exist_ok=True)
        os.environ["EHA_CACHE_DIR"] = str(shared)
    else:
        os.environ["EHA_CACHE_DIR"] = str(tmp_path_factory.mktemp("eha-cache"))
    yield
    if old is None:
        os.environ.pop("EHA_CACHE_DIR", None)
    else:
        os.environ["EHA_CACHE_DIR"] = old


@pytest.fixture
def eha():
    """The command line in a subprocess: ``eha("simulate", "--out", path)``."""
    return run_eha
