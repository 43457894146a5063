"""Shared fixtures: the real data in ../shared/data, skipped with a reason when absent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real data not available: {path} is absent (see shared/data/README.md)")
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    return _require(SHARED_DATA)


@pytest.fixture(scope="session")
def jacquard_root() -> Path:
    return _require(SHARED_DATA / "jacquard_samples")


@pytest.fixture(scope="session")
def cornell_samples_root() -> Path:
    return _require(SHARED_DATA / "cornell_samples")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
