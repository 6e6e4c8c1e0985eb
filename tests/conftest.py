"""Shared test fixtures and paths."""

from __future__ import annotations

from pathlib import Path

import blas_pin  # noqa: F401  (before numpy: one OpenBLAS kernel for the golden replays)
import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """../shared beside the clone (seeds, data); CI has it there too."""
    if not SHARED.is_dir():
        raise RuntimeError(f"{SHARED} is missing: the tests read the seeds and data from ../shared")
    return SHARED


#: modules that run the live gateway, subprocesses, brokers, ground stations or soak runs: the
#: integration tier (`scripts/test` runs it; `scripts/test --quick` leaves it out)
INTEGRATION_MODULES = frozenset({
    "test_aiding_live", "test_cli", "test_interop_mavproxy", "test_interop_mqtt", "test_interop_signing",
    "test_run_errors", "test_runtime", "test_sim_restart", "test_soak_relay", "test_soak_smoke", "test_gcs_protocols",
    "test_soak_interleave", "test_sigma_consistency", "test_delayed_default", "test_datasets_replay",
})  # fmt: skip


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        mod = item.module.__name__.rsplit(".", 1)[-1] if item.module is not None else ""
        if mod in INTEGRATION_MODULES:
            item.add_marker(pytest.mark.integration)
