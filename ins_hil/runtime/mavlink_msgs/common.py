"""What the message builders of both roles share: the dialect, the streams and default rates, the
precompiled framing of an unsigned link, the vehicle's status bits, and :class:`MessageBase`, the state
and helpers of an endpoint that the role mixins (:mod:`.gcs`, :mod:`.fc`, :mod:`.requests`) build on.

Units: SI and radians inside, MAVLink's integer units (1e-7 deg, mm, cm/s, cdeg) at the edge; altitudes
in MSL fields are EGM96 (:mod:`ins_hil.geoid`)."""

from __future__ import annotations

import importlib
import math
import secrets
import struct
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ins_hil.geoid import undulation
from ins_hil.nav import earth
from ins_hil.nav.rotation import euler_from_quat
from ins_hil.settings import setting
from ins_hil.types import FaultEvent, GnssFix, NavState, unix_from_gps

if TYPE_CHECKING:
    import asyncio

    from ins_hil.runtime.metrics import RuntimeMetrics


def mavlink_module() -> Any:
    """The MAVLink 2 dialect used everywhere (ardupilotmega ⊃ common)."""
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


GCS_RATES = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "ATTITUDE": 50.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GLOBAL_POSITION_INT": 10.0,
    "LOCAL_POSITION_NED": 10.0,
    "GPS_RAW_INT": 5.0,
    "VFR_HUD": 4.0,
    "ESTIMATOR_STATUS": 2.0,
    "EXTENDED_SYS_STATE": 1.0,
    "BATTERY_STATUS": 1.0,
    "HOME_POSITION": 0.5,
}
FC_RATES = {"HEARTBEAT": 1.0, "ODOMETRY": 30.0, "GPS_INPUT": 5.0, "HIL_STATE_QUATERNION": 0.0}
ALL_MESSAGES = sorted(set(GCS_RATES) | set(FC_RATES))
_HEADER = struct.Struct("<BBBBBB")  # len, incompat_flags, compat_flags, seq, sysid, compid


class _Frame:
    """Precompiled MAVLink 2 framing of one message type for an UNSIGNED link.

    :meth:`frame` takes the field values in wire order (pymavlink's ``ordered_fieldnames``,
    arrays flattened) and returns the same bytes as pymavlink's ``MAVLink.send`` of that
    message: payload packed with the message's own ``struct`` format, trailing zero bytes
    trimmed (MAVLink 2, at least one byte kept), header 0xFD·len·0·0·seq·sysid·compid·msgid(24 bit),
    CRC-16/MCRF4XX over header (without 0xFD) + payload + ``crc_extra``. Signed links must use
    pymavlink (the signature is not produced here).
    """

    __slots__ = ("_crc", "_extra", "_msgid", "_pack")

    def __init__(self, cls: Any) -> None:
        mavlink = mavlink_module()
        self._pack = cls.unpacker.pack
        mid = int(cls.id)
        self._msgid = bytes((mid & 0xFF, (mid >> 8) & 0xFF, mid >> 16))
        self._extra = bytes((int(cls.crc_extra),))
        mc = getattr(mavlink, "mcrf4xx", None)  # fastcrc's CRC-16/MCRF4XX, as pymavlink's x25crc uses
        self._crc = (lambda b: mc(b, 0xFFFF)) if mc is not None else (lambda b: mavlink.x25crc(b).crc)

    def frame(self, mav: Any, *values: Any) -> bytes:
        payload = self._pack(*values).rstrip(b"\x00") or b"\x00"
        body = _HEADER.pack(len(payload), 0, 0, mav.seq, mav.srcSystem, mav.srcComponent) + self._msgid + payload
        crc = self._crc(body + self._extra)
        return b"\xfd" + body + crc.to_bytes(2, "little")


_FRAMES: dict[str, _Frame] = {}


try:  # the live path in C (firmware_ref/src/live.c): ODOMETRY's numbers and framing; None without the extension
    _live_mod: Any = importlib.import_module("ins_hil._cref")  # (by name: the extension is no module of the layers)
    _live_ffi, _live_lib = _live_mod.ffi, _live_mod.lib
except ImportError:  # pragma: no cover - the extension is built at every install
    _live_ffi = _live_lib = None


def _frame_of(typ: str) -> _Frame:
    """The cached :class:`_Frame` of a message type name (e.g. ``"ODOMETRY"``)."""
    f = _FRAMES.get(typ)
    if f is None:
        cls = mavlink_module().mavlink_map[getattr(mavlink_module(), "MAVLINK_MSG_ID_" + typ)]
        f = _FRAMES[typ] = _Frame(cls)
    return f


#: a state older than this (s) is no valid solution (IMU lost): ESTIMATOR_STATUS flags drop, CRITICAL
SOLUTION_TIMEOUT_S = 0.5
#: the ``gcs`` home (MessageBase._track_home): taken at the first state whose vertical σ is at most this (m),
#: or that is aligned; re-taken while the vehicle stays at rest there each time the vertical σ has fallen
#: to HOME_RETAKE_RATIO of the σ it was taken with; fixed for good once the vehicle moved
HOME_MAX_STD_D = 1.0
HOME_RETAKE_RATIO = 0.7
HOME_REST_SPEED = 0.5  # m/s: ground speed and |vertical speed| below this is "at rest"
HOME_MOVED_SPEED = 2.0  # m/s: a ground speed above this ends the re-taking
_BEAT_RETRY_NS = 100_000_000  # a heartbeat the link could not take is tried again after 0.1 s


def _msg_names() -> dict[int, str]:
    m = mavlink_module()
    return {int(getattr(m, "MAVLINK_MSG_ID_" + t)): t for t in ALL_MESSAGES}


_MSG_NAMES = _msg_names()  # message id → name of the streamed messages


def _sensor_bits() -> dict[str, int]:
    m = mavlink_module()
    return {
        "imu": m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
        "gnss": m.MAV_SYS_STATUS_SENSOR_GPS,
        "baro": m.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE,
        "mag": m.MAV_SYS_STATUS_SENSOR_3D_MAG,
    }


_SENSOR_BITS = _sensor_bits()


def _floats(a: Any) -> list[float]:
    """Python floats of a small vector (ndarray.tolist is the cheap path)."""
    try:
        return a.tolist()
    except AttributeError:
        return [float(x) for x in a]


def _i16(x: float) -> int:
    return max(-32768, min(32767, round(float(x))))


def _u32(x: float) -> int:
    return max(0, min(0xFFFFFFFF, round(float(x))))


def _dop(g: GnssFix, name: str) -> int:
    """HDOP/VDOP × 100 of a fix where its source gives it (a ``hdop``/``vdop`` attribute), else UINT16_MAX."""
    v = getattr(g, name, None)
    if v is None or not math.isfinite(v) or v < 0:
        return 0xFFFF
    return min(0xFFFE, round(v * 100))


def _gps_week(g: GnssFix | None, t: float | None = None) -> tuple[int, int]:
    """(GPS week, ms of week) at sensor time ``t`` (s; default the fix's own) from a fix whose source gives
    GPS time (``gps_week`` > 0, ``gps_tow`` s), else (0, 0): ArduPilot takes week 0 as "no GPS time"."""
    if g is None or g.gps_week <= 0 or not math.isfinite(g.gps_tow):
        return 0, 0
    total = g.gps_week * 604_800 + g.gps_tow + ((t - g.t) if t is not None else 0.0)
    ms = round(total * 1000)  # rounded once: 604 799.9996 s is the next week's 0 ms, never 604 800 000 ms
    return ms // 604_800_000, ms % 604_800_000


def fault_text(ev: FaultEvent) -> tuple[int, str]:
    """STATUSTEXT (severity, ≤50 chars) for a fault event."""
    m = mavlink_module()
    if ev.sensor == "nav":  # NavCore's divergence reset (core_parts/gnss.py) or yaw reset (core_parts/yaw_reset.py)
        if ev.detail.startswith("yaw reset"):
            return m.MAV_SEVERITY_WARNING, "INS yaw reset to the GNSS yaw estimator"
        return m.MAV_SEVERITY_WARNING, "INS diverged: reset to GNSS"
    if ev.cleared:
        return m.MAV_SEVERITY_NOTICE, f"INS fault cleared: {ev.sensor}"
    return m.MAV_SEVERITY_WARNING, f"INS fault {ev.sensor} {ev.mode.name.lower()}"


#: the ground-station system ids obeyed by default: 255 (QGroundControl, MAVProxy, Mission Planner) and 245
#: (MAVSDK's ground-station default, ``Mavsdk::Configuration(ComponentType::GroundStation)``)
GCS_SYSIDS = (255, 245)


def read_key_file(path: str) -> str:
    """The MAVLink signing key text of a key file (``ins-hil keygen``): its first line, a passphrase (the key is its
    SHA-256, as MAVProxy and QGroundControl make it) or 64 hex digits. ValueError (one line) when the file cannot be
    read, is empty, or can be read by other users (POSIX mode bits; the key would not be secret)."""
    import os
    import stat

    try:
        st = os.stat(path)
        with open(path, encoding="utf-8") as f:
            text = f.readline().strip()
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"signing key file {path!r}: {getattr(e, 'strerror', None) or e}") from None
    if os.name == "posix" and st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ValueError(f"signing key file {path!r}: readable by other users (mode {stat.S_IMODE(st.st_mode):04o}): "
                         f"chmod 600 {path}")  # fmt: skip
    if not text:
        raise ValueError(f"signing key file {path!r}: empty (write a passphrase or 64 hex digits: ins-hil keygen)")
    if len(text) != 64 or any(c not in "0123456789abcdefABCDEF" for c in text):  # a passphrase
        if not (text.isascii() and text.isprintable()) or " " in text or len(text) < 16:
            raise ValueError(f"signing key file {path!r}: the passphrase must be one word of at least 16 printable "
                             "ASCII characters (as MAVProxy's `signing key` takes it), or 64 hex digits")  # fmt: skip
    return text


#: HEARTBEAT vehicle types an output may announce (MAV_TYPE_*)
MAV_TYPES = ("QUADROTOR", "FIXED_WING", "HELICOPTER", "HEXAROTOR", "OCTOROTOR", "VTOL_FIXEDROTOR", "GROUND_ROVER",
             "SURFACE_BOAT", "GENERIC", "ONBOARD_CONTROLLER")  # fmt: skip


@dataclass
class EndpointConfig:
    """One MAVLink output (the ``[[outputs]]`` tables of type mavlink)."""

    name: str = setting("gcs", help="the output's name (status view, counters)", nonempty=True, doc_default="mav<N>")
    url: str = setting(
        "udpout:127.0.0.1:14550",
        help=(
            "udpout:HOST:PORT (send to), udpin:HOST:PORT (listen, answer the last sender), tcp:HOST:PORT "
            "(connect), tcpin:HOST:PORT (listen), serial:DEVICE:BAUD or DEVICE,BAUD (MAVProxy's grammar)"
        ),
    )
    role: str = setting(
        "gcs", help="gcs: a ground station view; fc: external navigation for a flight controller", choices=("gcs", "fc")
    )
    sysid: int = setting(42, "", "[1, 255]", "our MAVLink system id")
    compid: int = setting(1, "", "[0, 255]", "our MAVLink component id (197: MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY)")
    mav_type: str = setting("QUADROTOR", help="HEARTBEAT vehicle type (MAV_TYPE_*)", choices=MAV_TYPES)
    signing_key: str = setting("", help="MAVLink 2 signing key (32 bytes); '' = unsigned", hex_bytes=32)
    rates: dict[str, float] = setting(factory=dict, help="the [outputs.rates] table")
    params_file: str = setting(
        "", help="parameter override file (MAV_CMD_PREFLIGHT_STORAGE); '' = <config>.params.toml"
    )
    # ODOMETRY frame_id: LOCAL_NED (PX4) or LOCAL_FRD (ArduPilot accepts only LOCAL_FRD; same values: x north)
    odometry_frame: str = setting(
        "LOCAL_NED",
        help="ODOMETRY frame_id: LOCAL_NED (PX4) or LOCAL_FRD (ArduPilot accepts only this)",
        choices=("LOCAL_NED", "LOCAL_FRD"),
    )
    # INT32 parameters in PARAM_VALUE: "bytewise" (the int's bytes: MAVSDK, QGroundControl) or "c_cast" (the
    # int's float value: MAVProxy, Mission Planner, which decode bytewise only for PX4); AUTOPILOT_VERSION says which
    param_encoding: str = setting(
        "bytewise",
        help="INT32 parameters on the wire: bytewise (MAVSDK, QGroundControl), c_cast (MAVProxy, Mission Planner)",
        choices=("bytewise", "c_cast"),
    )
    # system ids whose PARAM_SET, parameter save and state-changing commands are obeyed (0 = any system);
    # 255: QGroundControl, MAVProxy, Mission Planner; 245: MAVSDK's ground-station default. [] = none (read-only)
    allowed_gcs_sysids: list[int] = setting(
        factory=lambda: list(GCS_SYSIDS),
        range="[0, 255]",
        help=(
            "system ids obeyed for PARAM_SET, parameter saves and state-changing commands (255: QGroundControl, "
            "MAVProxy; 245: MAVSDK); [] = none (read-only); [0] = any system"
        ),
        unique=True,
    )
    signing_key_file: str = setting(
        "",
        help=(
            "file holding the signing key: a passphrase (its SHA-256, as MAVProxy and QGroundControl make it) or "
            "64 hex digits, mode 0600; `ins-hil keygen` writes one; '' = signing_key"
        ),
        file=True,
    )

    def signing_secret(self) -> str:
        """The signing key text (``signing_key``, or the content of ``signing_key_file``); '' = unsigned.
        Raises ValueError (one line) for a key file that cannot be read, is empty or readable by others."""
        if self.signing_key or not self.signing_key_file:
            return self.signing_key
        return read_key_file(self.signing_key_file)

    def exposed(self) -> bool:
        """Listens (udpin, tcpin) on an address other hosts reach (not loopback) and is unsigned: anyone on the
        network can send it requests (the writes are then held only by ``allowed_gcs_sysids``)."""
        import ipaddress

        from ins_hil.drivers.mavlink_link import parse_url

        u = parse_url(self.url)
        if not u.listens or self.signing_key or self.signing_key_file or u.host == "localhost":
            return False
        try:
            return not ipaddress.ip_address(u.host).is_loopback
        except ValueError:  # a host name: whatever it resolves to
            return True

    def allows(self, sysid: int) -> bool:
        """Whether system ``sysid`` may change this output's parameters or send it state-changing commands."""
        ids = self.allowed_gcs_sysids
        return 0 in ids or sysid in ids

    def effective_rates(self) -> dict[str, float]:
        base = dict(GCS_RATES if self.role == "gcs" else FC_RATES)
        base.update(self.rates)
        return {k: v for k, v in base.items() if v > 0}


#: a step of the ODOMETRY position (m) beyond what the velocity explains between two messages: reset_counter + 1
#: (the Python builder, ``fc.FcMessages._send_odometry``, and live_odometry's threshold, given as its square)
JUMP_M = 1.0


def _live_fits() -> bool:
    """Whether live_odometry's framing (ODOMETRY: msgid 331, CRC extra 91, 233-byte payload, hard-coded in
    firmware_ref/src/live.c) is this dialect's: else the Python builder sends ODOMETRY."""
    f = _frame_of("ODOMETRY")
    return f._msgid == bytes((331 & 0xFF, 331 >> 8, 0)) and f._extra == bytes((91,)) and f._pack.__self__.size == 233


class _LiveOdometry:
    """The C buffers of :func:`live_odometry` (firmware_ref/src/live.c) for one endpoint: the state's numbers in, the
    home (ECEF point, C_e^n, the ellipsoid), the last ODOMETRY's time, NED offset and velocity (``_fc_prev``), the ids,
    the frame out."""

    __slots__ = ("buf", "home", "ids", "out", "prev", "st")

    def __init__(self) -> None:
        ffi = _live_ffi
        assert ffi is not None
        self.st = ffi.new("double[23]")
        self.home = ffi.new("double[15]")
        self.prev = ffi.new("double[8]")
        self.ids = ffi.new("int[8]")
        self.out = ffi.new("uint8_t[280]")
        self.buf = ffi.buffer(self.out)


class MessageBase:
    """The endpoint's state as the message builders see it, and the builders both roles send
    (HEARTBEAT, SYSTEM_TIME) with their helpers: boot time, Euler angles, home and NED offset, MSL height,
    solution validity and the vehicle's status bits. Mixed into :class:`~ins_hil.runtime.mavlink_out.MavlinkEndpoint`,
    which sets the attributes declared here."""

    cfg: EndpointConfig
    name: str
    metrics: RuntimeMetrics
    period_ns: dict[str, int]  # period of each streamed message (ns)
    mav: Any  # pymavlink's MAVLink; the endpoint is its file (write)
    mav_type: int
    rates: dict[str, float]
    next_ns: dict[str, int]  # due time (monotonic ns) of each streamed message
    sent: dict[str, int]
    _m: Any  # the dialect module
    _fast: bool  # unsigned link: the hot messages are framed by _Frame
    _latest: tuple[NavState, int, int] | None  # newest state, arrival and ready time (monotonic ns)
    _wake: asyncio.Event
    _gnss: GnssFix | None
    _gnss_new: bool
    _home: tuple[float, float, float] | None
    _home_ecef: tuple[float, float, float]  # ECEF point of the home (m)
    _home_cen: tuple[float, ...]  # C_e^n at home, row-major
    _t0_ns: int

    if TYPE_CHECKING:

        def write(self, buf: bytes) -> None: ...
        def _count(self, typ: str) -> None: ...
        def statustext(self, severity: int, text: str) -> None: ...
        def set_rate(self, typ: str, hz: float) -> None: ...
        def _send_home_position(self, st: NavState | None = None) -> bool: ...

    def _init_vehicle(self) -> None:
        self.params: Any = None  # ins_hil.runtime.mavlink_params.ParamStore (attached by the gateway)
        self.params_index = 0
        self._seen: Any = None  # the newest state as last seen by _state_age_ns, and when (monotonic ns)
        self._seen_ns = 0
        self._reply_pending: list[Any] = []  # messages to send once, after the ACK / off the IMU path
        self._geoid_at = (math.inf, math.inf)
        self._geoid_n = 0.0
        self.rx_ignored = 0  # messages addressed to another system or component
        self._refused_from: set[int] = set()  # system ids told once (STATUSTEXT) that their writes are refused
        frames = {"LOCAL_NED": self._m.MAV_FRAME_LOCAL_NED, "LOCAL_FRD": self._m.MAV_FRAME_LOCAL_FRD}
        if self.cfg.odometry_frame not in frames:
            raise ValueError(f"{self.name}.odometry_frame = {self.cfg.odometry_frame!r}: LOCAL_NED or LOCAL_FRD")
        self._odom_frame = frames[self.cfg.odometry_frame]
        if self.cfg.param_encoding not in ("bytewise", "c_cast"):
            raise ValueError(f"{self.name}.param_encoding = {self.cfg.param_encoding!r}: bytewise or c_cast")
        self._had_solution = False  # a valid solution was seen (then CRITICAL when it is lost)
        self._home_fixed = False  # the gcs home is no longer re-taken (_track_home)
        self._home_sd = math.inf  # vertical σ (m) of the state the home was taken from
        self._drop_ref = (0, 0, 0)  # SYS_STATUS drop rate: window start (monotonic ns), dropped, received
        self._drop_cpct = 0  # drop rate of the last closed window (c%)
        self._write_ok = True  # the last write reached the transport
        # ODOMETRY reset_counter: from a random start (a restarted gateway does not repeat the value the flight
        # controller last saw, but with a 1/256 chance), + 1 whenever the solution becomes usable (the home is
        # taken; again after it was unusable) or NavState.resets changes (new core, GNSS position reset)
        self.reset_counter = secrets.randbelow(256)
        self._fc_usable = False  # the last fc-role state was usable (see _usable)
        self._fc_resets = -1  # NavState.resets of that state
        self._fc_seen_ns = 0  # when ODOMETRY last looked at a state (monotonic ns)
        self._fc_prev: tuple[float, ...] | None = None  # that state's t (s), NED offset (m), NED velocity (m/s)
        # unsigned link with the extension: ODOMETRY built and framed in C (its own copy of the home and _fc_prev)
        self._live = _LiveOdometry() if self._fast and _live_lib is not None and _live_fits() else None
        if self._live is not None:  # the ids that never change (the rest: per message, _odometry_c)
            self._live.ids[1] = self._m.MAV_FRAME_BODY_FRD
            self._live.ids[3] = self._m.MAV_ESTIMATOR_TYPE_VIO

    def _emit(self, frame: _Frame, *values: Any) -> None:
        """Send one message framed by ``frame`` (values in wire order), with pymavlink's bookkeeping."""
        self._emit_bytes(frame.frame(self.mav, *values))

    def _emit_bytes(self, buf: bytes) -> None:
        """Send one framed message (with the link's sequence number), with pymavlink's bookkeeping."""
        mav = self.mav
        self.write(buf)
        mav.seq = (mav.seq + 1) % 256
        mav.total_packets_sent += 1
        mav.total_bytes_sent += len(buf)

    def _tboot_ms(self, st: NavState) -> int:
        return round(st.t * 1000) & 0xFFFFFFFF

    def _euler(self, st: NavState) -> list[float]:
        """(roll, pitch, yaw) rad of the state's q_nb as Python floats."""
        return euler_from_quat(st.q_nb).tolist()

    def _msl(self, lat: float, lon: float, h: float) -> float:
        """Height above MSL (m, EGM96) of ``h`` (WGS84); the undulation is re-evaluated when the point
        moved by more than 1e-5 rad (~60 m: the 1° grid changes by < 1 cm over that)."""
        a, b = self._geoid_at
        if abs(lat - a) + abs(lon - b) > 1e-5:
            self._geoid_at = (lat, lon)
            self._geoid_n = undulation(lat, lon)
        return h - self._geoid_n

    def _set_home(self, st: NavState) -> None:
        """The first position is the home of LOCAL_POSITION_NED/ODOMETRY (and GLOBAL_POSITION_INT's
        relative altitude); its ECEF point and C_e^n are cached here as floats."""
        self._home = (st.lat, st.lon, st.h)
        self._home_ecef = earth.ecef_xyz(st.lat, st.lon, st.h)
        self._home_cen = tuple(earth.dcm_ecef_to_ned(st.lat, st.lon).ravel().tolist())
        if self._live is not None:  # the same numbers for the C ODOMETRY (live_odometry's ``home``)
            self._live.home[0:15] = [*self._home_ecef, *self._home_cen, earth.A_WGS84, earth.E2_WGS84, JUMP_M * JUMP_M]
        if self.cfg.role == "gcs":
            self._reply_pending.append("HOME_POSITION")  # sent by the endpoint's task, off the IMU path
            self._wake.set()

    def _track_home(self, st: NavState) -> None:
        """The ground-station home (HOME_POSITION, GLOBAL_POSITION_INT's relative altitude, the origin of the
        gcs role's LOCAL_POSITION_NED), from a converged solution rather than the first fix: the first
        state's height can be metres off (a 2 m GNSS σ), which a vehicle parked at home would then show as
        its relative altitude for the whole run. Taken at the first state whose vertical σ is at most
        ``HOME_MAX_STD_D`` (or that is aligned), then re-taken — HOME_POSITION sent again each time — while
        the vehicle stays at rest (ground and vertical speed below ``HOME_REST_SPEED``) whenever the
        vertical σ has fallen to ``HOME_RETAKE_RATIO`` of the σ of the last take; the first ground speed
        above ``HOME_MOVED_SPEED`` fixes it for the run. An ``fc`` endpoint keeps its first position (the
        origin of its ODOMETRY, which must not move under the flight controller)."""
        if self._home_fixed:
            return
        if self.cfg.role != "gcs":
            if self._home is None:
                self._set_home(st)
            self._home_fixed = True
            return
        sd = float(st.std_pos[2])
        vn, ve, vd = _floats(st.vel_ned)
        gs = math.hypot(vn, ve)
        if self._home is not None and gs > HOME_MOVED_SPEED:
            self._home_fixed = True
            return
        if self._home is None:
            if (math.isfinite(sd) and sd <= HOME_MAX_STD_D) or st.aligned:
                self._home_sd = sd if math.isfinite(sd) else math.inf
                self._set_home(st)
        elif gs < HOME_REST_SPEED and abs(vd) < HOME_REST_SPEED and sd <= HOME_RETAKE_RATIO * self._home_sd:
            self._home_sd = sd
            self._set_home(st)

    def _home_ned(self, st: NavState) -> tuple[float, float, float]:
        """Exact NED offset (m) of the state from the home: earth.ned_from_geodetic's formula
        (C_e^n(home) · (r_e − r_e,home)) in scalar floats with the home's terms cached."""
        if self._home is None:
            self._set_home(st)
        x, y, z = earth.ecef_xyz(st.lat, st.lon, st.h)
        x0, y0, z0 = self._home_ecef
        dx, dy, dz = x - x0, y - y0, z - z0
        c = self._home_cen
        return (
            c[0] * dx + c[1] * dy + c[2] * dz,
            c[3] * dx + c[4] * dy + c[5] * dz,
            c[6] * dx + c[7] * dy + c[8] * dz,
        )

    def _state_age_ns(self, lt: tuple[NavState, int, int]) -> int:
        """Age of the newest state: from its ready time (the loop's monotonic stamp), or, without one
        (0, tests and tools), from when this endpoint first saw it here (1–2 Hz checks; nothing is
        added to :meth:`offer`)."""
        now = time.monotonic_ns()
        if lt[2]:
            return now - lt[2]
        if lt is not self._seen:
            self._seen, self._seen_ns = lt, now
        return now - self._seen_ns

    def _solution_valid(self) -> bool:
        """A state within the last ``SOLUTION_TIMEOUT_S`` that is aligned, and the IMU not lost."""
        lt = self._latest
        if lt is None or not lt[0].aligned:
            return False
        if self._state_age_ns(lt) > SOLUTION_TIMEOUT_S * 1e9:
            return False
        imu = self.metrics.sensors["imu"]
        return not (imu.present and imu.count and not imu.healthy)

    def _usable(self, st: NavState) -> bool:
        """The state may be fed to a flight controller: aligned and the IMU not lost (a state that stops
        coming, or a core that re-initialises, is not aligned or not offered). The fc-role builders send
        nothing (ODOMETRY, HIL_STATE_QUATERNION) or no fix (GPS_INPUT) otherwise."""
        if not st.aligned:
            return False
        imu = self.metrics.sensors["imu"]
        return not (imu.present and imu.count and not imu.healthy)

    def _note_usable(self, st: NavState, usable: bool) -> bool:
        """Track usability and resets for ODOMETRY's ``reset_counter``: True when it was incremented here
        (the first usable state; usable again; the first state after a pause of the states longer than
        ``SOLUTION_TIMEOUT_S`` or 3 ODOMETRY periods, i.e. the IMU stopped; ``st.resets`` changed)."""
        now = time.monotonic_ns()
        pause = max(SOLUTION_TIMEOUT_S * 1e9, 3 * self.period_ns.get("ODOMETRY", 0))
        stale = now - self._fc_seen_ns > pause
        self._fc_seen_ns = now
        step = usable and (not self._fc_usable or stale or st.resets != self._fc_resets)
        self._fc_usable = usable
        if usable:
            self._fc_resets = st.resets
        if step:
            self.reset_counter = (self.reset_counter + 1) & 0xFF
        return step

    def _send_origin(self) -> None:
        """SET_GPS_GLOBAL_ORIGIN: the home (the origin of ODOMETRY's local frame) to the flight controller,
        ``target_system`` = this endpoint's system id (the autopilot's; PX4 checks it). Altitude MSL, mm."""
        if self._home is None:
            return
        lat, lon, h = self._home
        self.mav.set_gps_global_origin_send(
            self.cfg.sysid, round(math.degrees(lat) * 1e7), round(math.degrees(lon) * 1e7),
            round(self._msl(lat, lon, h) * 1000),
        )  # fmt: skip
        self._count("SET_GPS_GLOBAL_ORIGIN")

    def _vehicle_status(self) -> tuple[int, int, int, bool, int]:
        """SYS_STATUS (present, enabled, health) bits, solution valid, HEARTBEAT system_status.

        Per sensor kind (RuntimeMetrics.sensors): present = configured or seen, enabled = present,
        healthy = arriving at its rate; the IMU bits are unhealthy while FDI reports a fault; AHRS
        healthy = valid solution. system_status: STANDBY before the first aligned solution, ACTIVE
        when the solution is valid and every present sensor healthy, CRITICAL when the IMU is lost,
        or after a solution when it is invalid (no state for 0.5 s) or a sensor is lost (dead reckoning)."""
        m = self._m
        present = health = 0
        all_ok = True
        for kind, h in self.metrics.sensors.items():
            bit = _SENSOR_BITS[kind]
            if h.present:
                present |= bit
                if h.healthy:
                    health |= bit
                else:
                    all_ok = False
        if self.metrics.fdi_state != "ok":
            health &= ~(m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL)
        valid = self._solution_valid()
        present |= m.MAV_SYS_STATUS_AHRS
        if valid:
            health |= m.MAV_SYS_STATUS_AHRS
            self._had_solution = True
        imu = self.metrics.sensors["imu"]
        if valid and all_ok:
            status = m.MAV_STATE_ACTIVE
        elif self._had_solution or (imu.count and not imu.healthy):  # solution lost, or the IMU lost
            status = m.MAV_STATE_CRITICAL
        else:
            status = m.MAV_STATE_STANDBY
        return present, present, health, valid, status

    def _send_heartbeat(self, st: NavState | None) -> None:
        m = self._m
        status = self._vehicle_status()[4]
        if self.cfg.role == "gcs":
            typ, ap = self.mav_type, m.MAV_AUTOPILOT_GENERIC
        else:
            typ, ap = m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID
        if self._fast:  # wire order: custom_mode, type, autopilot, base_mode, system_status, mavlink_version
            self._emit(_frame_of("HEARTBEAT"), 0, typ, ap, 0, status, 3)
        else:
            self.mav.heartbeat_send(typ, ap, 0, 0, status)
        if not self._write_ok and "HEARTBEAT" in self.next_ns:  # link not up yet (TCP, serial, udpin: no peer)
            self.next_ns["HEARTBEAT"] = time.monotonic_ns() + _BEAT_RETRY_NS
        elif self._gnss is not None and self._gnss.gps_week > 0:
            self._send_system_time(st)  # with the 1 Hz HEARTBEAT, once the GNSS gives GPS time
        if self.cfg.role == "fc" and "ODOMETRY" in self.rates and self._write_ok:
            self._send_origin()  # with every HEARTBEAT once the home is set: a flight controller started later

    def _send_system_time(self, st: NavState | None) -> bool:
        """SYSTEM_TIME: UNIX time (µs) from the last fix's GPS time moved on to the state's time (the fix's
        own time without a state); time_boot_ms the state's. False (nothing sent) without GPS time."""
        g = self._gnss
        if g is None or g.gps_week <= 0 or not math.isfinite(g.gps_tow):
            return False
        t = st.t if st is not None else g.t
        unix = unix_from_gps(g.gps_week, g.gps_tow + (t - g.t))
        self.mav.system_time_send(round(unix * 1e6), round(t * 1000) & 0xFFFFFFFF)
        self._count("SYSTEM_TIME")
        return True
