"""DBC-described CAN IMU (industrial IMUs that are not DroneCAN), decoded with cantools.

The default profile is ``configs/imu_dbc.dbc``: angular rate (IMU_GYRO,
0x180) and specific force (IMU_ACCEL, 0x181) in separate 8-byte frames, each
with an 8-bit sample ``Counter`` and a ``Crc8`` (CRC-8/SAE-J1850 over bytes
0..6), plus a slow IMU_STATUS (temperature, flags, output rate). Message and
signal names are configurable (:class:`DbcProfile`) for other DBC files.

Rates → increments: such IMUs output sampled (already filtered) rates, so
``dtheta = ω·dt`` and ``dvel = f·dt`` with ``dt = 1/rate_hz`` (rectangular
integration: exact for constant rates, error O(dt²·ω̇) per sample). Time
``t`` = arrival time of the first sample + unwrapped counter × dt, so it is
as regular as the IMU's own clock (the counter), not as jittery as the bus.
The counter goes through a :class:`~ins_hil.drivers.clock.SourceClock` (8 bits,
tick = dt): the host arrival time counts the counter's wraps (after a 10 s
stall at 200 Hz the time advances 10 s, not the 8-bit remainder), and a reset
or jump of the counter re-anchors so the time never goes back. Frames are
matched on their id *and* their id format (a 29-bit frame is never the 11-bit
message of the same number).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cantools
import numpy as np
from ins_hil.drivers.clock import SourceClock

from ins_hil.settings import setting
from ins_hil.types import ImuSample

DEFAULT_DBC = Path(__file__).resolve().parent.parent / "configs" / "imu_dbc.dbc"


def _crc8_table() -> list[int]:
    tab = []
    for b in range(256):
        c = b
        for _ in range(8):
            c = ((c << 1) ^ 0x1D) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        tab.append(c)
    return tab


_CRC8 = _crc8_table()


def crc8_j1850(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF); check("123456789") = 0x4B."""
    c = 0xFF
    for b in data:
        c = _CRC8[c ^ b]
    return c ^ 0xFF


@dataclass
class DbcProfile:
    """Which DBC messages/signals carry what (names as in the DBC file)."""

    dbc: str = setting(
        str(DEFAULT_DBC), help="the DBC file", file=True, nonempty=True, doc_default="configs/imu_dbc.dbc (shipped)"
    )
    gyro_message: str = setting("IMU_GYRO", help="DBC message with the angular rates", nonempty=True)
    gyro_signals: tuple[str, str, str] = setting(
        ("GyroX", "GyroY", "GyroZ"), help="its x, y, z signals (rad/s)", length=3
    )
    accel_message: str = setting("IMU_ACCEL", help="DBC message with the specific force", nonempty=True)
    accel_signals: tuple[str, str, str] = setting(
        ("AccelX", "AccelY", "AccelZ"), help="its x, y, z signals (m/s²)", length=3
    )
    status_message: str | None = setting("IMU_STATUS", help="DBC message with Temperature/flags; '' = none")
    counter_signal: str | None = setting(
        "Counter", help="the sample counter signal in both messages (pairs them, times the samples); '' = none"
    )
    crc_signal: str | None = setting("Crc8", help="the CRC-8/SAE-J1850 signal in the last byte; '' = none")
    rate_hz: float = setting(200.0, "Hz", "[1, 10000]", "nominal sample rate")

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> DbcProfile:
        known = set(cls.__dataclass_fields__)
        bad = set(cfg) - known
        if bad:
            raise ValueError(f"DBC profile: unknown key(s) {sorted(bad)} (known: {sorted(known)})")
        kw = dict(cfg)
        for k in ("gyro_signals", "accel_signals"):
            if k in kw:
                v = tuple(kw[k])
                if len(v) != 3:
                    raise ValueError(f"DBC profile: {k!r} needs 3 signal names (x, y, z), got {kw[k]!r}")
                kw[k] = v
        p = cls(**kw)
        if not p.rate_hz > 0:
            raise ValueError(f"DBC profile: 'rate_hz' must be positive, got {p.rate_hz!r}")
        return p


@dataclass
class DbcImuDecoder:
    """CAN frames in, ImuSamples out, every drop counted in ``counts``.

    Reasons: unknown_id (frame id or id format not in the profile; not an
    error, counted as ``ignored``), length, crc, decode, nonfinite, range,
    duplicate, seq_backwards, time_jump, seq_gap (samples of which no frame
    came), unpaired (a gyro frame whose accel frame never came, or the
    reverse), and the ``clock_*`` events of :mod:`ins_hil.drivers.clock`.
    """

    profile: DbcProfile = field(default_factory=DbcProfile)
    imu_id: int = 0
    max_rate: float = 40.0  # rad/s: beyond is not physical for a navigation IMU
    max_accel: float = 400.0  # m/s^2
    counts: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = self.profile
        try:
            db: Any = cantools.database.load_file(p.dbc)
            self.db = db
        except FileNotFoundError as e:
            raise ValueError(f"DBC profile: file {p.dbc!r} not found") from e
        try:
            self.gyro = self.db.get_message_by_name(p.gyro_message)
            self.accel = self.db.get_message_by_name(p.accel_message)
            self.status = self.db.get_message_by_name(p.status_message) if p.status_message else None
        except KeyError as e:
            raise ValueError(f"DBC profile: message {e} not in {p.dbc}") from e
        self._extended = bool(self.gyro.is_extended_frame)
        if bool(self.accel.is_extended_frame) != self._extended:
            raise ValueError(f"DBC profile: {p.gyro_message} and {p.accel_message} must both use 11-bit or 29-bit ids")
        for m, sigs in ((self.gyro, p.gyro_signals), (self.accel, p.accel_signals)):
            names = {s.name for s in m.signals}
            for s in sigs:
                if s not in names:
                    raise ValueError(f"DBC profile: signal {s!r} not in message {m.name} of {p.dbc}")
            if p.counter_signal and p.counter_signal not in names:  # else a KeyError on every frame
                raise ValueError(f"DBC profile: counter_signal = {p.counter_signal!r}: not a signal of {m.name} "
                                 f"(signals: {', '.join(sorted(names))})")  # fmt: skip
        if not (isinstance(p.rate_hz, int | float) and 0 < p.rate_hz < math.inf):
            raise ValueError(f"DBC profile: 'rate_hz' must be a finite number > 0 (Hz), got {p.rate_hz!r}")
        self.dt = 1.0 / p.rate_hz
        self._pending: tuple[int, tuple[float, float, float], int] | None = None
        self.clock = SourceClock(
            8, self.dt, self.counts, gaps_from_time=True, anchor_host=True, same_key="duplicate",
            back_key="seq_backwards", jump_tol_s=max(0.1, 4 * self.dt),
        )  # fmt: skip
        self._n = 0  # samples seen (the time base of a profile without a counter)
        self.temperature = float("nan")
        self.flags = 0

    def _count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def _decode(self, msg: Any, data: bytes) -> dict[str, Any] | None:
        if len(data) != msg.length:
            self._count("length")
            return None
        p = self.profile
        if p.crc_signal is not None and crc8_j1850(data[:-1]) != data[-1]:
            self._count("crc")
            return None
        try:
            return msg.decode(bytes(data), decode_choices=False)  # type: ignore[no-any-return,unused-ignore]
        except Exception:
            self._count("decode")
            return None

    def reopen(self) -> None:
        """The bus was re-opened: forget a half pair; the time base is kept (the output continues)."""
        self._pending = None
        self.clock.reopen()

    def feed(self, can_id: int, data: bytes, now_ns: int, extended: bool = False) -> ImuSample | None:
        """One CAN frame (``extended``: 29-bit id); returns an ImuSample when a gyro/accel pair is complete."""
        p = self.profile
        if extended != self._extended:
            self._count("ignored")
            return None
        if can_id == self.gyro.frame_id:
            v = self._decode(self.gyro, data)
            if v is None:
                return None
            w = (float(v[p.gyro_signals[0]]), float(v[p.gyro_signals[1]]), float(v[p.gyro_signals[2]]))
            c = int(v[p.counter_signal]) if p.counter_signal else -1
            if self._pending is not None:
                self._count("unpaired")
                self.clock.rejected(self._pending[0])
            self._pending = (c, w, now_ns)
            return None
        if can_id == self.accel.frame_id:
            v = self._decode(self.accel, data)
            if v is None:
                return None
            a = (float(v[p.accel_signals[0]]), float(v[p.accel_signals[1]]), float(v[p.accel_signals[2]]))
            c = int(v[p.counter_signal]) if p.counter_signal else -1
            pend = self._pending
            if pend is None or pend[0] != c:
                self._count("unpaired")
                if pend is not None:
                    self._count("unpaired")  # the gyro frame waiting for its accel frame, too
                    self.clock.rejected(pend[0])
                self.clock.rejected(c)
                self._pending = None
                return None
            self._pending = None
            return self._sample(c, pend[1], a, pend[2])
        if self.status is not None and can_id == self.status.frame_id:
            v = self._decode(self.status, data)
            if v is not None:
                t = float(v.get("Temperature", math.nan))
                self.temperature = t if math.isfinite(t) else math.nan
                self.flags = int(v.get("Flags", 0)) & 0xFF
            return None
        self._count("ignored")
        return None

    def _sample(
        self, c: int, w: tuple[float, float, float], a: tuple[float, float, float], now_ns: int
    ) -> ImuSample | None:
        clk = self.clock
        if c < 0:  # no counter in the profile: one interval per sample (the host bounds a stall)
            c = self._n & 0xFF
            self._n += 1
        if not all(math.isfinite(x) for x in (*w, *a)):
            self._count("nonfinite")
            clk.rejected(c)
            return None
        if (
            max(abs(w[0]), abs(w[1]), abs(w[2])) > self.max_rate
            or max(abs(a[0]), abs(a[1]), abs(a[2])) > self.max_accel
        ):
            self._count("range")
            clk.rejected(c)
            return None
        t = clk.accept(c, 0, 1, now_ns)
        if t is None:
            return None
        dt = self.dt
        return ImuSample(
            t=t, dt=dt, dtheta=np.array(w) * dt, dvel=np.array(a) * dt, imu_id=self.imu_id,
            seq=(clk.last_raw + clk.base) & 0xFFFF, temperature=self.temperature, flags=self.flags,
            t_arrival_ns=now_ns,
        )  # fmt: skip


def encode_imu_frames(
    db: Any, gyro: tuple[float, float, float], accel: tuple[float, float, float], counter: int
) -> list[tuple[int, bytes]]:
    """Encode one sample as (frame id, 8 bytes) for IMU_GYRO and IMU_ACCEL (simulator, tests)."""
    out = []
    for name, sig, vals in (("IMU_GYRO", "Gyro", gyro), ("IMU_ACCEL", "Accel", accel)):
        m = db.get_message_by_name(name)
        b = bytearray(
            m.encode(
                {f"{sig}X": vals[0], f"{sig}Y": vals[1], f"{sig}Z": vals[2], "Counter": counter & 0xFF, "Crc8": 0},
                strict=False,
            )
        )
        b[7] = crc8_j1850(b[:7])
        out.append((m.frame_id, bytes(b)))
    return out
