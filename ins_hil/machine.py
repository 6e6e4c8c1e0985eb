"""Description of the machine a benchmark or report ran on (for the generated docs)."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo (or what platform knows)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def load_average() -> tuple[float, float, float]:
    """1/5/15-minute load averages (NaN where the OS has none)."""
    try:
        return os.getloadavg()
    except (OSError, AttributeError):
        return (float("nan"),) * 3


def describe() -> str:
    """One line: CPUs, model, Python, load average now."""
    l1, l5, l15 = load_average()
    return (
        f"{os.cpu_count()} CPUs (`nproc`), {cpu_model()}, Python {platform.python_version()}, "
        f"load average {l1:.2f}/{l5:.2f}/{l15:.2f}"
    )
