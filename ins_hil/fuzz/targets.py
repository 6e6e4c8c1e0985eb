"""The fuzz targets: one :class:`~ins_hil.fuzz.Target` entry each in :data:`TARGETS`.

Generators are structure-aware mutators: they start from valid frames / documents (a sensor
stream with advancing time and sequence), mutate fields or bytes and then recompute the
checksums (CRC-16 of the serial frame, DroneCAN transfer CRC and tail bytes, CRC-8 of the DBC
frames, MAVLink CRC with its CRC_EXTRA), so most inputs reach the value and time checks behind
the checksum; a share stays raw (bytes flipped after the checksum, truncations, garbage).

A harness whose decoder state can be poisoned for good by one input (a node clock pushed far
ahead) rebuilds the decoder every few hundred or thousand inputs, as a re-open would, so the
rest of the campaign still reaches the deeper checks (the poisoning itself is what the pipeline
stall count shows).

Adding a target is adding one ``Target(name, what, setup)`` entry to ``TARGETS``: ``setup(rng)``
returns a ``step()`` that makes and feeds one or a few inputs and returns ``(inputs, samples)``.
"""

from __future__ import annotations

import copy
import io
import math
import os
import random
import re
import shutil
import struct
import tempfile
import time
import tomllib
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.fuzz import Step, Target, Wrong
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

ROOT = Path(__file__).resolve().parent.parent.parent

# interesting values (float64 / float32-representable where it matters)
SPECIAL_F = [
    0.0, -0.0, 1.0, -1.0, 1e-45, 1.4e-45, 1e-300, 5e-324, 1e30, -1e30, 3.4e38, -3.4e38, 1e308, -1e308,
    math.inf, -math.inf, math.nan, 0.5, 100.0, 9.80665, 4294.967296, 2.0**31, -(2.0**31), 2.0**63,
]  # fmt: skip
SPECIAL_I = [0, 1, -1, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 2**63 - 1]


def _flip(rng: random.Random, b: bytearray, lo: int = 0, hi: int | None = None, n: int = 0) -> None:
    hi = len(b) if hi is None else hi
    if hi <= lo:
        return
    for _ in range(n or rng.choice((1, 1, 1, 2, 3, 8))):
        i = rng.randrange(lo, hi)
        r = rng.random()
        if r < 0.5:
            b[i] ^= 1 << rng.randrange(8)
        elif r < 0.8:
            b[i] = rng.choice((0x00, 0xFF, 0x7F, 0x80, 0x01))
        else:
            b[i] = rng.randrange(256)


def _splice(rng: random.Random, b: bytearray, lo: int, hi: int) -> None:
    """Overwrite an aligned 2/4/8-byte field in b[lo:hi] with an interesting value."""
    w = rng.choice((2, 4, 4, 8))
    if hi - lo < w:
        return
    off = lo + rng.randrange(0, (hi - lo - w) // w + 1) * w
    if w == 2:
        v = struct.pack("<H", rng.choice(SPECIAL_I) & 0xFFFF)
    elif w == 4:
        v = (
            struct.pack("<f", _f32(rng.choice(SPECIAL_F)))
            if rng.random() < 0.6
            else struct.pack("<I", rng.choice(SPECIAL_I) & 0xFFFFFFFF)
        )
    else:
        v = (
            struct.pack("<d", rng.choice(SPECIAL_F))
            if rng.random() < 0.6
            else struct.pack("<Q", rng.choice(SPECIAL_I) & (2**64 - 1))
        )
    b[off : off + w] = v


def _scratch() -> Path:
    """A new scratch folder for a harness's files, on the RAM file system where there is one (/dev/shm: a file
    rewritten on a disk file system can cost milliseconds of wall time an input)."""
    shm = "/dev/shm"
    ram = os.path.isdir(shm) and os.access(shm, os.W_OK)
    return Path(tempfile.mkdtemp(prefix="ins-hil-fuzz-", dir=shm if ram else None))


def _owned(step: Step, tmp: Path) -> Step:
    """``step``, its scratch folder ``tmp`` removed when the harness is dropped (a new chunk, a rebuild)."""
    weakref.finalize(step, shutil.rmtree, tmp, True)
    return step


def _f32(x: float) -> float:
    if math.isfinite(x) and abs(x) > 3.4e38:
        return math.copysign(math.inf, x)
    return x


# ------------------------------------------------------------------------------ serial frame
def _serial(rng: random.Random) -> Step:
    from ins_hil.drivers import serial_frame as sf

    parser = sf.FrameParser()
    body = sf._BODY
    st = {"seq": 0, "t": rng.randrange(2**32), "ns": 0}
    dt_us = rng.choice((1000, 2500, 5000))

    def frame() -> bytearray:
        st["seq"] = (st["seq"] + 1) & 0xFFFF
        st["t"] = (st["t"] + dt_us) & 0xFFFFFFFF
        b = body.pack(1, 0, st["seq"], st["t"], dt_us, 1e-4, -2e-4, 3e-5, 0.01, -0.002, -0.0098 * dt_us / 1000, 2150, 0)
        return bytearray(b)

    def step() -> tuple[int, list[Any]]:
        b = frame()
        r = rng.random()
        raw = False
        if r < 0.35:
            pass  # a valid frame keeps the stream going
        elif r < 0.6:
            _splice(rng, b, 0, len(b))
        elif r < 0.75:
            _flip(rng, b)
        elif r < 0.85:  # sequence / time games
            k = rng.randrange(4)
            t = struct.unpack_from("<I", b, 4)[0]
            if k == 0:
                struct.pack_into("<H", b, 2, rng.choice(SPECIAL_I) & 0xFFFF)
            elif k == 1:
                struct.pack_into("<I", b, 4, rng.choice(SPECIAL_I) & 0xFFFFFFFF)
            elif k == 2:
                struct.pack_into("<I", b, 4, (t + rng.choice((-1, 1)) * rng.randrange(1, 10**7)) & 0xFFFFFFFF)
            else:
                struct.pack_into("<H", b, 8, rng.choice((0, 1, 0xFFFF, rng.randrange(65536))))
        else:
            raw = True
        crc = struct.pack("<H", sf.crc16_ccitt(bytes(b)))
        data = bytearray(sf.SYNC + bytes(b) + crc)
        if raw:
            k = rng.randrange(3)
            if k == 0:
                _flip(rng, data)
            elif k == 1:
                data = data[: rng.randrange(len(data))]
            else:
                data = bytearray(rng.randbytes(rng.randrange(1, 60)))
        st["ns"] += 1_000_000
        return 1, parser.feed(bytes(data), st["ns"])

    return step


# ------------------------------------------------------------------------------ DroneCAN
def _dronecan(rng: random.Random) -> Step:
    from ins_hil.drivers import dronecan_codec as dc

    dec = dc.DroneCanDecoder()
    st: dict[str, Any] = {"t": 1.0, "ns": 10**9, "tid": {}}
    nodes = [10, 11, 42]
    gen_payload: list[tuple[int, Callable[[], bytes]]] = [
        (dc.DTID_RAW_IMU, lambda: dc.raw_imu_payload(
            ImuSample(st["t"], 0.005, np.array((1e-4, -2e-4, 3e-5)), np.array((0.01, -0.002, -0.049))))),
        (dc.DTID_RAW_IMU, lambda: dc.raw_imu_payload(
            ImuSample(st["t"], 0.005, np.array((1e-4, -2e-4, 3e-5)), np.array((0.01, -0.002, -0.049))))),
        (dc.DTID_FIX2, lambda: dc.fix2_payload(
            GnssFix(st["t"], 0.8, 0.2, 120.0, np.array((1.0, 2.0, 0.1)), 1.0, 2.0, 0.2), round(st["t"] * 1e6))),
        (dc.DTID_MAG2, lambda: dc.mag_payload((2e-5, 1e-6, 4e-5))),
        (dc.DTID_STATIC_PRESSURE, lambda: dc.pressure_payload(98_000.0)),
        (dc.DTID_NODE_STATUS, lambda: dc.node_status_payload(int(st["t"]))),
    ]  # fmt: skip
    cache: dict[int, bytes] = {}
    n = [0]

    def step() -> tuple[int, list[Any]]:
        n[0] += 1
        if n[0] % 500 == 0:
            dec.reopen()  # a bus re-open, as the CAN driver does it: the node clocks re-anchor, their output continues
        st["t"] += 0.005
        dtid, make = rng.choice(gen_payload)
        if dtid in cache and rng.random() < 0.95:
            payload = bytearray(cache[dtid])  # the DSDL packer is slow: reuse the template, mutate
            if dtid in (dc.DTID_RAW_IMU, dc.DTID_FIX2):  # both start with timestamp.usec (uint56)
                payload[:7] = round(st["t"] * 1e6).to_bytes(7, "little")
        else:
            payload = bytearray(make())
            cache[dtid] = bytes(payload)
        node = rng.choice(nodes)
        r = rng.random()
        if r < 0.3:
            pass
        elif r < 0.6:
            _splice(rng, payload, 0, len(payload))
        elif r < 0.75:
            _flip(rng, payload)
        elif r < 0.8:
            payload = (
                payload[: rng.randrange(len(payload) + 1)]
                if rng.random() < 0.5
                else payload + rng.randbytes(rng.randrange(1, 20))
            )
        key = (node, dtid)
        tid = (st["tid"].get(key, 0) + (1 if rng.random() < 0.9 else rng.randrange(32))) & 0x1F
        st["tid"][key] = tid
        frames = dc.split_transfer(dtid, bytes(payload), tid)
        can_id = dc.message_can_id(dtid, node)
        extended = True
        r = rng.random()
        if r < 0.08:
            fi = rng.randrange(len(frames))
            f = bytearray(frames[fi])
            _flip(rng, f)
            frames[fi] = bytes(f)
        elif r < 0.11 and len(frames) > 1:
            del frames[rng.randrange(len(frames))]
        elif r < 0.13:
            frames.insert(rng.randrange(len(frames) + 1), frames[rng.randrange(len(frames))])
        elif r < 0.15:
            can_id = rng.randrange(2**29)
        elif r < 0.16:
            extended = False
        out: list[Any] = []
        for f in frames:
            st["ns"] += rng.choice((1000, 100_000, 1_000_000))
            s = dec.feed(can_id, f, extended, st["ns"])
            if s is not None:
                out.append(s)
        return 1, out

    return step


# ------------------------------------------------------------------------------ DBC
def _dbc(rng: random.Random) -> Step:
    from ins_hil.drivers import dbc_codec as dbc

    dec = dbc.DbcImuDecoder()
    db = dec.db
    ids = [dec.gyro.frame_id, dec.accel.frame_id]
    status_id = dec.status.frame_id if dec.status is not None else 0x182
    st: dict[str, Any] = {"c": 0, "ns": 10**9, "pending": []}

    def step() -> tuple[int, list[Any]]:
        if not st["pending"]:
            st["c"] = (st["c"] + 1) & 0xFF
            st["pending"] = list(dbc.encode_imu_frames(db, (0.01, -0.02, 0.03), (0.1, 0.2, -9.8), st["c"]))
            if rng.random() < 0.02:
                b = bytearray(8)
                struct.pack_into("<hBH", b, 0, 2150, 0, 200)
                b[6] = st["c"]
                b[7] = dbc.crc8_j1850(b[:7])
                st["pending"].append((status_id, bytes(b)))
        can_id, data = st["pending"].pop(0)
        b = bytearray(data)
        r = rng.random()
        if r < 0.35:
            pass
        elif r < 0.7:
            _flip(rng, b, 0, 7)
            if rng.random() < 0.5:
                _splice(rng, b, 0, 6)
            b[7] = dbc.crc8_j1850(b[:7])
        elif r < 0.8:
            _flip(rng, b)
        elif r < 0.85:
            b = b[: rng.randrange(9)] if rng.random() < 0.5 else b + rng.randbytes(rng.randrange(1, 4))
        elif r < 0.9:
            can_id = rng.choice((*ids, status_id, rng.randrange(2**11), rng.randrange(2**29)))
        elif r < 0.95:  # counter games (pairing, duplicates, wraps)
            b[6] = rng.choice((0, 255, (b[6] + rng.randrange(256)) & 0xFF))
            b[7] = dbc.crc8_j1850(b[:7])
        st["ns"] += rng.choice((10_000, 2_500_000, 5_000_000, 10**9))
        s = dec.feed(can_id, bytes(b), st["ns"])
        return 1, [s] if s is not None else []

    return step


# ------------------------------------------------------------------------------ MAVLink
def _mavlink(rng: random.Random) -> Step:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from ins_hil.drivers.mavlink_in import MavlinkDriver

    got: list[Any] = []

    def new_driver() -> MavlinkDriver:
        d = MavlinkDriver("udpin:127.0.0.1:0")
        d._sink = got.append  # what run() attaches; feed() delivers here
        return d

    drv = new_driver()
    count = [0]
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    st = {"us": 10**6, "ns": 10**9}
    lat, lon = 473_977_000, 85_456_000

    def encoders() -> list[Any]:
        us = st["us"]
        ms = us // 1000
        return [
            lambda: mav.heartbeat_encode(1, 3, 0, 0, 4),
            lambda: mav.gps_raw_int_encode(us, 3, lat, lon, 488_000, 90, 130, 500, 9000, 12,
                                           alt_ellipsoid=536_000, h_acc=800, v_acc=1200, vel_acc=300),
            lambda: mav.gps2_raw_encode(us, 3, lat, lon, 488_000, 90, 130, 500, 9000, 12, 0, 0),
            lambda: mav.gps_input_encode(us, 0, 0, ms, 2200, 3, lat, lon, 488.0, 0.9, 1.3, 1.0, 2.0, 0.1,
                                         0.3, 0.8, 1.2, 12),
            lambda: mav.hil_gps_encode(us, 3, lat, lon, 488_000, 90, 130, 500, 100, 200, 10, 9000, 12),
            lambda: mav.scaled_pressure_encode(ms, 955.0, 0.0, 2150),
            lambda: mav.highres_imu_encode(us, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 955.0, 0.0,
                                           488.0, 21.5, 0x1FFF),
            lambda: mav.hil_sensor_encode(us, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 955.0, 0.0,
                                          488.0, 21.5, 0x1FFF),
            lambda: mav.scaled_imu_encode(ms, 10, 20, -1000, 10, 20, 30, 200, 0, 400),
            lambda: mav.raw_imu_encode(us, 10, 20, -1000, 10, 20, 30, 200, 0, 400),
            lambda: mav.timesync_encode(st["ns"] + 123_456, st["ns"] - 1_000_000),
        ]  # fmt: skip

    weights = [1, 3, 1, 3, 2, 2, 4, 2, 3, 3, 1]

    def step() -> tuple[int, list[Any]]:
        nonlocal drv
        count[0] += 1
        if count[0] % 2000 == 0:
            drv = new_driver()  # a re-open: a clock offset pushed away by junk starts afresh
        st["us"] += rng.choice((5000, 10000, 20000))
        st["ns"] += rng.choice((5_000_000, 10_000_000, 20_000_000))
        enc = rng.choices(encoders(), weights)[0]
        buf = bytearray(enc().pack(mav))
        mav.seq = (mav.seq + 1) & 0xFF  # what MAVLink.send() does after packing
        r = rng.random()
        if r < 0.3:
            pass
        elif r < 0.85:  # mutate the payload, recompute the CRC: the handlers see it
            msgid = buf[7] | buf[8] << 8 | buf[9] << 16
            n = buf[1]
            payload = bytearray(buf[10 : 10 + n])
            full = len(payload)
            cls = mavlink.mavlink_map.get(msgid)
            if cls is not None:
                full = struct.calcsize(
                    cls.native_format.decode()
                    if isinstance(cls.native_format, (bytes, bytearray))
                    else cls.native_format
                )
                payload += bytes(max(0, full - len(payload)))
            k = rng.random()
            if k < 0.6:
                _splice(rng, payload, 0, len(payload))
            elif k < 0.9:
                _flip(rng, payload)
            else:
                payload = payload[: rng.randrange(1, len(payload) + 1)]
            head = bytearray(buf[:10])
            head[1] = len(payload)
            crc = mavlink.x25crc(bytes(head[1:]) + bytes(payload))
            crc.accumulate(bytes((cls.crc_extra if cls is not None else 0,)))
            buf = head + payload + struct.pack("<H", crc.crc)
        elif r < 0.93:
            _flip(rng, buf)
        else:
            buf = buf[: rng.randrange(len(buf))] + rng.randbytes(rng.randrange(0, 30))
        got.clear()
        drv.feed(bytes(buf), st["ns"])
        return 1, list(got)

    return step


# ------------------------------------------------------------------------------ config loader
_PALETTE: list[Any] = [
    0, -1, 1, 999, 2**63, 1.5, -0.0, 1e-300, 1e300, math.inf, -math.inf, math.nan, True, False, "", "x",
    "/dev/null", "/", "udpin:", "udpout:1.2.3.4:99999", [], [True], [1.5], [0, 0], {}, {"a": 1}, "sim",
]  # fmt: skip
_TEXT_VALUES = [
    "0", "-1", "999", "1e309", "inf", "-inf", "nan", "true", '""', '"x"', "[]", "[true]", "{}", "1.5",
    '"/"', '"\\u0000"', "9223372036854775808", "[[1]]", "0x10", "1979-05-27", '"sim"',
]  # fmt: skip


def _copy_tree(d: Any) -> Any:
    """A copy of a TOML tree (its tables and arrays copied; the other values are immutable)."""
    if isinstance(d, dict):
        return {k: _copy_tree(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_copy_tree(v) for v in d]
    return d


def _mutate_tree(rng: random.Random, d: Any, depth: int = 0) -> None:
    if isinstance(d, dict) and d:
        k = rng.choice(list(d))
        r = rng.random()
        if r < 0.15:
            del d[k]
        elif r < 0.25:
            d["zz_" + str(rng.randrange(9))] = rng.choice(_PALETTE)
        elif r < 0.6 or not isinstance(d[k], dict | list) or depth > 4:
            d[k] = copy.deepcopy(rng.choice(_PALETTE))
        else:
            _mutate_tree(rng, d[k], depth + 1)
    elif isinstance(d, list) and d:
        i = rng.randrange(len(d))
        if rng.random() < 0.5 or not isinstance(d[i], dict | list):
            d[i] = copy.deepcopy(rng.choice(_PALETTE))
        else:
            _mutate_tree(rng, d[i], depth + 1)


def _config(rng: random.Random) -> Step:
    from ins_hil.config import ConfigError, from_dict, load

    seeds = [(p, p.read_text()) for p in sorted((ROOT / "configs").glob("*.toml"))]
    trees = [tomllib.loads(t) for _, t in seeds]
    tmp = _scratch()
    for f in (ROOT / "configs").glob("*.dbc"):
        (tmp / f.name).write_bytes(f.read_bytes())  # configs name their DBC relative to themselves

    def step() -> tuple[int, list[Any]]:
        i = rng.randrange(len(seeds))
        try:
            if rng.random() < 0.5:
                d = copy.deepcopy(trees[i])
                for _ in range(rng.choice((1, 1, 2, 3))):
                    _mutate_tree(rng, d)
                from_dict(d, source="<fuzz>")
            else:
                lines = seeds[i][1].splitlines()
                for _ in range(rng.choice((1, 1, 2, 4))):
                    j = rng.randrange(len(lines))
                    r = rng.random()
                    ln = lines[j]
                    if r < 0.55 and "=" in ln:
                        key = ln.split("=", 1)[0]
                        lines[j] = f"{key}= {rng.choice(_TEXT_VALUES)}"
                    elif r < 0.7:
                        del lines[j]
                    elif r < 0.8:
                        lines.insert(j, lines[rng.randrange(len(lines))])
                    elif r < 0.9:
                        lines.insert(j, f"zz{rng.randrange(9)} = {rng.choice(_TEXT_VALUES)}")
                    else:
                        b = bytearray(ln.encode())
                        _flip(rng, b) if b else None
                        lines[j] = b.decode("latin-1")
                raw = bytearray("\n".join(lines).encode())
                if rng.random() < 0.1:
                    _flip(rng, raw)
                p = tmp / "fuzz.toml"
                p.write_bytes(bytes(raw))
                load(p)
        except ConfigError:
            pass
        return 1, []

    return _owned(step, tmp)


# ------------------------------------------------------------------------------ recorder reader
def _key(s: Any) -> tuple[Any, ...]:
    vals: list[Any] = [type(s).__name__]
    for f in s.__slots__:
        v = getattr(s, f)
        if isinstance(v, np.ndarray):
            v = tuple(float(x).hex() for x in v)
        elif isinstance(v, float):
            v = v.hex()
        vals.append(v)
    return tuple(vals)


def _recorder(rng: random.Random) -> Step:
    from ins_hil.runtime import recorder as rec

    tmp = _scratch()
    src: list[Any] = []
    for k in range(60):
        t = 0.005 * k
        src.append(ImuSample(t, 0.005, np.array((1e-4, 2e-4, 3e-4)) * k, np.array((0.01, 0.0, -0.049)), 0, k, 21.0))
        if k % 10 == 0:
            src.append(GnssFix(t, 0.8, 0.2, 100.0 + k, np.array((1.0, 2.0, 0.1)), 1.0, 2.0, 0.3, FixType.FIX_3D, 9))
        if k % 10 == 5:
            src.append(BaroSample(t, 98_000.0 + k, 100.0, 21.0))
            src.append(MagSample(t, np.array((2e-5, 1e-6, 4e-5))))
    r = rec.Recorder(tmp / "seed.ihlog", header={"pipeline": {}})
    for s in src:
        r.write(s)
    r.close()
    seed = (tmp / "seed.ihlog").read_bytes()
    keys = [_key(s) for s in src]
    keyset = set(keys)
    hdr = b'{"pipeline": {}, "session": "v1", "part": 0}'
    v1 = (
        rec.MAGIC_V1
        + struct.pack("<I", len(hdr))
        + hdr
        + b"".join(rec.encode_record(s)[2:3] + rec.encode_record(s)[4:-4] for s in src)
    )
    path = tmp / "fuzz.ihlog"

    def step() -> tuple[int, list[Any]]:
        old = rng.random() < 0.1
        b = bytearray(v1 if old else seed)
        r = rng.random()
        if r < 0.55:
            _flip(rng, b, n=rng.choice((1, 1, 1, 2, 4)))
        elif r < 0.7:
            del b[rng.randrange(len(b)) :]
        elif r < 0.8:
            i = rng.randrange(len(b))
            b[i:i] = rng.randbytes(rng.randrange(1, 100))
        elif r < 0.9:
            i, j = sorted((rng.randrange(len(b)), rng.randrange(len(b))))
            b[i:j] = bytes(j - i)
        else:
            i, n = rng.randrange(len(b)), rng.randrange(1, 200)
            j = rng.randrange(len(b))
            b[j:j] = b[i : i + n]  # a stretch copied elsewhere (not frame-aligned in general)
        path.write_bytes(bytes(b))
        out: list[Any] = []
        for skip in (False, True):
            got = []
            try:
                for x in rec.read_records(path, skip_damaged=skip):
                    got.append(_key(x))
            except rec.RecordError:
                pass
            if old:
                continue  # format 1 has no CRC: only escaped exceptions are checked
            if not skip and got != keys[: len(got)]:
                out.append(Wrong("strict read returned records that were not recorded"))
            if skip and not set(got) <= keyset:
                out.append(Wrong("skip_damaged read returned records that were not recorded"))
        return 1, out

    return _owned(step, tmp)


# ------------------------------------------------------------------------------ dataset readers and configs
#: ../shared/data beside the clone: the shipped logs whose beginnings seed the reader targets (read, never copied
#: into the repository); without it the synthetic seeds made here are used alone
SHARED_DATA = ROOT.parent / "shared" / "data"
#: a binary seed's message spans (offset, length) and the bytes of a message before its time field
SPANS: dict[bytes, tuple[list[tuple[int, int]], int]] = {}
#: text lines of each shipped text file kept as a seed
SEED_LINES = 300
#: at most this share of a reader target's time replays accepted inputs (prepare, the core, the scores and the
#: summary); the rest only reads
REPLAY_SHARE = 0.2
_TEXT_CELLS = ["nan", "inf", "-inf", "1e308", "-1e308", "0", "-1", "", "3600000000", "x", "1e-300", "9" * 30, "0x10"]


def _text_mutate(rng: random.Random, b: bytes) -> bytes:
    """A CSV-like text mutated: a cell replaced by a special value, a cell or column dropped or added, a line
    duplicated, moved or deleted, a time jumped by an hour, CRLF, non-UTF-8 bytes."""
    lines = b.split(b"\n")
    if len(lines) < 3:
        return b
    for _ in range(rng.choice((1, 1, 2, 3))):
        j = rng.randrange(len(lines))
        cells = lines[j].split(b",")
        r = rng.random()
        if r < 0.35 and len(cells) > 1:
            cells[rng.randrange(len(cells))] = rng.choice(_TEXT_CELLS).encode()
        elif r < 0.45:
            del cells[rng.randrange(len(cells))]
        elif r < 0.5:
            cells.insert(rng.randrange(len(cells) + 1), b"1.5")
        elif r < 0.6:
            lines.insert(rng.randrange(len(lines)), lines[j])
        elif r < 0.68:
            lines.insert(rng.randrange(len(lines)), lines.pop(j))
        elif r < 0.75:
            del lines[j]
            continue
        elif r < 0.85 and len(cells) > 1:  # the time (2nd cell of a generic record, 1st of a topic row) far off
            k = 1 if cells[0].isalpha() else 0
            try:
                cells[k] = repr(float(cells[k]) + rng.choice((3600.0, 3.6e9, -3600.0, 1e-3))).encode()
            except ValueError:
                pass
        elif r < 0.92:
            lines = [ln + b"\r" for ln in lines]
            break
        else:
            cells[rng.randrange(len(cells))] += bytes((0xFF, 0xFE, 0xC3))
        lines[j] = b",".join(cells)
    return b"\n".join(lines)


def _bytes_mutate(rng: random.Random, b: bytes) -> bytes:
    """Bytes mutated: flips, a truncation, an inserted / zeroed / duplicated block, an interesting value."""
    out = bytearray(b)
    r = rng.random()
    if r < 0.4:
        _flip(rng, out, n=rng.choice((1, 1, 2, 4, 16)))
    elif r < 0.5:
        del out[rng.randrange(len(out) + 1) :]
    elif r < 0.6:
        i = rng.randrange(len(out) + 1)
        out[i:i] = rng.randbytes(rng.randrange(1, 200))
    elif r < 0.7:
        i, j = sorted((rng.randrange(len(out) + 1), rng.randrange(len(out) + 1)))
        out[i : min(j, i + 4096)] = bytes(min(j, i + 4096) - i)
    elif r < 0.8:
        i, n = rng.randrange(len(out) + 1), rng.randrange(1, 2000)
        j = rng.randrange(len(out) + 1)
        out[j:j] = out[i : i + n]
    else:
        for _ in range(rng.choice((1, 2, 4))):
            _splice(rng, out, 0, len(out))
    return bytes(out)


#: records of the IMU topic kept in a seed cut from a shipped binary log (the others: those of the same span); the
#: inputs a reader target replays are cut from these seeds (the DataFlash one is long enough for the core to navigate)
SEED_RECORDS = 200
#: IMU records (binary logs) or lines (text logs) of the short seeds most inputs of a reader target are cut from: every
#: kind of record and the file's definitions as in the long seed, a fifth of the records (a fifth of the reading)
SHORT_RECORDS = 40
#: ms after the drive's IMU start where its RTKLIB seed begins: a second before the car's speed passes 1 m/s
RTKLIB_SEED_MS = 35_000
#: parameters kept in a ULog seed (the reader keeps EKF2_, SENS_ and CAL_MAG ones in the dataset's meta)
SEED_PARAMS = 12
#: GNSS records a ULog seed keeps at least (the other topics go on after the IMU's records until then)
SEED_FIXES = 5
#: where in the shipped log the kept span starts (a share of its bytes: in flight, the GNSS fixed)
SEED_FROM = 0.4
_ULOG_BASE = {"int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t", "int64_t", "uint64_t", "float",
              "double", "bool", "char"}  # fmt: skip


def _ulog_records(b: bytes, start: int = 16) -> list[tuple[int, int, str]]:
    """The messages of a ULog from ``start``: (offset, length with the 3-byte header, type letter)."""
    out = []
    off = start
    while off + 3 <= len(b):
        size, typ = struct.unpack_from("<HB", b, off)
        if off + 3 + size > len(b):
            break
        out.append((off, 3 + size, chr(typ)))
        off += 3 + size
    return out


_ULOG_SIZE = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i", "uint32_t": "I",
              "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?", "char": "c"}  # fmt: skip
#: a 3-D fix written into a ULog seed's GNSS records (the shipped hover log never had one)
_ULOG_FIX = {"latitude_deg": 47.397742, "longitude_deg": 8.545594, "altitude_ellipsoid_m": 535.0,
             "altitude_msl_m": 488.0, "fix_type": 3, "satellites_used": 10, "eph": 1.0, "epv": 2.0,
             "s_variance_m_s": 0.3, "vel_ned_valid": True}  # fmt: skip


def _ulog_fields(fmt: bytes) -> dict[str, tuple[int, str]]:
    """Field name → (byte offset in a data record's payload, struct character) of a flat ULog format body
    (``name:type field;…``); the fields after the first nested type are left out."""
    out: dict[str, tuple[int, str]] = {}
    off = 0
    for f in fmt.split(b":", 1)[1].decode("latin-1").split(";"):
        if not f:
            continue
        typ, name = f.split(" ", 1)
        base, _, count = typ.partition("[")
        ch = _ULOG_SIZE.get(base)
        if ch is None:
            break
        n = int(count.rstrip("]")) if count else 1
        out[name] = (off, ch)
        off += struct.calcsize("<" + ch) * n
    return out


def ulog_seed(b: bytes, records: int = SEED_RECORDS, start: float = SEED_FROM) -> tuple[bytes, list[tuple[int, int]]]:
    """A small valid ULog cut from ``b`` (a whole log): the header, the flag bits (no appended data), the formats of
    the topics the reader reads (:func:`ins_hil.datasets.px4.all_topics`, nested types included), ``SEED_PARAMS``
    EKF2_ parameters, their subscriptions, and their data from ``start`` (a share of the file) on until ``records``
    ``sensor_combined`` records and ``SEED_FIXES`` GNSS records (a 3-D fix written into them: ``_ULOG_FIX``).
    Returns it and its message spans (offset, length) for the record mutations."""
    from ins_hil.datasets.px4 import all_topics

    TOPICS = all_topics()
    recs = _ulog_records(b)
    formats: dict[str, bytes] = {}
    for off, n, t in recs:
        if t == "F":
            body = b[off + 3 : off + n]
            formats[body.split(b":", 1)[0].decode("latin-1")] = b[off : off + n]
    need: set[str] = set()
    todo = [t for t in TOPICS if t in formats]
    while todo:
        name = todo.pop()
        if name in need or name not in formats:
            continue
        need.add(name)
        for field in formats[name][3:].split(b":", 1)[1].split(b";"):
            typ = field.split(b" ", 1)[0].split(b"[", 1)[0].decode("latin-1")
            if typ and typ not in _ULOG_BASE:
                todo.append(typ)
    out = bytearray(b[:16])
    spans: list[tuple[int, int]] = []
    ids: dict[int, str] = {}
    n_imu = params = n_gps = 0
    cut = int(start * len(b))
    for off, n, t in recs:
        keep = b""
        if t == "B":
            keep = b[off : off + 11] + bytes(n - 11)  # compat flags kept; incompat flags and appended offsets 0
        elif t == "F" and b[off + 3 : off + n].split(b":", 1)[0].decode("latin-1") in need:
            keep = b[off : off + n]
        elif t == "P" and not ids and params < SEED_PARAMS and b"EKF2_" in b[off : off + n]:
            keep = b[off : off + n]
            params += 1
        elif t == "A":
            name = b[off + 6 : off + n].decode("latin-1")
            if name in TOPICS:
                ids[struct.unpack_from("<H", b, off + 4)[0]] = name
                keep = b[off : off + n]
        elif t == "D" and off >= cut:
            name = ids.get(struct.unpack_from("<H", b, off + 3)[0], "")
            if name and not (name == "sensor_combined" and n_imu >= records):
                keep = b[off : off + n]
                if name in ("vehicle_gps_position", "sensor_gps"):  # a 3-D fix where the log had none
                    rec = bytearray(keep)
                    for fname, (k, ch) in _ulog_fields(formats[name][3:]).items():
                        if fname in _ULOG_FIX:
                            struct.pack_into("<" + ch, rec, 5 + k, _ULOG_FIX[fname])
                    keep = bytes(rec)
                n_imu += name == "sensor_combined"
                n_gps += name in ("vehicle_gps_position", "sensor_gps")
        if keep:
            spans.append((len(out), len(keep)))
            out += keep
        if n_imu >= records and n_gps >= SEED_FIXES:
            break
    return bytes(out), spans


def _df_records(b: bytes) -> list[tuple[int, int, str]]:
    """The messages of a DataFlash .bin: (offset, length, name); damaged stretches are skipped."""
    from ins_hil.datasets.dataflash import FMT_ID, FMT_LEN

    lens, names = {FMT_ID: FMT_LEN}, {FMT_ID: "FMT"}
    out = []
    off = 0
    while off + 3 <= len(b):
        if b[off] != 0xA3 or b[off + 1] != 0x95 or b[off + 2] not in lens:
            off += 1
            continue
        n = lens[b[off + 2]]
        if off + n > len(b) or n < 3:
            break
        if b[off + 2] == FMT_ID:
            lens[b[off + 3]] = b[off + 4]
            names[b[off + 3]] = b[off + 5 : off + 9].split(b"\0", 1)[0].decode("latin-1")
        out.append((off, n, names[b[off + 2]]))
        off += n
    return out


def dataflash_seed(
    b: bytes, records: int = SEED_RECORDS, start: float = SEED_FROM
) -> tuple[bytes, list[tuple[int, int]]]:
    """A small valid DataFlash .bin cut from ``b`` (a whole log): the FMT definitions of what it keeps, the first
    ORGN and firmware MSG, and the messages the reader reads (:func:`ins_hil.datasets.dataflash.all_fields`) and PARM
    from ``start`` (a share of the file) on until ``records`` IMU messages. Returns it and its message spans."""
    from ins_hil.datasets.dataflash import all_fields

    FIELDS = all_fields()
    out = bytearray()
    spans: list[tuple[int, int]] = []
    cut = int(start * len(b))
    n_imu = 0
    seen: set[str] = set()
    recs = _df_records(b)
    for off, n, name in recs:
        if name == "FMT":  # the definitions of the messages kept (and of FMT)
            defined = b[off + 5 : off + 9].split(b"\0", 1)[0].decode("latin-1")
            if defined in FIELDS or defined in ("FMT", "PARM"):
                spans.append((len(out), n))
                out += b[off : off + n]
    for off, n, name in recs:
        first = name in ("ORGN", "MSG") and name not in seen
        if first or (off >= cut and (name in FIELDS or name == "PARM")):
            seen.add(name)
            spans.append((len(out), n))
            out += b[off : off + n]
            n_imu += name == "IMU"
        if n_imu >= records:
            break
    return bytes(out), spans


def _record_mutate(rng: random.Random, b: bytes, spans: list[tuple[int, int]], head: int) -> bytes:
    """A binary log mutated record-wise (``spans``: (offset, length) of its messages; ``head``: the bytes of a
    message header): a message deleted, duplicated, moved or cut short, its time field (the first 8 bytes after
    the header) set to an interesting value or moved by an hour, a field of its body spliced, or its header
    bytes damaged; the log cut at a message boundary."""
    if not spans:
        return _bytes_mutate(rng, b)
    out = bytearray(b)
    for _ in range(rng.choice((1, 1, 2, 3))):
        off, n = spans[rng.randrange(len(spans))]
        if off + n > len(out):
            continue
        r = rng.random()
        if r < 0.15:
            del out[off : off + n]
            break  # the spans after it moved
        elif r < 0.3:
            out[off:off] = out[off : off + n]
            break
        elif r < 0.4:
            j = spans[rng.randrange(len(spans))][0]
            rec = out[off : off + n]
            del out[off : off + n]
            j = min(j, len(out))
            out[j:j] = rec
            break
        elif r < 0.55 and n >= head + 8:
            t = struct.unpack_from("<Q", out, off + head)[0]
            v = rng.choice([0, 1, 2**63 - 1, 2**64 - 1, t + 3_600_000_000, max(t - 3_600_000_000, 0), t - 1 if t else 0,
                            t + 1, 2**32])  # fmt: skip
            struct.pack_into("<Q", out, off + head, v & (2**64 - 1))
        elif r < 0.8:
            _splice(rng, out, off + head, off + n)
        elif r < 0.9:
            _flip(rng, out, off, off + head)
        else:
            del out[off + rng.randrange(n) :]
            break
    return bytes(out)


def _synthetic_dataset(seconds: float = 3.0) -> Any:
    """A small vehicle at rest: IMU 100 Hz, GNSS 5 Hz, baro and magnetometer 10 Hz (a seed and the config
    target's data)."""
    from ins_hil.datasets.dataset import Dataset

    n = int(seconds * 100)
    imu = [ImuSample(0.01 * k, 0.01, np.array((1e-6, -2e-6, 3e-6)), np.array((0.001, -0.002, -0.0980))) for k in
           range(1, n + 1)]  # fmt: skip
    gnss = [GnssFix(0.2 * k, 0.8, 0.2, 300.0, np.array((0.0, 0.0, 0.0)), 1.0, 2.0, 0.2, FixType.FIX_3D, 9) for k in
            range(int(seconds * 5))]  # fmt: skip
    baro = [BaroSample(0.1 * k, 97_000.0, 300.0) for k in range(int(seconds * 10))]
    mag = [MagSample(0.1 * k, np.array((2e-5, 1e-6, 4e-5))) for k in range(int(seconds * 10))]
    return Dataset(imu, gnss, baro, mag, events=[(0.5, "takeoff")],
                   meta={"source": "<fuzz>", "format": "csv", "utc_start_s": 1.7e9})  # fmt: skip


def _px4_mag(t0_us: int, seconds: float) -> bytes:
    """A ulog2csv ``vehicle_magnetometer_0.csv`` of ``seconds`` from ``t0_us`` (µs) at 10 Hz: a field of 0.5 G at
    yaw 0 and level (``REPLAY_MAG_NED`` in gauss)."""
    g = [v * 1e4 for v in REPLAY_MAG_NED]
    rows = [f"{t0_us + 100_000 * k},{g[0]:.4f},{g[1]:.4f},{g[2]:.4f}" for k in range(int(seconds * 10))]
    return ("\n".join(["timestamp,magnetometer_ga[0],magnetometer_ga[1],magnetometer_ga[2]", *rows]) + "\n").encode()


def _head_lines(p: Path, n: int = SEED_LINES) -> bytes:
    with p.open("rb") as f:
        return b"".join(f.readline() for _ in range(n))


def _reader_seeds(fmt: str, tmp: Path, short: bool = False) -> list[dict[str, bytes]]:
    """Seeds of a reader: {relative file name: bytes} (a folder format has several files); the beginnings of
    the shipped logs where ../shared/data has them, and a synthetic one where the format allows. ``short``: the same
    cuts with ``SHORT_RECORDS`` IMU records or lines (a text file's lines, a synthetic log's IMU samples) instead of
    ``SEED_RECORDS`` / ``SEED_LINES`` / 3 s at 100 Hz."""
    from ins_hil.datasets import generic_csv, rtklib

    seeds: list[dict[str, bytes]] = []
    d = SHARED_DATA
    records = SHORT_RECORDS if short else SEED_RECORDS
    lines = SHORT_RECORDS if short else SEED_LINES
    if fmt == "csv":
        p = tmp / "seed.csv"
        generic_csv.write_generic_csv(p, _synthetic_dataset(SHORT_RECORDS / 100 if short else 3.0))
        seeds.append({"d.csv": p.read_bytes()})
    elif fmt == "px4-ulog" and (d / "uav/px4_hover_92s/hover.ulg").is_file():
        b, spans = ulog_seed((d / "uav/px4_hover_92s/hover.ulg").read_bytes(), records)
        SPANS[b] = (spans, 5)  # a data message: header, msg_id, then its timestamp
        seeds.append({"d.ulg": b})
    elif fmt == "px4-csv":
        q = d / "uav/px4_quad_157s"
        if q.is_dir():
            seeds.append({f.name: _head_lines(f, lines) for f in sorted(q.glob("*.csv"))})
            # the folder has no magnetometer: one written for the replay's alignment (REPLAY_MAG_NED)
            t0 = int(seeds[-1]["sensor_combined_0.csv"].split(b"\n")[1].split(b",")[0])
            seeds[-1]["vehicle_magnetometer_0.csv"] = _px4_mag(t0, 2.0)
        cols = ["timestamp", "gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]", "gyro_integral_dt", "accelerometer_m_s2[0]",
                "accelerometer_m_s2[1]", "accelerometer_m_s2[2]", "accelerometer_integral_dt"]  # fmt: skip
        rows = [f"{1_000_000 + 4000 * k},0.01,0,0,4000,0.1,0,-9.8,4000" for k in range(lines)]
        gps = ["timestamp,lat,lon,alt,fix_type,eph,epv,s_variance_m_s,vel_n_m_s,vel_e_m_s,vel_d_m_s,satellites_used"]
        gps += [f"{1_000_000 + 200_000 * k},470000000,80000000,400000,3,1.0,2.0,0.3,0,0,0,9" for k in range(6)]
        seeds.append({"sensor_combined_0.csv": ("\n".join([",".join(cols), *rows]) + "\n").encode(),
                      "vehicle_gps_position_0.csv": ("\n".join(gps) + "\n").encode()})  # fmt: skip
        seeds[-1]["vehicle_magnetometer_0.csv"] = _px4_mag(1_000_000, 2.0)
    elif fmt in ("ardupilot-bin", "ardupilot-log") and (d / "uav/ardupilot_copter_150s/flight.bin").is_file():
        head, spans = dataflash_seed((d / "uav/ardupilot_copter_150s/flight.bin").read_bytes(), records)
        SPANS[head] = (spans, 3)  # a message: header, then TimeUS
        if fmt == "ardupilot-bin":
            seeds.append({"d.bin": head})
        else:
            from pymavlink import DFReader

            p = tmp / "seed.bin"
            p.write_bytes(head)
            r = DFReader.DFReader_binary(str(p), zero_time_base=True)
            out = [f"FMT, {fm.type}, {fm.len}, {fm.name}, {fm.format}, {','.join(fm.columns)}"
                   for fm in {fm.name: fm for fm in r.formats.values()}.values()]  # fmt: skip
            while (m := r.recv_match(type=["IMU", "GPS", "GPA", "BARO", "MAG", "NKF1", "XKF1", "MSG"])) is not None:
                out.append(", ".join([m.get_type()] + [str(getattr(m, c)) for c in m.fmt.columns]))
            seeds.append({"d.log": ("\n".join(out) + "\n").encode()})
    elif fmt == "rtklib" and (d / "gnss_imu_drive_0708/imu_1934.csv").is_file():
        # the window where the car drives off (its speed passes 1 m/s 36 s after the IMU's start): the replay's
        # core levels in motion and takes its yaw from the GNSS course, so the seed navigates (the log's head is
        # at rest, and RTKLIB files have no magnetometer); the time tags' byte offsets rebased to the window
        g = d / "gnss_imu_drive_0708"
        whole = (g / "imu_1934.csv").read_bytes()
        tag = (g / "imu_1934.csv.tag").read_bytes()
        tags = np.frombuffer(tag[76 : 76 + 8 * ((len(tag) - 76) // 8)], dtype="<u4").reshape(-1, 2).astype(np.int64)
        b0 = int(tags[np.searchsorted(tags[:, 0], RTKLIB_SEED_MS), 1])
        b0 = whole.rfind(b"\n", 0, b0) + 1
        rest = io.BytesIO(whole[b0:])
        imu = b"".join(rest.readline() for _ in range(lines))
        keep = tags[(tags[:, 1] >= b0) & (tags[:, 1] < b0 + len(imu))] - np.array([0, b0])
        last = np.array([[keep[-1, 0] + 10 if len(keep) else 0, len(imu)]])
        tag = tag[:76] + np.vstack([keep, last]).astype("<u4").tobytes()
        tt = rtklib.read_timetag(g / "imu_1934.csv.tag")
        t_win = tt.start + tt.frac + (keep[0, 0] if len(keep) else RTKLIB_SEED_MS) / 1000.0
        pos_lines = (g / "gnss_1934_sf.pos").read_bytes().splitlines(keepends=True)
        pos_head = [ln for ln in pos_lines if ln.startswith(b"%")]
        pos_body = [ln for ln in pos_lines if not ln.startswith(b"%")]
        k0 = int(np.searchsorted(rtklib.read_pos(g / "gnss_1934_sf.pos").t, t_win - 1.0))  # a second before it
        pos = b"".join(pos_head + pos_body[k0 : k0 + (10 if short else 60)])
        seeds.append({"imu.csv": imu, "imu.csv.tag": tag, "sol.pos": pos})
    elif fmt == "ihlog":
        from ins_hil.runtime import recorder as rec

        ds = _synthetic_dataset(SHORT_RECORDS / 100 if short else 1.0)
        r = rec.Recorder(tmp / "seed.ihlog", header={"pipeline": {}})
        for x in sorted([*ds.imu, *ds.gnss, *ds.baro, *ds.mag], key=lambda x: x.t):
            r.write(x)
        r.close()
        seeds.append({"d.ihlog": (tmp / "seed.ihlog").read_bytes()})
    return seeds


_SEEDS: dict[tuple[str, bool], list[dict[str, bytes]]] = {}


def reader_seeds(fmt: str, short: bool = False) -> list[dict[str, bytes]]:
    """:func:`_reader_seeds`, cut once per process (a harness rebuilt every chunk reuses them; their record spans stay
    in ``SPANS``)."""
    key = (fmt, short)
    if key not in _SEEDS:
        tmp = _scratch()
        try:
            _SEEDS[key] = _reader_seeds(fmt, tmp, short)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return list(_SEEDS[key])


_WARMED: set[Any] = set()


def _warm(key: Any, run: Callable[[], Any]) -> None:
    """Run ``run`` once per process and ``key`` in a harness's setup (outside the campaign's measured time): the
    imports and first-call costs of the reader and the replay (pyulog, scipy's chi-square quantiles, ...) that
    would otherwise land on the first chunk's first inputs."""
    if key not in _WARMED:
        _WARMED.add(key)
        try:
            run()
        except Exception:  # a warm-up only: the inputs find what fails
            pass


def _replay_check(ds: Any, cfg: Any) -> list[Any]:
    """Replay ``ds`` with ``cfg`` through the dataset replay (prepare, the core, the scores) and its summary:
    ``Replayed`` (whether the core navigated) when it gives finite figures, [] when it refuses the data in one line
    (ReplayError), a ``Wrong`` for a NaN printed as a figure, non-finite states or a pipeline error."""
    from ins_hil.datasets import report
    from ins_hil.datasets.run import ReplayError
    from ins_hil.fuzz import Replayed

    try:
        m, _ = report.replay(ds, cfg)
    except ReplayError as e:
        # the clean refusals of bad data; but what passed the validation boundary must never give the core a
        # non-finite state or raise in the pipeline: those are findings (the replay refuses them in one line)
        why = str(e)
        if "non-finite navigation states" in why or "a pipeline error" in why:
            return [Replayed(True), Wrong(f"a replay of validated samples: {why[-200:]}")]
        return []
    done: list[Any] = [Replayed(m.get("t_nav_s") is not None)]
    text = report.format_table(report.summary(m)).lower()
    if "nan" in text.replace("not scored", "").replace("nanos", ""):
        return [*done, Wrong(f"a NaN printed as a figure: {text[:300]!r}")]
    return done


#: T: the Earth field (NED) the reader targets' replays take as the magnetometer reference (a mid-latitude field;
#: any field gives the refined alignment a yaw, so a seed with a magnetometer navigates without motion)
REPLAY_MAG_NED = [2.0e-5, 0.0, 4.4e-5]


def replay_config() -> Any:
    """The dataset config the reader targets replay their accepted inputs with: a quick static alignment (0.5 s
    levelling after 0.2 s at rest, yaw from the magnetometer against ``REPLAY_MAG_NED``), so the seeds' cores
    navigate within their second of data (the default 2 s + 1.5 s would outlast every seed but the DataFlash one)."""
    from ins_hil.datasets.config import DatasetConfig

    return DatasetConfig(name="fuzz", rtklib={}, nav={"alignment": {"time": 0.5, "still_delay": 0.2},
                                                      "mag": {"ref_ned": list(REPLAY_MAG_NED)}})  # fmt: skip


#: the reader formats whose input is a folder, and those that are text
FOLDERS = ("px4-csv", "rtklib")
TEXTS = ("csv", "px4-csv", "ardupilot-log", "rtklib")


def _mutated(
    rng: random.Random, seed: dict[str, bytes], fmt: str, root: Path, plain: dict[str, bytes] | None = None
) -> Path:
    """One file of ``seed`` mutated (text formats cell- and line-wise or as bytes, binary logs record-wise or as
    bytes; a folder format's file sometimes missing), written to the emptied folder ``root``; returns the path
    the reader is given (``root`` for a folder format). ``plain``: that seed written as it is instead."""
    if root.exists():
        for f in root.iterdir():
            f.unlink()
    root.mkdir(exist_ok=True)
    if plain is not None:
        for name, b in plain.items():
            (root / name).write_bytes(b)
        return root if fmt in FOLDERS else root / next(iter(plain))
    names = list(seed)
    victim = rng.choice(names)
    for name, b in seed.items():
        if name == victim:
            if fmt in TEXTS and not name.endswith(".tag") and rng.random() < 0.6:
                b = _text_mutate(rng, b)
            elif b in SPANS and rng.random() < 0.6:
                b = _record_mutate(rng, b, *SPANS[b])
            else:
                b = _bytes_mutate(rng, b)
        (root / name).write_bytes(b)
    if fmt in FOLDERS and rng.random() < 0.05:  # a file of the folder missing
        (root / rng.choice(names)).unlink()
    return root if fmt in FOLDERS else root / names[0]


def _reader(fmt: str) -> Callable[[random.Random], Step]:
    """A reader target: a seed of ``fmt`` mutated (bytes; text formats also cell- and line-wise), read with the
    reader; a DatasetError is the clean refusal, anything else raised escapes. The samples it yields go through
    the replay's validation boundary (:func:`ins_hil.datasets.run.screen`); every sample it passes is checked against
    the campaign's physical ranges (:func:`ins_hil.fuzz.suspects`, the doubtful ones returned for the campaign's
    oracle). Accepted inputs are replayed (:func:`_replay_check`) in up to ``REPLAY_SHARE`` of the time: while the
    replays are within it the next input is cut from the long seed (``SEED_RECORDS``: the DataFlash seed's core
    navigates) and replayed if accepted, otherwise from the short one (``SHORT_RECORDS``) and not replayed."""

    def setup(rng: random.Random) -> Step:
        from ins_hil.datasets.dataset import DatasetError, read_dataset
        from ins_hil.datasets.run import ReplayError, screen
        from ins_hil.fuzz import Checked, suspects

        tmp = _scratch()
        seeds = reader_seeds(fmt)
        if not seeds:
            raise RuntimeError(f"{fmt}: no seed ({SHARED_DATA} missing)")
        short = reader_seeds(fmt, short=True)
        _warm(("reader", fmt), lambda: _replay_check(read_dataset(_mutated(rng, {}, fmt, tmp / "in", seeds[0]), fmt),
                                                     replay_config()))  # fmt: skip
        clock = [time.perf_counter(), 0.0]  # the start, the seconds spent replaying
        cfg = replay_config()

        def step() -> tuple[int, list[Any]]:
            t0 = time.perf_counter()
            replay = clock[1] <= REPLAY_SHARE * (t0 - clock[0])
            path = _mutated(rng, rng.choice(seeds if replay else short), fmt, tmp / "in")
            try:
                ds = read_dataset(path, fmt)
            except DatasetError:
                return 1, []
            try:
                sc = screen(ds.imu, ds.gnss, [*ds.baro, *ds.mag], str(path))
            except ReplayError:
                return 1, []
            # (a baro sample of a log carries its altitude alone: the campaign's oracle wants a pressure)
            checked = [*sc.imu, *sc.gnss, *[m for m in sc.aux if m.kind == "mag"]]
            out: list[Any] = suspects(checked)
            out.append(Checked(len(checked) - len(out)))
            if replay:
                now = time.perf_counter()
                out += _replay_check(ds, cfg)
                clock[1] += time.perf_counter() - now
            return 1, out

        return _owned(step, tmp)

    return setup


#: the formats whose mutated seeds the replay targets run through ``ins-hil replay``
REPLAY_FORMATS = ("csv", "px4-ulog", "px4-csv", "ardupilot-bin", "ardupilot-log", "rtklib", "ihlog")
#: the replay's guarantee on a corrupted log: it ends within this (s) and under this address space (MiB)
REPLAY_SECONDS = 60.0
REPLAY_MIB = 1024
_NUMBER_NAN = re.compile(r"(?<![a-z_])(nan|[+-]?inf)(?![a-z_])")


def replay_oracle(rc: int, out: str, err: str, path: Path) -> list[Any]:
    """The guarantee of ``ins-hil replay`` on a corrupted log, checked on one run: exit 0 with no NaN or inf
    printed as a figure, or exit ≠ 0 with one line on stderr that names ``path`` and is a foreseen refusal (not
    "the replay failed (KeyError…)", not an escaped exception's type). [] when kept, else one ``Wrong``."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if rc == 0:
        m = _NUMBER_NAN.search(out.lower().replace("not scored", ""))
        return [Wrong(f"exit 0 with a non-finite figure {m.group(0)!r}: {out[:300]!r}")] if m else []
    if len(lines) != 1:
        return [Wrong(f"exit {rc} with {len(lines)} lines on stderr: {err[:300]!r}")]
    if str(path) not in lines[0]:
        return [Wrong(f"exit {rc}, its line does not name the file: {lines[0][:300]!r}")]
    if "the replay failed (" in lines[0] or "--debug for the traceback" in lines[0]:
        return [Wrong(f"exit {rc}, an unforeseen failure: {lines[0][:300]!r}")]
    return []


def _replay_seeds(tmp: Path) -> list[tuple[str, dict[str, bytes]]]:
    seeds = [(fmt, s) for fmt in REPLAY_FORMATS for s in reader_seeds(fmt)]
    if not seeds:
        raise RuntimeError(f"replay: no seed ({SHARED_DATA} missing)")
    return seeds


def _replay_dataset(rng: random.Random) -> Step:
    """What ``ins-hil replay LOG`` runs, in process: :func:`ins_hil.datasets.report.replay_to_dir` (read, replay,
    metrics, the summary text; no plots) on a mutated seed of every reader format. The command prints the text
    and exits 0, or maps DatasetError / DatasetConfigError / ValueError (exit 2) and ReplayError (exit 1) to one
    line; anything else is its "the replay failed (…)". So: a return is checked for a NaN or inf figure, those
    refusals for one line naming the file (:func:`replay_oracle`), anything else escapes. (The fuzz layer may not
    import the command line; :func:`_replay_process` runs the command itself.)"""
    from ins_hil.datasets import ihlog, report
    from ins_hil.datasets.run import ReplayError
    from ins_hil.evaluation.sim_flight import sim_truth

    ihlog.set_truth_source(sim_truth)  # as the command does: a simulated gateway log against its truth
    tmp = _scratch()
    seeds = _replay_seeds(tmp)

    def step() -> tuple[int, list[Any]]:
        fmt, seed = rng.choice(seeds)
        path = _mutated(rng, seed, fmt, tmp / "in")
        try:
            _, text = report.replay_to_dir(path, None, tmp / "out", plots=False)
        except ReplayError as e:
            return 1, replay_oracle(1, "", f"ins-hil replay: {e}", path)
        except ValueError as e:  # DatasetError, DatasetConfigError
            return 1, replay_oracle(2, "", f"ins-hil replay: {e}", path)
        return 1, replay_oracle(0, text, "", path)

    return _owned(step, tmp)


def _replay_process(rng: random.Random) -> Step:
    """``python -m ins_hil replay LOG --no-plots --quiet`` as a child process under ``REPLAY_MIB`` MiB of address
    space (RLIMIT_AS) on a mutated seed of every reader format: killed after ``REPLAY_SECONDS`` (a hang); each run
    checked by :func:`replay_oracle`; its wall time and peak resident memory (``os.wait4``) returned as
    :class:`~ins_hil.fuzz.Measure` (the campaign keeps their maxima)."""
    import os
    import resource
    import subprocess
    import sys

    from ins_hil.fuzz import Measure

    tmp = _scratch()
    seeds = _replay_seeds(tmp)

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (REPLAY_MIB * 1024 * 1024, resource.getrlimit(resource.RLIMIT_AS)[1]))

    def step() -> tuple[int, list[Any]]:
        fmt, seed = rng.choice(seeds)
        path = _mutated(rng, seed, fmt, tmp / "in")
        cmd = [sys.executable, "-m", "ins_hil", "replay", str(path), "--out", str(tmp / "out"), "--no-plots", "--quiet"]
        t0 = time.perf_counter()
        with (tmp / "stdout").open("w+") as fo, (tmp / "stderr").open("w+") as fe:
            child = subprocess.Popen(cmd, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL, preexec_fn=cap, cwd=ROOT)
            while True:
                pid, status, ru = os.wait4(child.pid, os.WNOHANG)
                if pid:
                    break
                if time.perf_counter() - t0 > REPLAY_SECONDS:
                    child.kill()
                    pid, status, ru = os.wait4(child.pid, 0)
                    child.returncode = -9
                    return 1, [Wrong(f"killed after {REPLAY_SECONDS:g} s"),
                               Measure("replay wall s", time.perf_counter() - t0)]  # fmt: skip
                time.sleep(0.02)
            child.returncode = os.waitstatus_to_exitcode(status)
            fo.seek(0)
            fe.seek(0)
            out, err = fo.read(), fe.read()
        wall = time.perf_counter() - t0
        found = replay_oracle(child.returncode, out, err, path)
        return 1, [*found, Measure("replay wall s", wall), Measure("replay peak RSS MiB", ru.ru_maxrss / 1024.0)]

    return _owned(step, tmp)


#: s of the synthetic data set an accepted dataset config replays: the shipped configs' alignment (2 s levelling
#: after 1.5 s at rest) ends within it, so their cores navigate (those that take the yaw from the magnetometer)
CONFIG_SECONDS = 4.0


def _dataset_config(rng: random.Random) -> Step:
    """The dataset config: the shipped configs/datasets/*.toml mutated (as TOML trees and as text), loaded; a
    DatasetConfigError is the clean refusal. An accepted config replays a small synthetic data set (prepare, the
    core, the outage protocol, the scores, the summary): a ReplayError / DatasetError is a clean refusal too,
    anything else escapes; a NaN printed as a figure is counted (``Wrong``)."""
    from ins_hil.datasets.config import DatasetConfigError, from_dict, load
    from ins_hil.datasets.dataset import DatasetError

    files = sorted((ROOT / "configs" / "datasets").glob("*.toml"))
    seeds = [(p, p.read_text()) for p in files]
    trees = [tomllib.loads(t) for _, t in seeds]
    tmp = _scratch()
    n = [0]
    _warm("dataset_config", lambda: _replay_check(_synthetic_dataset(CONFIG_SECONDS), load(files[0])))

    def step() -> tuple[int, list[Any]]:
        i = rng.randrange(len(seeds))
        n[0] += 1
        try:
            if rng.random() < 0.5:
                d = _copy_tree(trees[i])
                for _ in range(rng.choice((1, 1, 2, 3))):
                    _mutate_tree(rng, d)
                cfg = from_dict(d, "<fuzz>", tmp)
            else:
                lines = seeds[i][1].splitlines()
                for _ in range(rng.choice((1, 1, 2, 4))):
                    j = rng.randrange(len(lines))
                    ln = lines[j]
                    r = rng.random()
                    if r < 0.6 and "=" in ln:
                        lines[j] = (
                            f"{ln.split('=', 1)[0]}= {rng.choice([*_TEXT_VALUES, '-1e308', '-9.2e18', '1e-300'])}"
                        )
                    elif r < 0.75:
                        del lines[j]
                    elif r < 0.85:
                        lines.insert(j, lines[rng.randrange(len(lines))])
                    else:
                        b = bytearray(ln.encode())
                        _flip(rng, b) if b else None
                        lines[j] = b.decode("latin-1")
                p = tmp / "fuzz.toml"
                p.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogateescape")
                cfg = load(p)
        except DatasetConfigError:
            return 1, []
        if n[0] % 4:
            return 1, []
        try:  # one accepted config in four replays the small data set with it
            # a fresh data set each time (a tenth of a deep copy's time)
            return 1, _replay_check(_synthetic_dataset(CONFIG_SECONDS), cfg)
        except (DatasetError, DatasetConfigError):
            return 1, []

    return _owned(step, tmp)


TARGETS: list[Target] = [
    # weights: shares of the budget, set so every decoder gets about the same number of inputs
    Target("serial_frame", "ins_hil.drivers.serial_frame.FrameParser.feed", _serial, 0.45, nav=True),
    Target("dronecan", "ins_hil.drivers.dronecan_codec.DroneCanDecoder.feed", _dronecan, 1.5, nav=True),
    Target("dbc", "ins_hil.drivers.dbc_codec.DbcImuDecoder.feed", _dbc, 0.7, nav=True),
    Target("mavlink_in", "ins_hil.drivers.mavlink_in.MavlinkDriver.feed", _mavlink, 1.35, nav=True),
    Target(
        "config", "ins_hil.config.from_dict / load (mutated configs/*.toml)", _config, 0.5, decoder=False, goal=10_000
    ),
    Target("recorder_reader", "ins_hil.runtime.recorder.read_records", _recorder, 0.5, decoder=False, goal=100_000),
    # the dataset readers (mutated beginnings of the shipped logs, synthetic seeds) and the dataset config
    *(
        Target(
            f"reader_{f.replace('-', '_')}",
            f"ins_hil.datasets.dataset.read_dataset(..., {f!r}) + replay screen",
            _reader(f),
            0.3,
            decoder=False,
        )
        for f in ("csv", "px4-ulog", "px4-csv", "ardupilot-bin", "ardupilot-log", "rtklib", "ihlog")
    ),
    Target(
        "replay_dataset",
        "ins_hil.datasets.report.replay_to_dir (ins-hil replay LOG's path) on mutated logs of every reader format",
        _replay_dataset,
        0.3,
        decoder=False,
        goal=10_000,
    ),
    Target(
        "replay_process",
        f"python -m ins_hil replay LOG in a child under {REPLAY_MIB} MiB, killed after {REPLAY_SECONDS:g} s",
        _replay_process,
        0.15,
        decoder=False,
        goal=500,
    ),
    Target(
        "dataset_config",
        "ins_hil.datasets.config.from_dict / load + a small replay",
        _dataset_config,
        0.3,
        decoder=False,
        goal=100_000,
    ),
]


def by_name(names: list[str] | None) -> list[Target]:
    """The targets named (all when None); raises ValueError naming the unknown ones."""
    if not names:
        return list(TARGETS)
    known = {t.name: t for t in TARGETS}
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"unknown fuzz target(s) {bad} (known: {', '.join(known)})")
    return [known[n] for n in names]
