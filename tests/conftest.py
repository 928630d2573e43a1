"""Shared pytest fixtures."""

from __future__ import annotations

import pathlib
import shutil
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    return REPO


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def engine() -> str:
    """Path of the standalone ``rspiv-engine`` binary, built (or brought up to date) by cargo;
    without cargo, an ``rspiv-engine`` on the PATH."""
    cargo = shutil.which("cargo")
    if cargo is not None:
        subprocess.run([cargo, "build", "-q", "-p", "rspiv-engine"], cwd=REPO, check=True)
        return str(REPO / "target" / "debug" / "rspiv-engine")
    exe = shutil.which("rspiv-engine")
    if exe is None:
        pytest.fail("neither cargo nor an installed rspiv-engine is available")
    return exe
