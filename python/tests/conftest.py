"""Fixtures shared by the tests: a model cache of the test session's own (so that the first
construction of each model compiles it and the cache's behaviour is what the tests see), and the
bflow command of the C++ build for comparisons with the C++ API."""

import os
import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session", autouse=True)
def model_cache(tmp_path_factory):
    directory = tmp_path_factory.mktemp("models")
    previous = os.environ.get("BFLOW_CACHE_DIR")
    os.environ["BFLOW_CACHE_DIR"] = str(directory)
    yield directory
    if previous is None:
        del os.environ["BFLOW_CACHE_DIR"]
    else:
        os.environ["BFLOW_CACHE_DIR"] = previous


@pytest.fixture(scope="session")
def cli():
    """The `bflow` command of the C++ build: $BFLOW_CLI (scripts/test sets it), else build/cli/bflow
    of the repository, else `bflow` on the PATH."""
    candidates = [os.environ.get("BFLOW_CLI"),
                  str(Path(__file__).resolve().parents[2] / "build" / "cli" / "bflow"),
                  shutil.which("bflow")]
    for c in candidates:
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return c
    pytest.fail("no bflow command: build it (cmake --build build) or set BFLOW_CLI")
