"""Description of the machine a benchmark or report ran on (for the generated docs)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: USER_HZ: the unit of the CPU times in /proc (ticks per second)
CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def steal_ticks(cpus: tuple[int, ...]) -> list[int]:
    """Cumulative steal time (USER_HZ ticks, /proc/stat) of these CPUs: time the hypervisor ran
    something else on our virtual CPUs, which no priority inside the guest can prevent ([] if unknown)."""
    try:
        lines = Path("/proc/stat").read_text().splitlines()
    except OSError:
        return []
    by_cpu = {}
    for line in lines:
        f = line.split()
        if f and f[0].startswith("cpu") and f[0] != "cpu" and len(f) > 8:
            by_cpu[int(f[0][3:])] = int(f[8])
    return [by_cpu.get(c, 0) for c in cpus]


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


def load_note(load1: float | None = None, *, own: float = 1.0) -> str:
    """Whether wall-clock figures are trustworthy: the 1-minute load average against the CPUs.

    ``own``: the load the measuring command itself contributes (about one busy process).
    """
    if load1 is None:
        load1 = load_average()[0]
    ncpu = os.cpu_count() or 1
    if load1 != load1:  # NaN: the OS gives no load average
        return "load average unknown"
    if load1 <= own + 0.3:
        return f"load average {load1:.2f} on {ncpu} CPUs: nothing else was running, timings are clean"
    return (
        f"load average {load1:.2f} on {ncpu} CPUs: other processes shared the CPUs, "
        "so wall-clock timings are noisy upper bounds"
    )


def summary() -> str:
    """One line for a generated report: CPUs, model, Python, and the load now with what it means for
    wall-clock figures (:func:`load_note`)."""
    return f"{os.cpu_count()} CPUs (`nproc`), {cpu_model()}, Python {platform.python_version()}; {load_note()}"


def compiler() -> str:
    """First line of ``cc --version`` ("n/a" without a C compiler)."""
    import shutil
    import subprocess

    if not shutil.which("cc"):
        return "n/a"
    out = subprocess.run(["cc", "--version"], capture_output=True, text=True).stdout.splitlines()
    return out[0] if out else "n/a"


def info() -> dict[str, str]:
    """The machine as fields: cpu, nproc, load (1/5/15-minute averages), python, cc, os."""
    return {
        "cpu": cpu_model(),
        "nproc": str(os.cpu_count()),
        "load": ", ".join(f"{x:.2f}" for x in load_average()),
        "python": platform.python_version(),
        "cc": compiler(),
        "os": f"{platform.system()} {platform.release()}",
    }
