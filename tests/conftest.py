"""Shared test fixtures and paths."""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

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


#: the lock a test run's workers share (pytest-xdist: one per core): every test holds it shared from its setup to its
#: teardown (its module's fixtures included), a real-time run that needs the machine (the null relay's 1 kHz soak:
#: its frame count and loss are real-time properties) holds it alone (:func:`machine_alone`)
_MACHINE_LOCK = Path(tempfile.gettempdir()) / f"ins-hil-tests-{os.getuid()}.lock"
_held: list[Any] = []  # this worker's lock file while a test runs


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    with open(_MACHINE_LOCK, "a+") as f:
        fcntl.flock(f, fcntl.LOCK_SH)
        _held.append(f)
        try:
            yield
        finally:
            _held.pop()
            fcntl.flock(f, fcntl.LOCK_UN)


@contextlib.contextmanager
def machine_alone() -> Iterator[None]:
    """No other test of this run (on another xdist worker) runs meanwhile: they wait for their turn, and this
    waits for theirs to end. For a real-time run whose figures a second real-time test or a CPU-bound fixture beside
    it would break on a 2-core machine. The test's shared hold becomes exclusive (flock converts it) and back."""
    f = _held[-1]
    fcntl.flock(f, fcntl.LOCK_EX)
    try:
        yield
    finally:
        fcntl.flock(f, fcntl.LOCK_SH)


#: modules that run the live gateway, subprocesses, brokers, ground stations or soak runs: the
#: integration tier (`scripts/test` runs it; `scripts/test --quick` leaves it out)
INTEGRATION_MODULES = frozenset({
    "test_aiding_live", "test_cli", "test_interop_mavproxy", "test_interop_mqtt", "test_interop_signing",
    "test_run_errors", "test_runtime", "test_sim_restart", "test_soak_relay", "test_soak_smoke", "test_gcs_protocols",
    "test_soak_interleave", "test_sigma_consistency", "test_delayed_default", "test_datasets_replay",
})  # fmt: skip


#: the modules that take longest in the default run (their own seconds, measured on an idle 2-core machine), longest
#: first: on pytest-xdist workers (`scripts/test`: --dist loadfile --no-loadscope-reorder) they are handed out
#: first, so that no long module starts last while the other worker idles; the rest follow by test count
LONG_MODULES = (
    "test_soak_smoke",  # 130 s: a 2-minute real-time soak (a quarter of one core; the worker only waits)
    "test_datasets_offset",  # 90 s: time-offset and mounting-yaw searches, 5 to 11 replays each
    "test_mechanization_ie",  # 45 s: one hour of the e- and i-frame mechanizations at 100 Hz
    "test_book_ch3_examples",  # 35 s: the chapter's examples in full (cached for the module)
    "test_dataset",  # 35 s: the drive's protocol replayed twice
    "test_gcs_protocols",  # 30 s: live endpoints, MAVProxy, a gateway with sensor pauses
    "test_replay",  # 25 s: Monte-Carlo NEES replays
    "test_reproduce",  # 20 s: the reproduction report
    "test_interop_mavsdk",  # 16 s: MAVSDK against a running gateway
)


def _module(item: pytest.Item) -> str:
    return item.module.__name__.rsplit(".", 1)[-1] if item.module is not None else ""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if _module(item) in INTEGRATION_MODULES:
            item.add_marker(pytest.mark.integration)
    if hasattr(config, "workerinput"):  # a pytest-xdist worker: the long modules first, then by test count
        count: dict[str, int] = {}
        for item in items:
            count[item.nodeid.split("::")[0]] = count.get(item.nodeid.split("::")[0], 0) + 1
        rank = {m: k for k, m in enumerate(LONG_MODULES)}

        def key(item: pytest.Item) -> tuple[int, int]:
            return rank.get(_module(item), len(rank)), -count[item.nodeid.split("::")[0]]

        items.sort(key=key)  # stable: a module's tests keep their order
