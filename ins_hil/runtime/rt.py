"""Real-time scheduling of a process (Linux): SCHED_FIFO priority and locked memory.

A HIL gateway on a small companion computer shares its CPUs with everything else the
computer runs; under the default time-sharing scheduler a busy neighbour (or a
low-priority job that got its slice) delays an IMU sample by milliseconds. SCHED_FIFO
makes the loop preempt every time-shared task as soon as it is runnable; the kernel's
RT throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default) still
leaves the rest of the system a share if the loop ever spins.
"""

from __future__ import annotations

import os

#: SCHED_FIFO priorities of the soak's processes: the sensors above the gateway above the client
PRIO_SENSORS = 60
PRIO_GATEWAY = 50
PRIO_CLIENT = 40


def set_realtime(priority: int) -> str:
    """Run this process (all its threads created later) under SCHED_FIFO at ``priority`` (1–99).

    Returns ``""`` on success, else why not (no permission: run as root or grant CAP_SYS_NICE,
    e.g. ``setcap cap_sys_nice+ep`` on the interpreter, or ``LimitRTPRIO`` in a systemd unit);
    ``priority`` 0 means time-sharing (SCHED_OTHER) and always succeeds.
    """
    if not 0 <= priority <= 99:
        raise ValueError(f"real-time priority {priority}: must be 0 (off) to 99")
    if not hasattr(os, "sched_setscheduler"):
        return "" if priority == 0 else "this platform has no sched_setscheduler"
    try:
        if priority == 0:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        else:
            os.sched_setscheduler(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
    except PermissionError:
        return f"SCHED_FIFO {priority}: permission denied (needs root or CAP_SYS_NICE)"
    except OSError as e:
        return f"SCHED_FIFO {priority}: {e}"
    return ""


def lock_memory() -> str:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``: keep every page of this process resident, so the IMU path
    never waits for a page fault (standard practice for a real-time process; needs root, CAP_IPC_LOCK
    or a large enough RLIMIT_MEMLOCK). Costs resident memory (the gateway: ~110 → ~290 MiB); its latency
    effect was within run-to-run noise in the soak on the development VM. Returns ``""`` on success, else why not."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        if libc.mlockall(1 | 2) != 0:  # MCL_CURRENT | MCL_FUTURE
            return f"mlockall: {os.strerror(ctypes.get_errno())}"
    except (OSError, AttributeError) as e:
        return f"mlockall: {e}"
    return ""


def enter_realtime(priority: int) -> str:
    """How a real-time process starts: :func:`set_realtime` at ``priority``, then :func:`lock_memory`.
    Returns ``""`` on success, else a warning that says what the process runs with instead."""
    why = set_realtime(priority)
    if why:
        return f"{why}; running time-shared"
    why = lock_memory()
    if why:
        return f"{why}; pages may be faulted in on the IMU path"
    return ""


def policy(pid: int = 0) -> str:
    """A process's (0: this one) scheduling policy and priority, e.g. ``"SCHED_FIFO 50"`` or ``"SCHED_OTHER"``."""
    if not hasattr(os, "sched_getscheduler"):
        return "?"
    try:
        pol = os.sched_getscheduler(pid) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        prio = os.sched_getparam(pid).sched_priority
    except OSError:
        return "?"
    names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
             if hasattr(os, n)}  # fmt: skip
    name = names.get(pol, str(pol))
    return f"{name} {prio}" if prio else name
