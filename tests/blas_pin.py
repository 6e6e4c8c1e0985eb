"""One OpenBLAS kernel on every x86-64 machine with AVX2: a smaller spread of the golden replays.

OpenBLAS picks its kernels by CPU at load time: the SkylakeX (AVX-512) and Haswell (AVX2) kernels round a
matrix product differently in the last bit, which moves the golden replays (tests/golden_replay.py) from one
machine to another with the same numpy/scipy releases. The replays are compared within tolerances that hold
without the pin too (docs/testing.md); the pin removes one source of the spread. Import this module before
numpy (tests/conftest.py, tests/golden_replay.py); an ``OPENBLAS_CORETYPE`` already set is kept.
"""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

KERNEL = "Haswell"


def pin() -> None:
    """Set ``OPENBLAS_CORETYPE`` when the CPU can run the pinned kernel (x86-64 with AVX2)."""
    if "numpy" in sys.modules or platform.machine() not in ("x86_64", "AMD64"):
        return
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return
    if " avx2" in flags:
        os.environ.setdefault("OPENBLAS_CORETYPE", KERNEL)


pin()
