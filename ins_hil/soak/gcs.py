"""Soak ground-station client: receives the gateway's MAVLink on UDP and stamps every message.

Binds ``127.0.0.1:--port`` (the gateway's ``udpout:`` output), parses with pymavlink and
stamps CLOCK_MONOTONIC right after ``recvfrom``. Writes to ``--out`` (flushed every
second, so memory stays flat over hours):

* ``gcs_odometry.bin``: int64 (time_usec = the state's sensor time, receive ns);
* ``gcs_odometry_std.bin``: float64 (t s, σ north, σ east, σ down m) from the ODOMETRY pose covariance
  diagonal (NaN when the gateway marks it unknown): the σ the navigation check judges the error by;
* ``gcs_position.bin``: float64 (t s, receive ns, lat rad, lon rad, h m) from GLOBAL_POSITION_INT;
* ``gcs_attitude.bin``: float64 (t s, receive ns, roll, pitch, yaw rad) from ATTITUDE;
* ``gcs_text.jsonl``: STATUSTEXT (receive ns, severity, text) — the fault announcements;
* ``gcs.json``: message counts by type, bad data.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.runtime.rt import policy, set_realtime
from ins_hil.soak.simproc import die_with_parent, pin


class _Stop(Exception):
    pass


def _std(var: float) -> float:
    """σ (m) of a covariance diagonal element; NaN when unknown (NaN) or negative."""
    return math.sqrt(var) if var >= 0.0 else math.nan


def run(a: argparse.Namespace) -> None:
    pin(a.cpu)
    why = set_realtime(a.rt)
    from pymavlink.dialects.v20 import common as mavlink2

    out = Path(a.out)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", a.port))
    sock.settimeout(0.2)
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    odo: list[tuple[int, int]] = []
    odo_std: list[tuple[float, ...]] = []
    pos: list[tuple[float, ...]] = []
    att: list[tuple[float, ...]] = []
    counts: dict[str, int] = {}
    files = {k: open(out / f"gcs_{k}.bin", "wb") for k in ("odometry", "odometry_std", "position", "attitude")}
    f_text = open(out / "gcs_text.jsonl", "w")

    def on_term(*_: Any) -> None:
        raise _Stop

    signal.signal(signal.SIGTERM, on_term)
    # measurement apparatus: no collector pause between a datagram and its receive stamp
    # (the loop below creates no reference cycles)
    gc.collect()
    gc.freeze()
    gc.disable()
    print(json.dumps({"ready": True, "pid": os.getpid(), "scheduling": policy(), "rt_error": why}), flush=True)
    last_flush = time.monotonic()
    mono = time.monotonic_ns

    def flush() -> None:
        if odo:
            np.array(odo, dtype=np.int64).tofile(files["odometry"])
            odo.clear()
        for key, rows in (("odometry_std", odo_std), ("position", pos), ("attitude", att)):
            if rows:
                np.array(rows, dtype=np.float64).tofile(files[key])
                rows.clear()
        for f in (*files.values(), f_text):
            f.flush()

    try:
        while True:
            try:
                data = sock.recv(65536)
            except TimeoutError:
                data = b""
            now = mono()
            if data:
                for m in mav.parse_buffer(data) or []:
                    typ = m.get_type()
                    counts[typ] = counts.get(typ, 0) + 1
                    if typ == "ODOMETRY":
                        odo.append((m.time_usec, now))
                        pc = m.pose_covariance  # upper triangle, row-major: N, E, D variances at 0, 6, 11
                        odo_std.append((m.time_usec * 1e-6, *(_std(pc[i]) for i in (0, 6, 11))))
                    elif typ == "GLOBAL_POSITION_INT":
                        pos.append((m.time_boot_ms * 1e-3, float(now), math.radians(m.lat * 1e-7),
                                    math.radians(m.lon * 1e-7), m.alt * 1e-3))  # fmt: skip
                    elif typ == "ATTITUDE":
                        att.append((m.time_boot_ms * 1e-3, float(now), m.roll, m.pitch, m.yaw))
                    elif typ == "STATUSTEXT":
                        text = m.text if isinstance(m.text, str) else m.text.decode(errors="replace")
                        f_text.write(json.dumps({"recv_ns": now, "severity": m.severity, "text": text}) + "\n")
            if time.monotonic() - last_flush >= 1.0:
                last_flush = time.monotonic()
                flush()
    except (_Stop, KeyboardInterrupt):
        pass
    finally:
        flush()
        for f in (*files.values(), f_text):
            f.close()
        (out / "gcs.json").write_text(json.dumps({"messages": counts}, indent=1))


def main(argv: list[str] | None = None) -> int:
    die_with_parent()
    ap = argparse.ArgumentParser(description="soak ground-station client (see ins_hil.soak.gcs)")
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--cpu", type=int, default=-1)
    ap.add_argument("--rt", type=int, default=0, help="SCHED_FIFO priority (0 = time-shared)")
    run(ap.parse_args(argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
