"""Shared test fixtures and paths."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """../shared beside the clone (seeds, data); CI has it there too."""
    if not SHARED.is_dir():
        raise RuntimeError(f"{SHARED} is missing: the tests read the seeds and data from ../shared")
    return SHARED
