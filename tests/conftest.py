"""Shared fixtures: the shared data folder (skip when absent) and the model directory."""

from __future__ import annotations

from pathlib import Path

import pytest

from facesculpt.paths import model_home, shared_data_dir


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """`../shared/data` (or $FACESCULPT_DATA); tests that need it skip with a reason when absent."""
    path = shared_data_dir()
    if path is None:
        pytest.skip("shared test data not found: set FACESCULPT_DATA or place it at ../shared/data")
    return path


@pytest.fixture(scope="session")
def models_dir() -> Path:
    """The directory `facesculpt setup` filled; tests that need the networks skip when it is empty."""
    path = model_home()
    if not (path / "manifest.json").is_file():
        pytest.skip(f"no converted networks in {path}: run `facesculpt setup` first")
    return path
