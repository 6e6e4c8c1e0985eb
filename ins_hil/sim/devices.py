"""Simulated sensors over real local transports, in their own process.

The IMU writes 41-byte serial frames (:mod:`ins_hil.drivers.serial_frame`)
into a pseudo-terminal at its rate (1 kHz by default): the gateway opens the
pty's slave side like any serial port. The GNSS receiver (GPS_INPUT, with
NED velocity and accuracies) and the barometer (SCALED_PRESSURE) talk
MAVLink 2 over UDP from their own system id, with a HEARTBEAT at 1 Hz, and
optionally sign their messages. Truth comes from
:mod:`ins_hil.sim.trajectory`, the sensor errors from :mod:`ins_hil.sim.sensors`.

Every device shares one sensor clock: ``t`` (s) since the start of the
trajectory, the serial frame's ``t_us``, GPS_INPUT ``time_usec`` and
SCALED_PRESSURE ``time_boot_ms``. The truth is generated in chunks of
``chunk_s`` seconds (in a helper thread, ahead of time), so a run can be
unbounded; position continues across chunks, the Gauss–Markov bias drift
restarts from its stationary distribution at each chunk boundary.

Run as ``python -m ins_hil.sim.devices ...``: the first stdout line is a JSON
object naming the pty (``{"imu": "/dev/pts/N"}``); :class:`SimDevices`
starts and stops that process for the gateway and the tests.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tty
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np

from ins_hil.drivers.mavlink_link import signing_timestamp
from ins_hil.drivers.serial_frame import encode
from ins_hil.geoid import msl_height
from ins_hil.sim import sensors
from ins_hil.sim.trajectory import TruthSeries, generate, static_profile, uav_profile
from ins_hil.types import ImuSample, SimConfig, gps_from_unix


def truth_chunks(cfg: SimConfig) -> Any:
    """Yield (truth, imu_series, gnss_fixes, baro_samples) chunk after chunk (deterministic for a seed)."""
    prof = uav_profile() if cfg.profile == "uav" else static_profile(yaw=0.3)
    dt = 1.0 / cfg.imu_rate
    rng = np.random.default_rng(cfg.seed)
    if cfg.imu_errors == "mems":
        gyro, accel = sensors.mems_gyro(rng), sensors.mems_accel(rng)
    else:
        gyro, accel = sensors.ImuErrorModel(), sensors.ImuErrorModel()
    gm = sensors.GnssModel(rate=cfg.gnss_rate, std_ne=cfg.gnss_std_ne, std_d=cfg.gnss_std_d, std_vel=cfg.gnss_std_vel)
    lat, lon, h, t0 = math.radians(cfg.lat_deg), math.radians(cfg.lon_deg), cfg.h, 0.0
    n_chunk = max(1, round(cfg.chunk_s / dt))
    while True:
        truth = generate(prof, n_chunk * dt, dt, lat, lon, h, t0=t0)
        imu = sensors.corrupt_imu(truth, gyro, accel, rng)
        # GNSS/baro epochs: skip row 0 (it belongs to the previous chunk) by generating on rows 1..N
        sub = _tail(truth)
        fixes = sensors.gnss_fixes(sub, gm, rng)
        baro = sensors.baro_samples(sub, rate=cfg.baro_rate, std=cfg.baro_std, seed=rng)
        yield truth, imu, fixes, baro
        lat, lon, h, t0 = float(truth.lat[-1]), float(truth.lon[-1]), float(truth.h[-1]), float(truth.t[-1])


def _tail(tr: TruthSeries) -> TruthSeries:
    return TruthSeries(tr.t[1:], tr.q_nb[1:], tr.euler[1:], tr.vel_ned[1:], tr.lat[1:], tr.lon[1:], tr.h[1:],
                       tr.dtheta, tr.dvel, tr.dt)  # fmt: skip


class _UdpWriter:
    """File-like for pymavlink: each write is one datagram to ``addr``; ``poll`` reads what comes back."""

    def __init__(self, addr: tuple[str, int]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.addr = addr
        self.errors = 0

    def poll(self) -> bytes:
        out = b""
        while True:
            try:
                data, _ = self.sock.recvfrom(4096)
            except (BlockingIOError, ConnectionRefusedError):
                return out
            except OSError:
                return out
            out += data

    def write(self, b: bytes) -> None:
        try:
            self.sock.sendto(b, self.addr)
        except OSError:
            self.errors += 1


def _mavlink(writer: _UdpWriter, sysid: int, compid: int, key: str) -> Any:
    from pymavlink.dialects.v20 import common as mavlink2

    mav = mavlink2.MAVLink(writer, srcSystem=sysid, srcComponent=compid)
    if key:
        mav.signing.secret_key = bytes.fromhex(key)
        mav.signing.link_id = 1
        mav.signing.timestamp = signing_timestamp()
        mav.signing.sign_outgoing = True
    return mav


def run_devices(cfg: SimConfig, gnss_addr: tuple[str, int], announce: bool = True) -> None:
    """The device process body: serve the IMU pty and send GNSS/baro until ``duration`` (or forever)."""
    sys.setswitchinterval(0.0005)  # the chunk generator thread must not hold the GIL for long
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    path = os.ttyname(slave)
    if announce:
        print(json.dumps({"imu": path, "pid": os.getpid()}), flush=True)
    writer = _UdpWriter(gnss_addr)
    from pymavlink.dialects.v20 import common as mavlink2

    mav = _mavlink(writer, cfg.gnss_sysid, mavlink2.MAV_COMP_ID_GPS, cfg.sign_key)
    rx = mavlink2.MAVLink(None)
    rx.robust_parsing = True
    chunks = truth_chunks(cfg)
    nxt: list[Any] = [next(chunks)]
    ready = threading.Event()

    def prefetch() -> None:
        nxt.append(next(chunks))
        ready.set()

    t_start_ns = time.monotonic_ns()
    dropped = 0
    pending = bytearray()
    seq = 0
    dt = 1.0 / cfg.imu_rate
    link = SensorLink(writer, rx, mav, t_start_ns, cfg.duration)
    while True:
        _truth, imu, fixes, baro = nxt.pop(0)
        ready.clear()
        th = threading.Thread(target=prefetch, daemon=True)
        th.start()

        def emit_imu(i: int, _due_ns: int, imu: Any = imu) -> None:
            nonlocal seq, dropped
            frame = encode(
                ImuSample(float(imu.t[i]), dt, imu.dtheta[i], imu.dvel[i], 0, seq & 0xFFFF, 35.0, int(imu.flags[i]))
            )
            seq += 1
            # a UART keeps whole frames: queue what the pty cannot take now, drop whole frames
            # (counted) only when more than ~100 ms is queued, never part of one
            if len(pending) > 100 * len(frame):
                dropped += 1
            else:
                pending.extend(frame)
            if pending:
                try:
                    n = os.write(master, pending)
                    del pending[:n]
                except OSError as e:
                    if e.errno not in (errno.EAGAIN, errno.EWOULDBLOCK):
                        raise

        if not link.serve(schedule(imu.t, fixes, baro, cfg.gnss_latency), emit_imu, fixes, baro):
            return
        th.join()


def schedule(imu_t: Any, fixes: list[Any], baro: list[Any], gnss_latency: float) -> list[tuple[float, int, int]]:
    """The send schedule of one chunk: (send time s, kind 0 = IMU epoch / 1 = GNSS / 2 = baro, index), sorted.

    GNSS fixes go out ``gnss_latency`` after their time of validity, the rest at their sensor time."""
    sched: list[tuple[float, int, int]] = [(float(imu_t[k]), 0, k) for k in range(len(imu_t))]
    sched += [(f.t + gnss_latency, 1, i) for i, f in enumerate(fixes)]
    sched += [(b.t, 2, i) for i, b in enumerate(baro)]
    sched.sort()
    return sched


def send_order(
    cfg: SimConfig, duration: float, alter: Callable[[list[Any], list[Any]], tuple[list[Any], list[Any]]] | None = None
) -> Iterator[Any]:
    """Every simulated input (ImuSample, GnssFix, BaroSample) of :func:`truth_chunks` in the devices'
    send order (:func:`schedule`) for ``duration`` s, without real time: the offline stand-in for a live
    run. ``alter(fixes, baro) -> (fixes, baro)`` may inject aiding faults chunk by chunk."""
    for truth, imu, fixes, baro in truth_chunks(cfg):
        if alter is not None:
            fixes, baro = alter(fixes, baro)
        samples = list(imu.samples())
        for _, kind, i in schedule(imu.t, fixes, baro, cfg.gnss_latency):
            yield samples[i] if kind == 0 else (fixes if kind == 1 else baro)[i]
        if truth.t[-1] >= duration - 1e-9:
            return


class SensorLink:
    """The one send loop of the simulated devices (``run_devices`` and the soak's sensor process).

    :meth:`serve` sleeps until each scheduled time (``t_start_ns`` + send time, CLOCK_MONOTONIC),
    hands IMU epochs to the caller's ``emit_imu(index, due_ns)`` (the frames and their transport:
    one pty, or several, with emission stamps), sends GNSS (GPS_INPUT) and baro
    (SCALED_PRESSURE) over MAVLink, answers TIMESYNC and sends a 1 Hz HEARTBEAT."""

    def __init__(self, writer: _UdpWriter, rx: Any, mav: Any, t_start_ns: int, duration: float = 0.0) -> None:
        self.writer, self.rx, self.mav = writer, rx, mav
        self.t_start_ns = t_start_ns
        self.duration = duration
        self._t_hb = -1.0
        # GPS time at sensor time 0: the wall clock at the start (GPS time goes to the outputs only)
        week, tow = gps_from_unix(time.time())
        self.gps0 = week * 604_800 + tow

    def serve(
        self,
        sched: Iterable[tuple[float, int, int]],
        emit_imu: Callable[[int, int], None],
        fixes: list[Any],
        baro: list[Any],
    ) -> bool:
        """Send one chunk's schedule; False once ``duration`` (> 0) is reached."""
        from pymavlink.dialects.v20 import common as mavlink2

        mono = time.monotonic_ns
        t0 = self.t_start_ns
        t_start = t0 * 1e-9
        mav = self.mav
        for ts, kind, i in sched:
            if self.duration and ts > self.duration:
                return False
            due = t0 + round(ts * 1e9)
            delay = (due - mono()) * 1e-9
            if delay > 0:
                time.sleep(delay)
            if kind == 0:
                emit_imu(i, due)
            elif kind == 1:
                _send_gnss(mav, fixes[i], self.gps0)
            else:
                b = baro[i]
                mav.scaled_pressure_send(round(b.t * 1000), b.pressure / 100.0, 0.0, 2000)
            _answer_timesync(self.writer, self.rx, mav, t_start)
            if ts - self._t_hb >= 1.0:
                self._t_hb = ts
                mav.heartbeat_send(mavlink2.MAV_TYPE_GENERIC, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        return True


def _answer_timesync(writer: _UdpWriter, rx: Any, mav: Any, t_start: float) -> None:
    """Answer TIMESYNC requests (tc1 = 0) with the device clock (ns of sensor time), as a flight controller does."""
    data = writer.poll()
    if not data:
        return
    for m in rx.parse_buffer(data) or []:
        if m.get_type() == "TIMESYNC" and m.tc1 == 0:
            mav.timesync_send(int((time.monotonic() - t_start) * 1e9), m.ts1)


def _send_gnss(mav: Any, f: Any, gps0: float = 0.0) -> None:
    """One fix as GPS_INPUT; ``gps0``: GPS time (s since the GPS epoch) at sensor time 0 (0 = no GPS time)."""
    v = f.vel_ned
    g = gps0 + f.t
    week = int(g // 604_800) if gps0 else 0
    mav.gps_input_send(
        round(f.t * 1e6),  # time_usec: the shared sensor clock
        0,  # gps_id
        0,  # ignore_flags: all fields valid
        round((g - week * 604_800) * 1000) if gps0 else 0,  # time_week_ms
        week,  # time_week
        int(f.fix_type),
        round(math.degrees(f.lat) * 1e7),
        round(math.degrees(f.lon) * 1e7),
        float(msl_height(f.lat, f.lon, f.h)),  # alt (m): MSL in the MAVLink spec (EGM96), f.h is WGS84
        0.8,
        1.2,  # hdop, vdop
        float(v[0]),
        float(v[1]),
        float(v[2]),
        float(f.std_vel),
        float(f.std_ne),
        float(f.std_d),
        int(f.num_sats),
    )


class SimDevices:
    """Start/stop the device process. ``imu_path`` is the path the serial driver opens: a stable symlink
    (in a private temporary folder) to the process's pty, so :meth:`restart` — a new process with a new
    pty whose sensor clock and sequence start again at 0, like a power-cycled IMU — is a re-plug at the
    same device path for the gateway."""

    def __init__(self, cfg: SimConfig, gnss_addr: tuple[str, int]) -> None:
        self.cfg = cfg
        self.gnss_addr = gnss_addr
        self.proc: subprocess.Popen[str] | None = None
        self.imu_path = ""
        self.pty_path = ""
        self._dir = ""

    def start(self, timeout: float = 30.0) -> str:
        args = [sys.executable, "-m", "ins_hil.sim.devices", "--gnss-udp", f"{self.gnss_addr[0]}:{self.gnss_addr[1]}"]
        for k, v in self.cfg.__dict__.items():
            args += [f"--{k.replace('_', '-')}", str(v)]
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        t0 = time.monotonic()
        line = self.proc.stdout.readline()
        if not line:
            rc = self.proc.wait(timeout=max(0.1, timeout - (time.monotonic() - t0)))
            raise RuntimeError(f"simulated devices exited (status {rc}) before announcing the IMU pty")
        self.pty_path = json.loads(line)["imu"]
        if not self._dir:
            self._dir = tempfile.mkdtemp(prefix="ins-hil-sim-")
        link = os.path.join(self._dir, "imu")
        tmp = link + ".new"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(self.pty_path, tmp)
        os.replace(tmp, link)  # atomic: the driver sees the old pty or the new one, never no path
        self.imu_path = link
        return self.imu_path

    def restart(self, timeout: float = 30.0) -> str:
        """Stop the device process and start a fresh one (sensor clocks from 0) behind the same ``imu_path``."""
        self._stop_process()
        return self.start(timeout)

    def stop(self) -> None:
        self._stop_process()
        if self._dir:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = ""

    def _stop_process(self) -> None:
        p = self.proc
        if p is None:
            return
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(timeout=3)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if p.stdout is not None:
            p.stdout.close()
        self.proc = None


def _die_with_parent() -> None:
    """Linux: get SIGTERM when the gateway process dies, even by SIGKILL (prctl PR_SET_PDEATHSIG)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def main(argv: list[str] | None = None) -> int:
    _die_with_parent()
    ap = argparse.ArgumentParser(description="simulated IMU (pty) + GNSS/baro (MAVLink over UDP)")
    ap.add_argument("--gnss-udp", required=True, help="host:port of the gateway's MAVLink input")
    for k, v in SimConfig().__dict__.items():
        ap.add_argument(f"--{k.replace('_', '-')}", type=type(v), default=v)
    a = ap.parse_args(argv)
    host, port = a.gnss_udp.rsplit(":", 1)
    cfg = SimConfig(**{k: getattr(a, k) for k in SimConfig().__dict__})
    try:
        run_devices(cfg, (host, int(port)))
    except (KeyboardInterrupt, BrokenPipeError):
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
