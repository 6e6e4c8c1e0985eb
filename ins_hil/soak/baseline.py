"""Platform baseline of a soak: the machine's own wake-up latency, measured by cyclictest.

Every end-to-end sample of the soak passes several wake-ups of SCHED_FIFO threads across the
two CPUs (the sensor emitter's timer, the kernel worker that moves the pty bytes, the gateway,
the ground-station client). ``cyclictest`` (Debian ``rt-tests``, the standard real-time latency
test: one SCHED_FIFO thread per CPU waking every ``interval_us`` and recording how late it ran,
memory locked) measures what the kernel and the hypervisor alone add to each wake-up, with
nothing of ours running. Its tail bounds what any program can reach on this machine: if one
wake-up in a thousand is over 1 ms late, an end-to-end path of four wake-ups cannot have a
p99.9 near its typical latency.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def cyclictest(duration_s: float, cpus: list[int], prio: int = 80, interval_us: int = 1000) -> dict[str, Any]:
    """Run cyclictest for ``duration_s`` s' worth of wake-ups with one thread per CPU in ``cpus``.

    The run is a fixed count of wake-ups per thread (``-l``, ``duration_s / interval``), not a wall-clock
    duration: on a busy host a timed run loses its start-up and every skipped period, so its count would
    say how loaded the machine was rather than what was measured.

    Returns ``{"available": True, "duration_s", "loops", "interval_us", "priority", "cpus": {cpu: {n, p50_us,
    p99_us, p999_us, p9999_us, max_us, over_1ms, over_2ms}}}`` or ``{"available": False, "why": ...}``
    (not installed, not permitted, failed): never raises for a missing tool."""
    exe = shutil.which("cyclictest")
    if exe is None:
        return {"available": False, "why": "cyclictest is not installed (Debian package rt-tests)"}
    loops = max(1, round(duration_s * 1e6 / interval_us))
    # one process per CPU, run together: a single cyclictest with -t N stops every thread as soon as the
    # first one has its -l count, which cuts the others short
    with tempfile.TemporaryDirectory() as td:
        hists = {c: Path(td) / f"hist{c}" for c in cpus}
        procs: dict[int, subprocess.Popen[str]] = {}
        try:
            for c, hist in hists.items():
                cmd = [
                    exe, "-m", "-q", "-p", str(prio), "-i", str(interval_us), "-a", str(c), "-t", "1",
                    "-l", str(loops), "-h", "20000", f"--histfile={hist}",
                ]  # fmt: skip
                procs[c] = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            errs = {c: p.communicate(timeout=4 * duration_s + 60)[1] for c, p in procs.items()}
        except (OSError, subprocess.SubprocessError) as e:
            for p in procs.values():
                p.kill()
                p.wait()
            return {"available": False, "why": f"cyclictest: {e}"}
        out: dict[int, dict[str, float]] = {}
        for c, p in procs.items():
            if p.returncode != 0 or not hists[c].exists():
                return {"available": False, "why": f"cyclictest exited {p.returncode}: {errs[c].strip()[:200]}"}
            out.update(parse_histogram(hists[c].read_text(), [c]))
    return {
        "available": True, "duration_s": duration_s, "loops": loops, "interval_us": interval_us, "priority": prio,
        "cpus": out,
    }  # fmt: skip


def parse_histogram(text: str, cpus: list[int]) -> dict[int, dict[str, float]]:
    """Per-CPU statistics from a cyclictest ``--histfile`` (1 µs bins; overflow past the last bin
    counted at the reported maximum)."""
    rows, maxima, overflow = [], [], []
    for line in text.splitlines():
        if line.startswith("# Max Latencies:"):
            maxima = [int(x) for x in line.split(":", 1)[1].split()]
        elif line.startswith("# Histogram Overflows:"):
            overflow = [int(x) for x in line.split(":", 1)[1].split()]
        elif line.strip() and not line.startswith("#"):
            rows.append([int(x) for x in line.split()])
    if not rows:
        raise ValueError("cyclictest histogram: no data")
    a = np.array(rows, dtype=np.int64)
    us = a[:, 0]
    res: dict[int, dict[str, float]] = {}
    for j, cpu in enumerate(cpus):
        h = a[:, 1 + j].copy()
        mx = maxima[j] if j < len(maxima) else int(us[h > 0].max(initial=0))
        ov = overflow[j] if j < len(overflow) else 0
        vals = np.append(us, mx)
        cnt = np.append(h, ov)
        n = int(cnt.sum())
        cum = np.cumsum(cnt)

        def pct(p: float, vals: np.ndarray = vals, cum: np.ndarray = cum, n: int = n) -> float:
            return float(vals[min(len(vals) - 1, int(np.searchsorted(cum, p / 100.0 * n)))])

        res[cpu] = {
            "n": n, "p50_us": pct(50), "p99_us": pct(99), "p999_us": pct(99.9), "p9999_us": pct(99.99),
            "max_us": float(mx), "over_1ms": int(cnt[vals > 1000].sum()), "over_2ms": int(cnt[vals > 2000].sum()),
        }  # fmt: skip
    return res


def section(p: dict[str, Any] | None) -> str:
    """The report's paragraph on the platform baseline."""
    if not p:
        return ""
    if not p.get("available"):
        return f"Platform wake-up latency (cyclictest): not measured: {p.get('why', '?')}.\n"
    loops = p.get("loops", "?")
    lines = [
        "### Platform baseline: the machine's own wake-up latency (cyclictest, before the runs)",
        "",
        f"`cyclictest -m -p {p['priority']} -i {p['interval_us']} -l {loops}` on each CPU at once: a SCHED_FIFO "
        f"thread waking every {p['interval_us'] / 1000:g} ms, {loops} times, with nothing of the soak running: "
        "how late the kernel and the hypervisor alone let a real-time thread run. Every end-to-end sample of the "
        "soak passes several such wake-ups on the two CPUs (the emitter's timer, the pty's kernel worker, the "
        "gateway, the ground-station client), so this tail is a floor under the soak's tail, whatever the gateway "
        "does.",
        "",
        "| CPU | wake-ups | p50 (µs) | p99 (µs) | p99.9 (µs) | p99.99 (µs) | max (µs) | > 1 ms | > 2 ms |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for cpu, s in sorted(p["cpus"].items(), key=lambda kv: int(kv[0])):
        lines.append(
            f"| {cpu} | {s['n']} | {s['p50_us']:.0f} | {s['p99_us']:.0f} | {s['p999_us']:.0f} | "
            f"{s['p9999_us']:.0f} | {s['max_us']:.0f} | {s['over_1ms']} | {s['over_2ms']} |"
        )
    return "\n".join(lines) + "\n"
