"""Soak sensor process: N serial IMUs on ptys + GNSS/baro MAVLink over UDP, every emission stamped.

Like :mod:`ins_hil.sim.devices` (whose send loop :class:`~ins_hil.sim.devices.SensorLink`
and MAVLink helpers it uses, with its own IMU emitter that stamps every epoch) but built for
measurement: it pins itself to one CPU, waits for ``go`` on stdin before its clock
starts (so no frame is written before the gateway reads), simulates ``--imus``
redundant IMUs (:mod:`ins_hil.sim.redundant`, ``imu_id`` = unit; ``--links shared``: all
frames interleaved on one pty like an IMU hub, ``separate``: one pty per IMU) with
the fault schedule injected (:mod:`ins_hil.sim.faults`), and writes to ``--out``:

* ``emission.bin``: int64 pairs (sensor time µs, CLOCK_MONOTONIC ns just after the
  first unit's frame was handed to the pty) for every IMU epoch;
* ``truth.bin``: float64 rows (t, lat, lon, h, vn, ve, vd, roll, pitch, yaw) at 10 Hz
  (rad, m, m/s, s of sensor time);
* ``sim.json``: frames written and dropped (pty full) per link, send lateness, scheduling.

The sensor data (trajectory, sensor errors, faults, encoded frames, send schedule) are made
by a producer process (:func:`produce`, SCHED_IDLE on the same CPU) up to 64 10-s chunks
ahead (16 before the start) into a temporary directory (``/dev/shm``); the emitter maps them and only
writes, so a long computation never delays an emission. With ``--rt`` the emitter runs
under SCHED_FIFO (:mod:`ins_hil.runtime.rt`).

Sensor time ``t`` = CLOCK_MONOTONIC − start, the same clock as the gateway's
``t_arrival_ns`` (both processes read the system-wide monotonic clock).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import errno
import gc
import json
import math
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tty
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.drivers.serial_frame import FRAME_LEN, encode
from ins_hil.runtime.metrics import LatencyHistogram
from ins_hil.runtime.rt import policy, set_realtime
from ins_hil.sim import sensors
from ins_hil.sim.devices import SensorLink, _mavlink, _UdpWriter, schedule
from ins_hil.sim.faults import inject, inject_imu
from ins_hil.sim.redundant import simulate
from ins_hil.sim.trajectory import TruthSeries, generate, static_profile, uav_profile
from ins_hil.soak.faults import geometry_for, parse_faults
from ins_hil.types import ImuSample

TRUTH_COLS = ("t", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "yaw")
TRUTH_RATE = 10.0  # Hz


def pin(cpu: int) -> None:
    """Pin this process to one CPU (no-op if it does not exist) and use 1 ns timer slack (Linux)."""
    if cpu >= 0:
        try:  # the parent may be pinned elsewhere: any CPU of the machine is allowed
            os.sched_setaffinity(0, {cpu})
        except OSError as e:
            print(f"soak: cannot pin to CPU {cpu}: {e}", file=sys.stderr)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)  # PR_SET_TIMERSLACK = 1 ns
    except (OSError, AttributeError):
        pass


def chunks(a: argparse.Namespace) -> Any:
    """Yield (imu epochs, truth, gnss fixes, baro samples) per ``chunk_s`` (deterministic for a seed).

    imu epochs: (t (N,), dtheta (N, units, 3), dvel (N, units, 3), flags (N, units)) in each unit's frame.
    """
    prof = uav_profile() if a.profile == "uav" else static_profile(yaw=0.3)
    dt = 1.0 / a.rate
    rng = np.random.default_rng(a.seed)
    faults = parse_faults(a.faults, a.duration, a.imus)
    gm = sensors.GnssModel(rate=a.gnss_rate)
    geo = geometry_for(a.imus) if a.imus > 1 else None
    gyro, accel = sensors.mems_gyro(rng), sensors.mems_accel(rng)
    lat, lon, h, t0 = math.radians(a.lat_deg), math.radians(a.lon_deg), a.h, 0.0
    n_chunk = max(1, round(a.chunk_s / dt))
    k = 0
    while True:
        truth = generate(prof, n_chunk * dt, dt, lat, lon, h, t0=t0)
        if geo is None:
            s = sensors.corrupt_imu(truth, gyro, accel, rng)
            for f in faults:
                s = inject_imu(s, f, seed=a.seed + k)
            dth, dv, fl = s.dtheta[:, None, :], s.dvel[:, None, :], np.asarray(s.flags)[:, None]
            t = s.t
        else:
            r = simulate(truth, geo, seed=a.seed * 1000 + k)
            for f in faults:
                r = inject(r, f, seed=a.seed + k)
            n = len(r.t)
            dth, dv, fl, t = r.gyro.reshape(n, -1, 3), r.accel.reshape(n, -1, 3), r.flags, r.t
        sub = TruthSeries(truth.t[1:], truth.q_nb[1:], truth.euler[1:], truth.vel_ned[1:], truth.lat[1:],
                          truth.lon[1:], truth.h[1:], truth.dtheta, truth.dvel, truth.dt)  # fmt: skip
        fixes = sensors.gnss_fixes(sub, gm, rng)
        baro = sensors.baro_samples(sub, rate=a.baro_rate, std=0.5, seed=rng)
        yield (t, dth, dv, fl), sub, fixes, baro
        lat, lon, h, t0 = float(truth.lat[-1]), float(truth.lon[-1]), float(truth.h[-1]), float(truth.t[-1])
        k += 1


def truth_rows(tr: TruthSeries, rate: float) -> np.ndarray:
    """Rows (t, lat, lon, h, vn, ve, vd, roll, pitch, yaw) at the sensor times that are multiples of 1/rate."""
    step = 1.0 / rate
    sel = np.flatnonzero(np.abs(tr.t / step - np.round(tr.t / step)) < 1e-6)
    return np.column_stack((tr.t[sel], tr.lat[sel], tr.lon[sel], tr.h[sel], tr.vel_ned[sel], tr.euler[sel])).astype(
        np.float64
    )


#: DroneCAN node id of simulated IMU unit u: CAN_NODE_BASE + u (the gateway's imu_id)
CAN_NODE_BASE = 10


def slcan_line(can_id: int, data: bytes) -> bytes:
    """One extended CAN frame as an slcan (Lawicel) line: ``T`` + 8 hex id + dlc + hex data + CR."""
    return b"T%08X%d%s\r" % (can_id, len(data), data.hex().upper().encode())


class SlcanNodes:
    """The simulated IMUs as DroneCAN nodes ``CAN_NODE_BASE + u``: per epoch one RawIMU transfer per node
    (``timestamp.usec`` = the epoch's sensor time), and a NodeStatus per node once a second of sensor time,
    each frame an slcan line (the bytes an slcan adapter puts on its serial line)."""

    def __init__(self, n_units: int) -> None:
        from ins_hil.drivers import dronecan_codec as dc

        self.dc, self.n = dc, n_units
        self.tid = {(u, k): 0 for u in range(n_units) for k in (dc.DTID_RAW_IMU, dc.DTID_NODE_STATUS)}
        self.next_status = 0.0  # s of sensor time

    def _transfer(self, u: int, dtid: int, payload: bytes, priority: int) -> bytes:
        dc = self.dc
        cid = dc.message_can_id(dtid, CAN_NODE_BASE + u, priority)
        t = self.tid[(u, dtid)]
        self.tid[(u, dtid)] = (t + 1) & 0x1F
        return b"".join(slcan_line(cid, f) for f in dc.split_transfer(dtid, payload, t))

    def chunk(self, t: np.ndarray, dth: np.ndarray, dv: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(uint8 (N, units, W) rows of slcan bytes, int32 (N, units) bytes used per row) of one chunk."""
        dc = self.dc
        rows: list[list[bytes]] = []
        for i in range(len(t)):
            tk = float(t[i])
            row = []
            for u in range(self.n):
                b = self._transfer(u, dc.DTID_RAW_IMU, dc.raw_imu_payload(ImuSample(tk, dt, dth[i, u], dv[i, u])), 16)
                if tk >= self.next_status:
                    b += self._transfer(u, dc.DTID_NODE_STATUS, dc.node_status_payload(int(tk)), 24)
                row.append(b)
            if tk >= self.next_status:
                self.next_status = math.floor(tk) + 1.0
            rows.append(row)
        w = max(len(b) for r in rows for b in r)
        frames = np.zeros((len(t), self.n, w), dtype=np.uint8)
        lens = np.zeros((len(t), self.n), dtype=np.int32)
        for i, r in enumerate(rows):
            for u, b in enumerate(r):
                frames[i, u, : len(b)] = np.frombuffer(b, dtype=np.uint8)
                lens[i, u] = len(b)
        return frames, lens


def die_with_parent() -> None:
    """Linux: get SIGTERM when the parent (the soak orchestrator) dies (prctl PR_SET_PDEATHSIG)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        pass


class _Stop(Exception):
    pass


def _write(fd: int, frame: bytes, pending: list[bytes], u: int) -> bool:
    """Write one frame to a non-blocking pty like a UART with a FIFO: whole frames or nothing.

    The rest of a partially written frame waits in ``pending[u]`` and goes first next time;
    a new frame is dropped (False) while an older one is still waiting (the reader is behind).
    """
    if pending[u]:
        try:
            n = os.write(fd, pending[u])
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EWOULDBLOCK):
                raise
            n = 0
        pending[u] = pending[u][n:]
        if pending[u]:
            return False
    try:
        n = os.write(fd, frame)
    except OSError as e:
        if e.errno not in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise
        return False
    if n < len(frame):
        pending[u] = frame[n:]
    return True


#: chunks the producer may have ready ahead of the emitter (~1.2 MB each with 2 IMUs at 1 kHz)
AHEAD = 64
#: chunks made before the emitter starts: under a background load on its CPU the SCHED_IDLE producer
#: gets almost no time, and the run lives on this reserve (0.7 CPU-s per 10-s chunk with 2 IMUs)
PRE_CHUNKS = 16


def _chunk_path(d: Path, k: int, what: str) -> Path:
    return d / f"{k:06d}.{what}"


def produce(a: argparse.Namespace, d: Path) -> None:
    """The producer process body: every chunk of :func:`chunks`, ready to send, into directory ``d``.

    Per chunk ``k``: ``t.npy`` (epoch sensor times), ``frames.npy`` (uint8 (N, units, 41): the encoded
    serial frames, ``seq`` counting epochs over the whole run), ``sched.npy`` (the send schedule of
    :func:`~ins_hil.sim.devices.schedule` as float64 rows (time, kind, index)), ``aid.pkl`` (the GNSS fixes
    and baro samples) and then an empty ``ready`` marker; the truth rows go to ``--out``/truth.bin.
    At most :data:`AHEAD` chunks wait unconsumed (the emitter deletes what it has sent). Runs
    under SCHED_IDLE: the emitter, the client and kernel workers always come first on the shared CPU.
    """
    # SCHED_IDLE: anything else that wakes on this CPU preempts it at once, including the kernel worker
    # that moves the emitter's pty bytes to the gateway (a SCHED_BATCH/nice producer made that worker
    # wait for the rest of the producer's time slice: milliseconds of latency)
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    out = Path(a.out)
    dt = 1.0 / a.rate
    seq = 0
    can_node = SlcanNodes(a.imus) if a.imu_transport == "can" else None
    with open(out / "truth.bin", "wb") as f_tr:
        for k, ((t_imu, dth, dv, fl), sub, fixes, baro) in enumerate(chunks(a)):
            while _chunk_path(d, k - AHEAD, "ready").exists():
                time.sleep(0.05)
            truth_rows(sub, TRUTH_RATE).tofile(f_tr)
            f_tr.flush()
            n = len(t_imu)
            lens = None
            if can_node is not None:
                frames, lens = can_node.chunk(t_imu, dth, dv, dt)
            else:
                frames = np.empty((n, a.imus, FRAME_LEN), dtype=np.uint8)
                for i in range(n):
                    tk = float(t_imu[i])
                    for u in range(a.imus):
                        frame = encode(ImuSample(tk, dt, dth[i, u], dv[i, u], u, seq & 0xFFFF, 35.0, int(fl[i, u])))
                        frames[i, u] = np.frombuffer(frame, dtype=np.uint8)
                    seq += 1
            if lens is not None:
                np.save(_chunk_path(d, k, "lens.npy"), lens)
            sched = np.array(schedule(t_imu, fixes, baro, a.gnss_latency), dtype=np.float64).reshape(-1, 3)
            np.save(_chunk_path(d, k, "t.npy"), np.asarray(t_imu, dtype=np.float64))
            np.save(_chunk_path(d, k, "frames.npy"), frames)
            np.save(_chunk_path(d, k, "sched.npy"), sched)
            with open(_chunk_path(d, k, "aid.pkl"), "wb") as f:
                pickle.dump((fixes, baro), f, protocol=pickle.HIGHEST_PROTOCOL)
            _chunk_path(d, k, "ready").touch()


def _sched_rows(sched: np.ndarray, step: int = 256) -> Iterator[tuple[float, int, int]]:
    """(time, kind, index) rows, converted to Python numbers a slice at a time (no long pause)."""
    for j in range(0, len(sched), step):
        blk = sched[j : j + step]
        yield from zip(blk[:, 0].tolist(), blk[:, 1].astype(np.int64).tolist(), blk[:, 2].astype(np.int64).tolist())


class _Chunks:
    """The emitter's side of the producer: wait for, map and delete chunk files."""

    def __init__(self, d: Path, producer: subprocess.Popen[bytes]) -> None:
        self.d, self.producer = d, producer
        self.lens: np.ndarray | None = None  # CAN: bytes used of each (epoch, unit) row of the last chunk

    def load(self, k: int, timeout: float = 120.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[Any], list[Any]]:
        t0 = time.monotonic()
        ready = _chunk_path(self.d, k, "ready")
        while not ready.exists():
            if self.producer.poll() is not None:
                raise RuntimeError(f"the sensor data producer exited (status {self.producer.returncode})")
            if time.monotonic() - t0 > timeout:
                raise RuntimeError(f"the sensor data producer did not deliver chunk {k} within {timeout:.0f} s")
            time.sleep(0.005)
        t = np.load(_chunk_path(self.d, k, "t.npy"), mmap_mode="r")
        frames = np.load(_chunk_path(self.d, k, "frames.npy"), mmap_mode="r")
        sched = np.load(_chunk_path(self.d, k, "sched.npy"), mmap_mode="r")
        with open(_chunk_path(self.d, k, "aid.pkl"), "rb") as f:
            fixes, baro = pickle.load(f)
        lens_path = _chunk_path(self.d, k, "lens.npy")
        self.lens = np.load(lens_path) if lens_path.exists() else None
        return t, frames, sched, fixes, baro

    def done(self, k: int) -> None:
        for what in ("ready", "t.npy", "frames.npy", "lens.npy", "sched.npy", "aid.pkl"):
            with contextlib.suppress(OSError):
                _chunk_path(self.d, k, what).unlink()


def run(a: argparse.Namespace) -> None:
    """The process body (see module doc)."""
    pin(a.cpu)
    out = Path(a.out)
    # the sensor data come from a producer process (time-shared, low priority), not from a thread of this
    # one: a generator thread holding the GIL delayed emissions by milliseconds (tens under SCHED_FIFO)
    shm = Path("/dev/shm") if Path("/dev/shm").is_dir() else out
    d = Path(tempfile.mkdtemp(prefix="ins-hil-soak-", dir=shm))
    producer = subprocess.Popen([sys.executable, "-m", "ins_hil.soak.simproc", "--produce", str(d), *sys.argv[1:]])
    try:
        _emit(a, out, _Chunks(d, producer))
    finally:
        producer.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            producer.wait(5)
        shutil.rmtree(d, ignore_errors=True)


def _emit(a: argparse.Namespace, out: Path, src: _Chunks) -> None:
    if a.imu_transport == "can" and a.links == "separate":
        raise SystemExit("soak simulator: --imu-transport can puts every node on one bus (--links shared)")
    n_links = a.imus if a.links == "separate" else 1
    masters, slaves, paths = [], [], []
    for _ in range(n_links):
        m, s = os.openpty()
        tty.setraw(s)
        os.set_blocking(m, False)
        masters.append(m)
        slaves.append(s)  # kept open: the pty lives until we exit
        paths.append(os.ttyname(s))
    host, port = a.gnss_udp.rsplit(":", 1)
    writer = _UdpWriter((host, int(port)))
    from pymavlink.dialects.v20 import common as mavlink2

    mav = _mavlink(writer, 1, mavlink2.MAV_COMP_ID_GPS, "")
    rx = mavlink2.MAVLink(None)
    rx.robust_parsing = True
    k = 0
    cur = src.load(k)
    src.load(min(PRE_CHUNKS, math.ceil(a.duration / a.chunk_s)) - 1, timeout=600.0)  # the reserve
    why = set_realtime(a.rt)
    print(json.dumps({"imu": paths, "pid": os.getpid(), "scheduling": policy(), "rt_error": why}), flush=True)
    if sys.stdin.readline().strip() != "go":
        return
    # measurement apparatus: no collector pause (tens of ms in this process) between two emissions;
    # the emitter creates no reference cycles, so reference counting frees everything
    gc.collect()
    gc.freeze()
    gc.disable()
    written = [0] * n_links
    units = range(a.imus)
    pending = [b""] * n_links
    dropped = [0] * n_links
    late = LatencyHistogram()  # emission − scheduled time
    stats: dict[str, Any] = {"scheduling": policy(), "rt_error": why}

    ppid = os.getppid()
    stopped = False

    def on_term(*_: Any) -> None:
        nonlocal stopped
        stopped = True
        raise _Stop

    signal.signal(signal.SIGTERM, on_term)
    f_em = open(out / "emission.bin", "wb")
    t_start_ns = time.monotonic_ns()
    stats["t_start_ns"] = t_start_ns
    mono = time.monotonic_ns
    link = SensorLink(writer, rx, mav, t_start_ns, a.duration)

    def _write_stats() -> None:
        stats.update(
            imus=a.imus,
            links=n_links,
            rate_hz=a.rate,
            written=written,
            dropped_pty_full=dropped,
            unsent_pending_bytes=[len(b) for b in pending],
            udp_send_errors=writer.errors,
            send_lateness=late.summary(),
            t_end_ns=time.monotonic_ns(),
        )
        (out / "sim.json").write_text(json.dumps(stats, indent=1))

    try:
        while True:
            t_imu, frames, sched, fixes, baro = cur
            n = len(t_imu)
            em = np.zeros((n, 2), dtype=np.int64)
            em[:, 0] = np.round(t_imu * 1e6).astype(np.int64)
            n_done = 0

            lens = src.lens

            def emit_imu(i: int, due: int, frames: Any = frames, em: Any = em, lens: Any = lens) -> None:
                # every unit's frame of epoch i, stamped (CLOCK_MONOTONIC) after the first write; on a shared
                # link the epoch's frames go out back to back in one write, as an IMU hub sends them
                nonlocal n_done
                row = frames[i]
                if n_links == 1:
                    data = row.tobytes() if lens is None else b"".join(row[u, : lens[i, u]].tobytes() for u in units)
                    if _write(masters[0], data, pending, 0):
                        written[0] += a.imus
                    else:
                        dropped[0] += a.imus
                    now = mono()
                    em[i, 1] = now
                    late.record(now - due)
                else:
                    for u in range(a.imus):
                        if _write(masters[u], row[u].tobytes(), pending, u):
                            written[u] += 1
                        else:
                            dropped[u] += 1
                        if u == 0:
                            now = mono()
                            em[i, 1] = now
                            late.record(now - due)
                n_done = i + 1

            try:
                if not link.serve(_sched_rows(sched), emit_imu, fixes, baro):
                    raise _Stop
            finally:
                em[:n_done][em[:n_done, 1] > 0].tofile(f_em)
            src.done(k)
            k += 1
            cur = src.load(k)
    except (_Stop, KeyboardInterrupt, BrokenPipeError):
        pass
    finally:
        f_em.close()
        _write_stats()
    # keep the ptys open (closing them discards what the gateway has not read yet) until told to stop,
    # unless we were stopped already or the parent is gone
    with contextlib.suppress(_Stop, KeyboardInterrupt):
        while not stopped and os.getppid() == ppid:
            time.sleep(0.2)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description="soak sensor process (see ins_hil.soak.simproc)")
    ap.add_argument("--gnss-udp", required=True, help="host:port of the gateway's MAVLink input")
    ap.add_argument("--out", required=True)
    ap.add_argument("--imus", type=int, default=1)
    ap.add_argument("--links", choices=["shared", "separate"], default="shared")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--duration", type=float, required=True)
    ap.add_argument("--faults", default="none")
    ap.add_argument("--cpu", type=int, default=-1)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--profile", default="uav", choices=["uav", "static"])
    ap.add_argument("--gnss-rate", type=float, default=5.0)
    ap.add_argument("--gnss-latency", type=float, default=0.05)
    ap.add_argument("--baro-rate", type=float, default=25.0)
    ap.add_argument(
        "--imu-transport",
        choices=["serial", "can"],
        default="serial",
        help="serial frames, or DroneCAN nodes (RawIMU + NodeStatus) as slcan lines on the pty",
    )
    ap.add_argument("--chunk-s", type=float, default=10.0)
    ap.add_argument("--rt", type=int, default=0, help="SCHED_FIFO priority of the emitter (0 = time-shared)")
    ap.add_argument("--produce", metavar="DIR", help=argparse.SUPPRESS)  # internal: the producer process
    ap.add_argument("--lat-deg", type=float, default=50.45)
    ap.add_argument("--lon-deg", type=float, default=30.52)
    ap.add_argument("--h", type=float, default=180.0)
    return ap


def main(argv: list[str] | None = None) -> int:
    die_with_parent()
    a = build_parser().parse_args(argv)
    if a.produce:
        with contextlib.suppress(KeyboardInterrupt):
            produce(a, Path(a.produce))
        return 0
    with contextlib.suppress(_Stop, KeyboardInterrupt):  # a SIGTERM during the clean-up (the whole process group
        run(a)  # was signalled: the soak's Ctrl-C or timeout): stopped, not a traceback
    return 0


if __name__ == "__main__":
    sys.exit(main())
