"""Typed, time-stamped samples and states shared by drivers, core and runtime.

SI units inside (rad, m, m/s, s, Pa, T); body frame FRD, navigation frame NED.
Every sample carries the sensor's own time ``t`` (s, sensor clock, after any
clock-offset correction by the runtime) and the monotonic arrival time
``t_arrival_ns`` (``time.monotonic_ns()`` when the bytes arrived; 0 offline).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag
from typing import Any, ClassVar, Literal, Protocol, TypeAlias

import numpy as np
from numpy.typing import NDArray

from ins_hil.settings import ConfigError as ConfigError  # the runtime raises it too
from ins_hil.settings import setting

#: float arrays of any shape (3-vectors, quaternions, matrices); float64 by convention
Vec: TypeAlias = NDArray[Any]


def _zeros3() -> Vec:
    return np.zeros(3)


class ImuFlags(IntFlag):
    """Status bits of an IMU sample (also the serial frame's status byte)."""

    NONE = 0
    GYRO_SATURATED = 1
    ACCEL_SATURATED = 2
    SELFTEST_FAIL = 4
    CLIPPED = 8
    TEMP_INVALID = 16


@dataclass(slots=True)
class ImuSample:
    """One IMU output interval, in increment form.

    ``dtheta``: delta angle over the interval (rad, body FRD, ∫ω_ib dt).
    ``dvel``: delta velocity over the interval (m/s, body FRD, ∫f_b dt).
    ``dt``: interval length (s); ``t``: sensor time at the END of the interval (s).
    """

    #: the sample's kind (:attr:`ins_hil.types.AidSample.kind`)
    kind: ClassVar[Literal["imu"]] = "imu"

    t: float
    dt: float
    dtheta: Vec
    dvel: Vec
    imu_id: int = 0
    seq: int = 0
    temperature: float = float("nan")
    flags: int = 0
    t_arrival_ns: int = 0

    @property
    def gyro(self) -> Vec:
        """Mean angular rate over the interval (rad/s)."""
        return self.dtheta / self.dt

    @property
    def accel(self) -> Vec:
        """Mean specific force over the interval (m/s^2)."""
        return self.dvel / self.dt


class FixType(IntEnum):
    """GNSS fix quality (MAVLink GPS_FIX_TYPE numbering)."""

    NO_FIX = 1
    FIX_2D = 2
    FIX_3D = 3
    DGPS = 4
    RTK_FLOAT = 5
    RTK_FIXED = 6


@dataclass(slots=True)
class GnssFix:
    """A GNSS position/velocity solution valid at sensor time ``t`` (s).

    lat/lon in rad (WGS84), h ellipsoidal height (m); vel_ned m/s or None.
    Standard deviations in m and m/s. ``gps_week``/``gps_tow`` (s of the week) are the GPS time of the
    fix where the receiver gives it (week 0 = unknown); ``hdop``/``vdop`` its dilutions of precision
    (NaN = unknown). They go to the outputs only (GPS_INPUT, SYSTEM_TIME, GPS_RAW_INT), never to the core.
    """

    #: the sample's kind (:attr:`ins_hil.types.AidSample.kind`)
    kind: ClassVar[Literal["gnss"]] = "gnss"

    t: float
    lat: float
    lon: float
    h: float
    vel_ned: Vec | None = None
    std_ne: float = 2.5
    std_d: float = 5.0
    std_vel: float = 0.3
    fix_type: FixType = FixType.FIX_3D
    num_sats: int = 0
    source: int = 0
    t_arrival_ns: int = 0
    gps_week: int = 0
    gps_tow: float = math.nan
    hdop: float = math.nan
    vdop: float = math.nan


@dataclass(slots=True)
class BaroSample:
    """Static pressure (Pa) and/or barometric altitude (m, above the baro datum)."""

    #: the sample's kind (:attr:`ins_hil.types.AidSample.kind`)
    kind: ClassVar[Literal["baro"]] = "baro"

    t: float
    pressure: float
    altitude: float = float("nan")
    temperature: float = float("nan")
    source: int = 0
    t_arrival_ns: int = 0


@dataclass(slots=True)
class MagSample:
    """Magnetic field in body FRD (tesla)."""

    #: the sample's kind (:attr:`ins_hil.types.AidSample.kind`)
    kind: ClassVar[Literal["mag"]] = "mag"

    t: float
    field_b: Vec
    source: int = 0
    t_arrival_ns: int = 0


class AidSample(Protocol):
    """What every aiding sample has: its time of validity ``t`` (s, sensor clock) and its arrival time
    ``t_arrival_ns`` (ns, host monotonic; 0 offline). The aiding sample types are :class:`GnssFix`,
    :class:`BaroSample`, :class:`MagSample` and those of the aid modules (:mod:`ins_hil.aids`, one per aid
    source: its sample type, model, validation and record codec); the core dispatches on the registry.

    ``kind``: a class attribute of every sample type, ``"imu"`` for :class:`ImuSample` and the name of the aid
    source that reads it for an aiding sample (``"gnss"``, ``"baro"``, ``"mag"``, ``"odometer"``, ...; the
    registry checks it, :func:`ins_hil.aids.sources`). Code that tells samples apart reads ``s.kind`` (and
    :func:`ins_hil.aids.source_of` for what the aid does with it), never ``isinstance`` on the sample types."""

    t: float
    t_arrival_ns: int

    @property
    def kind(self) -> str: ...


#: every sample a driver, a reader or the simulator hands to the runtime: the IMU's or an aid source's (the one
#: sample union; the aid sources' registry is :mod:`ins_hil.aids`)
Sample: TypeAlias = ImuSample | AidSample


@dataclass(slots=True)
class NavState:
    """The navigation solution at time ``t`` (s).

    q_nb: Hamilton scalar-first quaternion body→NED; vel_ned (m/s);
    lat/lon (rad), h (m, ellipsoidal); biases in body FRD (rad/s, m/s^2);
    std_* are 1-σ from the filter covariance (NED position m, velocity m/s,
    attitude rad about NED axes). ``resets`` changes when the solution may step (see the field).
    """

    t: float
    q_nb: Vec
    vel_ned: Vec
    lat: float
    lon: float
    h: float
    gyro_bias: Vec = field(default_factory=_zeros3)
    accel_bias: Vec = field(default_factory=_zeros3)
    std_pos: Vec = field(default_factory=_zeros3)
    std_vel: Vec = field(default_factory=_zeros3)
    std_att: Vec = field(default_factory=_zeros3)
    omega_b: Vec = field(default_factory=_zeros3)
    accel_b: Vec = field(default_factory=_zeros3)
    aligned: bool = False
    test_ratios: dict[str, float] = field(default_factory=dict)
    #: resets of the solution so far (a new core: initialisation, restart or re-alignment after a fault;
    #: a GNSS position reset): position/attitude may step when it changes (ODOMETRY ``reset_counter``)
    resets: int = 0


class FaultMode(IntEnum):
    """Failure modes of inertial sensors (and aiding sensors)."""

    UNKNOWN = 0
    STEP_BIAS = 1
    RAMP = 2
    STUCK = 3
    DROPOUT = 4
    NOISE_BURST = 5
    SATURATION = 6
    SCALE_FACTOR = 7
    JUMP = 8
    DRIFT = 9


@dataclass(slots=True)
class FaultEvent:
    """A detected and (where possible) isolated fault.

    ``sensor`` names the sensor, e.g. ``"gyro[3]"``, ``"imu1.accel.y"``,
    ``"gnss"``, ``"baro"``. ``magnitude`` is the estimated fault size in the
    sensor's SI unit. ``isolated`` is False for detection without isolation.
    """

    t: float
    sensor: str
    mode: FaultMode = FaultMode.UNKNOWN
    magnitude: float = float("nan")
    isolated: bool = True
    cleared: bool = False
    detail: str = ""


@dataclass
class SimConfig:
    """What the simulated sensors simulate: the ``[sim]`` table of a gateway config (read by
    :mod:`ins_hil.sim.devices`; here, below both, so the config and the replay name it without the
    simulator). Units and ranges per key: each field's metadata (docs/configuration.md)."""

    profile: str = setting(
        "uav", help="uav: 10 s at rest, then sweeping turns at 20 m/s; static: at rest", choices=("uav", "static")
    )
    imu_rate: float = setting(1000.0, "Hz", "[1, 10000]", "simulated IMU rate (serial frames into a pty)")
    imu_errors: str = setting("mems", help="mems: UAV-grade MEMS errors; none: error-free", choices=("mems", "none"))
    gnss_rate: float = setting(5.0, "Hz", "(0, 100]", "GNSS rate (GPS_INPUT over MAVLink)")
    gnss_latency: float = setting(0.05, "s", "[0, 1]", "from the time of validity to sending")
    gnss_std_ne: float = setting(1.0, "m", "(0, 1000]", "GNSS horizontal noise")
    gnss_std_d: float = setting(2.0, "m", "(0, 1000]", "GNSS vertical noise")
    gnss_std_vel: float = setting(0.1, "m/s", "(0, 100]", "GNSS velocity noise")
    baro_rate: float = setting(25.0, "Hz", "(0, 1000]", "baro rate (SCALED_PRESSURE over MAVLink)")
    baro_std: float = setting(0.5, "m", "[0, 100]", "baro noise")
    lat_deg: float = setting(50.45, "°", "[-89, 89]", "start latitude")
    lon_deg: float = setting(30.52, "°", "[-180, 180]", "start longitude")
    h: float = setting(180.0, "m", "[-1000, 100000]", "start height above the WGS84 ellipsoid")
    seed: int = setting(7, "", "[0, 4294967295]", "random seed (the same seed gives the same run)")
    chunk_s: float = setting(10.0, "s", "[0.1, 60]", "simulated in chunks of this length")
    duration: float = setting(0.0, "s", "0 | [0.1, 1e7]", "stop the simulator after this long; 0 = until stopped")
    gnss_sysid: int = setting(1, "", "[1, 255]", "MAVLink system id of the simulated GNSS")
    sign_key: str = setting("", help="MAVLink 2 signing key (32 bytes); '' = unsigned", hex_bytes=32)


#: GPS time − UTC (s), the leap seconds since 1980 (constant since 2017-01-01)
GPS_UTC_LEAP_S = 18
#: UNIX time (s) of the GPS epoch, 1980-01-06 00:00:00 UTC
GPS_EPOCH_UNIX_S = 315_964_800


def gps_from_unix(unix_s: float) -> tuple[int, float]:
    """(GPS week, seconds of week) of a UNIX time (s, UTC)."""
    g = unix_s - GPS_EPOCH_UNIX_S + GPS_UTC_LEAP_S
    week = int(g // 604_800)
    return week, g - week * 604_800


def unix_from_gps(week: int, tow: float) -> float:
    """UNIX time (s, UTC) of a GPS week and seconds of week."""
    return GPS_EPOCH_UNIX_S + week * 604_800 + tow - GPS_UTC_LEAP_S
