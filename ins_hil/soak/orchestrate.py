"""Start the three soak processes pinned to their CPUs, sample /proc, stop them in order.

Layout on a 2-core machine: CPU A = sensors + ground station (+ this sampler),
CPU B = the gateway alone (or the null relay in its place, ``gateway="relay"``).
Background load: ``load`` busy-loop processes, one per CPU in turn (``load=2`` loads
both). Per second the sampler records, for each process, CPU time (utime+stime), RSS
and open file descriptors into ``proc.jsonl`` and prints a progress line (``progress``
callback).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ins_hil.machine import CLK_TCK, steal_ticks
from ins_hil.runtime.rt import PRIO_CLIENT, PRIO_GATEWAY, PRIO_SENSORS, policy

GCS_RATE = 47.0
PAGE = os.sysconf("SC_PAGE_SIZE")
#: what runs on the gateway CPU: the real gateway, or the null relay (the platform floor, ins_hil.soak.relay)
GATEWAYS = {"ins-hil": "ins_hil.soak.gateway", "relay": "ins_hil.soak.relay"}
RELAY_LABEL = "null relay: no navigation, the transport and wake-up chain alone"


@dataclass
class SoakOptions:
    """One soak run."""

    duration: float = 120.0  # s
    rate: float = 1000.0  # IMU Hz
    imus: int = 1
    links: str = "shared"  # IMU frames: shared (one pty, interleaved by imu_id) | separate (one pty per IMU)
    faults: str = "auto"  # see ins_hil.soak.faults
    core: str = "python"
    load: int = 0  # busy-loop background processes
    transports: str = "serial,udp"
    # ODOMETRY Hz (the end-to-end latency samples). Not 50: every process here reads one clock, so a
    # 50 Hz output would sample the same phase of the 200 ms GNSS cycle for a whole run (always, or
    # never, the epoch after a GNSS update); a period that is no multiple of 1 ms or 200 ms sweeps
    # every phase, as the independent clocks of a real flight controller and GNSS receiver do.
    gcs_rate: float = GCS_RATE
    record: bool = True
    rt: bool = True  # SCHED_FIFO for sensors, gateway and client (ins_hil.runtime.rt priorities)
    # ins-hil: the real gateway; relay: the null relay in its place (same CPU, priority and transports,
    # no navigation: the end-to-end latency floor of the transport and wake-up chain, ins_hil.soak.relay)
    gateway: str = "ins-hil"
    seed: int = 7
    out: str = "soak-out"
    profile: bool = False  # cProfile the gateway (profile.pstats; slows it: for the cost table, not timing)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpus() -> tuple[int, int]:
    """(sensor CPU, gateway CPU): the first two CPUs we may run on (the same one on a 1-CPU machine)."""
    avail = sorted(os.sched_getaffinity(0))
    return avail[0], avail[1] if len(avail) > 1 else avail[0]


def allowed_cpus(pid: int) -> str:
    """The CPUs a process may run on (``Cpus_allowed_list`` of /proc/PID/status), e.g. ``"1"``."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("Cpus_allowed_list:"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "?"


def proc_sample(pid: int) -> dict[str, float] | None:
    """CPU seconds, RSS (bytes), open fds and threads of a live process (None if it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            st = f.read().rsplit(")", 1)[1].split()
        rss = int(st[21]) * PAGE  # field 24 (rss pages), after the ')' split: index 21
        cpu = (int(st[11]) + int(st[12])) / CLK_TCK  # utime, stime (fields 14, 15)
        threads = int(st[17])
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except (OSError, IndexError, ValueError):
        return None
    return {"cpu_s": cpu, "rss": rss, "fds": fds, "threads": threads}


def _line(p: subprocess.Popen[str], what: str, timeout: float = 60.0) -> dict[str, Any]:
    assert p.stdout is not None
    t0 = time.monotonic()
    line = p.stdout.readline()
    if not line:
        rc = p.wait(timeout=max(0.1, timeout - (time.monotonic() - t0)))
        raise RuntimeError(f"{what} exited (status {rc}) before it was ready; see its stderr above")
    return dict(json.loads(line))


def _stop(p: subprocess.Popen[str] | None, timeout: float = 10.0) -> None:
    if p is None or p.poll() is not None:
        return
    p.terminate()
    try:
        p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


def run_soak(opt: SoakOptions, progress: Callable[[str], None] | None = None) -> Path:
    """Run one soak; every raw file goes to ``opt.out`` (created). Returns that directory."""
    out = Path(opt.out)
    out.mkdir(parents=True, exist_ok=True)
    for f in out.glob("*"):
        if f.is_file() and f.suffix in (".bin", ".jsonl", ".json", ".ihlog", ".png", ".md", ".pstats"):
            f.unlink()
    transports = {t.strip() for t in opt.transports.split(",") if t.strip()}
    if transports not in ({"serial", "udp"}, {"can", "udp"}):
        raise RuntimeError(
            f"--transports {opt.transports!r}: serial,udp or can,udp (the IMU over serial frames or DroneCAN over "
            "slcan on a pty; GNSS/MAVLink over UDP)"
        )
    imu_transport = "can" if "can" in transports else "serial"
    if imu_transport == "can" and opt.links != "shared":
        raise RuntimeError("--transports can: every DroneCAN node is on one bus (--imu-links shared)")
    if opt.gateway not in GATEWAYS:
        raise RuntimeError(f"--gateway {opt.gateway!r}: one of {', '.join(GATEWAYS)}")
    cpu_s, cpu_g = cpus()
    recorded = opt.record and opt.gateway == "ins-hil"  # the relay records nothing
    (out / "options.json").write_text(
        json.dumps({**asdict(opt), "record": recorded, "cpu_sensors": cpu_s, "cpu_gateway": cpu_g}, indent=1)
    )
    py = sys.executable
    gnss_port, gcs_port = free_udp_port(), free_udp_port()
    procs: dict[str, subprocess.Popen[str]] = {}
    loaders: list[subprocess.Popen[str]] = []
    fproc = open(out / "proc.jsonl", "w")
    own_affinity = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {cpu_s})
        procs["gcs"] = subprocess.Popen(
            [py, "-m", "ins_hil.soak.gcs", "--port", str(gcs_port), "--out", str(out), "--cpu", str(cpu_s),
             "--rt", str(PRIO_CLIENT if opt.rt else 0)],
            stdout=subprocess.PIPE, text=True)  # fmt: skip
        _line(procs["gcs"], "ground-station client")
        procs["sim"] = subprocess.Popen(
            [py, "-m", "ins_hil.soak.simproc", "--gnss-udp", f"127.0.0.1:{gnss_port}", "--out", str(out),
             "--imus", str(opt.imus), "--links", opt.links, "--rate", str(opt.rate), "--duration", str(opt.duration),
             "--faults", opt.faults, "--cpu", str(cpu_s), "--seed", str(opt.seed),
             "--rt", str(PRIO_SENSORS if opt.rt else 0), "--imu-transport", imu_transport],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
        ptys = _line(procs["sim"], "sensor simulator")["imu"]
        gw_args = [py, "-m", GATEWAYS[opt.gateway], "--gnss-port", str(gnss_port), "--gcs-port", str(gcs_port),
                   "--gcs-rate", str(opt.gcs_rate), "--rate", str(opt.rate), "--core", opt.core,
                   "--duration", str(opt.duration + 3.0), "--out", str(out), "--cpu", str(cpu_g),
                   "--imus", str(opt.imus), "--rt", str(PRIO_GATEWAY if opt.rt else 0),
                   "--imu-transport", imu_transport]  # fmt: skip
        for p in ptys:
            gw_args += ["--imu", p]
        if recorded:
            gw_args.append("--record")
        if opt.profile and opt.gateway == "ins-hil":
            gw_args.append("--profile")
        procs["gateway"] = subprocess.Popen(gw_args, stdout=subprocess.PIPE, text=True)
        _line(procs["gateway"], "gateway")
        for i in range(opt.load):
            cpu = (cpu_s, cpu_g)[i % 2]
            loaders.append(subprocess.Popen(
                [py, "-c", f"import os; os.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"], text=True))  # fmt: skip
        time.sleep(0.5)  # the gateway's serial readers are polling
        t0 = time.monotonic()
        assert procs["sim"].stdin is not None
        procs["sim"].stdin.write("go\n")
        procs["sim"].stdin.flush()
        pids = {k: p.pid for k, p in procs.items()}
        opts = json.loads((out / "options.json").read_text())
        opts["affinity"] = {k: allowed_cpus(pid) for k, pid in pids.items()}
        opts["scheduling"] = {k: policy(pid) for k, pid in pids.items()}
        (out / "options.json").write_text(json.dumps(opts, indent=1))
        ts_path = out / "gateway_ts.jsonl"
        while True:
            time.sleep(1.0 - (time.monotonic() - t0) % 1.0)
            el = time.monotonic() - t0
            row: dict[str, Any] = {"t": el, "mono_ns": time.monotonic_ns(), "steal": steal_ticks((cpu_s, cpu_g))}
            for k, pid in pids.items():
                s = proc_sample(pid)
                if s is not None:
                    row[k] = s
            fproc.write(json.dumps(row) + "\n")
            fproc.flush()
            if progress is not None:
                progress(_progress(el, opt, row, ts_path))
            if procs["gateway"].poll() is not None or el > opt.duration + 20:
                break
            if procs["sim"].poll() is not None and procs["sim"].returncode != 0:
                raise RuntimeError(f"sensor simulator failed (status {procs['sim'].returncode})")
        rc = procs["gateway"].wait(timeout=30)
        if rc != 0:
            raise RuntimeError(f"gateway process failed (status {rc}); see its stderr above")
    finally:
        fproc.close()
        for p in loaders:
            _stop(p, 2.0)
        for k in ("sim", "gateway", "gcs"):
            _stop(procs.get(k))
        for p in procs.values():
            for stream in (p.stdout, p.stdin):
                if stream is not None:
                    stream.close()
        os.sched_setaffinity(0, own_affinity)
    return out


def _progress(el: float, opt: SoakOptions, row: dict[str, Any], ts_path: Path) -> str:
    last: dict[str, Any] = {}
    try:
        with open(ts_path, "rb") as f:
            f.seek(max(0, f.seek(0, 2) - 4096))
            lines = f.read().splitlines()
        if lines:
            last = json.loads(lines[-1])
    except (OSError, ValueError):
        pass
    g = row.get("gateway", {})
    w = last.get("window", {}).get("arrival_to_state", {})
    p99 = w.get("p99_us")
    return (
        f"[soak] {el:6.0f}/{opt.duration:.0f} s  epochs {last.get('epochs', 0)}  late {last.get('late', 0)}  "
        f"dropped {last.get('dropped', 0)}  queue {last.get('queue_max_1s', 0)}  "
        f"arrival→state p99 {p99 if p99 is None else f'{p99:.0f}'} µs  "
        f"RSS {g.get('rss', 0) / 2**20:.1f} MiB  fds {g.get('fds', 0)}  faults {last.get('faults', 0)}"
    )
