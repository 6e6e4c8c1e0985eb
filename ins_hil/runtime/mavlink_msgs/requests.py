"""A ground station's requests to the gateway (messages to its system id or broadcast): the parameter
protocol (:mod:`ins_hil.runtime.mavlink_params`), COMMAND_LONG/COMMAND_INT (always a COMMAND_ACK),
MAV_CMD_REQUEST_MESSAGE, MAV_CMD_SET_/GET_MESSAGE_INTERVAL, MAV_CMD_PREFLIGHT_STORAGE, MISSION_REQUEST_LIST
(MISSION_COUNT 0) and MAVLink FTP (a NAK). Replies (among them AUTOPILOT_VERSION and HOME_POSITION)
wait in ``_reply_pending`` and go out after the ACK.

A request is answered only when addressed to this system and component (or broadcast, 0): the ``fc`` role
shares its system id with the autopilot, whose parameters and commands are not ours. Writes (:data:`_WRITES`:
PARAM_SET, and every COMMAND_LONG/COMMAND_INT but the read-only ones of :data:`_READ_ONLY_COMMANDS`, among them
MAV_CMD_PREFLIGHT_STORAGE) are obeyed only from the system ids of ``allowed_gcs_sysids``; from any other
system they are refused (:meth:`Requests._refuse`): counted (``rx_refused_sysid``), answered the protocol's way
(COMMAND_ACK DENIED; PARAM_VALUE with the unchanged value) and reported once per system id (STATUSTEXT and
a warning)."""

from __future__ import annotations

import math
import struct
import time
from typing import Any

from ins_hil.runtime.mavlink_msgs.common import _MSG_NAMES, EndpointConfig, MessageBase, mavlink_module

_HANDLED = frozenset(
    ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET", "COMMAND_LONG", "COMMAND_INT",
     "MISSION_REQUEST_LIST", "FILE_TRANSFER_PROTOCOL")
)  # fmt: skip
_FTP_ERR_UNKNOWN_COMMAND = 7  # MAVLink FTP error code UnknownCommand
#: the requests that can change the gateway (a message type that changes anything must be listed here)
_WRITES = frozenset(("PARAM_SET", "COMMAND_LONG", "COMMAND_INT"))
#: the commands that only read: answered from any system (every other command is a write)
_READ_ONLY_COMMANDS = frozenset(
    int(getattr(mavlink_module(), "MAV_CMD_" + c))
    for c in ("REQUEST_MESSAGE", "REQUEST_AUTOPILOT_CAPABILITIES", "GET_MESSAGE_INTERVAL", "REQUEST_PROTOCOL_VERSION")
)
#: streamed messages whose builder needs no state (sent without one: no IMU, no solution yet)
_STATELESS = ("HEARTBEAT", "SYS_STATUS", "ESTIMATOR_STATUS", "EXTENDED_SYS_STATE", "BATTERY_STATUS")


class Requests(MessageBase):
    """Answers to the requests above (``_on_<message>``) and the queue of replies."""

    def _handle(self, msg: Any, typ: str) -> None:
        """Answer a ground station's request addressed to this system and component (0 = broadcast); a write
        from a system id that is not an allowed ground station is refused (:meth:`_refuse`)."""
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.cfg.sysid):
            self.rx_ignored += 1
            self.metrics.output(self.name, "rx_other_system")
            return
        if getattr(msg, "target_component", 0) not in (0, self.cfg.compid):  # e.g. the autopilot of our system
            self.rx_ignored += 1
            self.metrics.output(self.name, "rx_other_component")
            return
        try:
            writes = typ in _WRITES and (typ == "PARAM_SET" or int(msg.command) not in _READ_ONLY_COMMANDS)
            if writes and not self.cfg.allows(msg.get_srcSystem()):
                self._refuse(msg, typ)
            else:
                getattr(self, "_on_" + typ.lower())(msg)
        except Exception as e:  # a malformed request must not kill the link
            self.metrics.output(self.name, "rx_error")
            self.metrics.warn(f"{self.name}: {typ}: {type(e).__name__}: {e}")
        self._send_replies()

    def _refuse(self, msg: Any, typ: str) -> None:
        """A write from a system that is not an allowed ground station: nothing changes; counted, answered (PARAM_SET:
        PARAM_VALUE with the value in force; a command: COMMAND_ACK DENIED), told once per system id."""
        m = self._m
        src = msg.get_srcSystem()
        self.metrics.output(self.name, "rx_refused_sysid")
        if src not in self._refused_from:
            self._refused_from.add(src)
            self.statustext(m.MAV_SEVERITY_WARNING, f"sysid {src}: not an allowed GCS, writes refused")
            what = typ if typ == "PARAM_SET" else f"{typ} {int(msg.command)}"
            self.metrics.warn(f"{self.name}: {what} from system {src} refused: not in allowed_gcs_sysids "
                              f"{self.cfg.allowed_gcs_sysids} (later ones counted as rx_refused_sysid)")  # fmt: skip
        if typ == "PARAM_SET":
            if self.params is not None:
                names = self.params.names(self.params_index)
                name = _param_name(msg.param_id)
                if name in names:
                    self._param_value(name, names.index(name))  # the unchanged value: the protocol's "no"
            return
        self.mav.command_ack_send(int(msg.command), m.MAV_RESULT_DENIED, 0, 0, src, msg.get_srcComponent())
        self._count("COMMAND_ACK")

    def _param_value(self, name: str, index: int) -> None:
        from ins_hil.runtime.mavlink_params import encode_wire

        value, ptype = self.params.get(self.params_index, name)
        count = len(self.params.names(self.params_index))
        wire = encode_wire(value, ptype) if self.cfg.param_encoding == "bytewise" else float(value)
        self.mav.param_value_send(name.encode(), wire, ptype, count, index)
        self._count("PARAM_VALUE")

    def _on_param_request_list(self, msg: Any) -> None:
        if self.params is None:
            return
        for i, name in enumerate(self.params.names(self.params_index)):
            self._param_value(name, i)

    def _on_param_request_read(self, msg: Any) -> None:
        if self.params is None:
            return
        names = self.params.names(self.params_index)
        name = _param_name(msg.param_id)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._param_value(names[msg.param_index], msg.param_index)
        elif name in names:
            self._param_value(name, names.index(name))

    def _on_param_set(self, msg: Any) -> None:
        if self.params is None:
            return
        from ins_hil.runtime.mavlink_params import ParamError

        names = self.params.names(self.params_index)
        name = _param_name(msg.param_id)
        if name not in names:
            self.statustext(self._m.MAV_SEVERITY_WARNING, f"param {name}: unknown")
            return
        try:
            self.params.set(self.params_index, name, float(msg.param_value), int(msg.param_type))
        except ParamError as e:
            self.metrics.output(self.name, "param_refused")
            self.statustext(self._m.MAV_SEVERITY_WARNING, str(e))
            self.metrics.warn(f"{self.name}: PARAM_SET refused: {e}")
        else:
            self.metrics.output(self.name, "param_set")
            for w in self.params.warnings:
                self.metrics.warn(w)
            self.params.warnings.clear()
        self._param_value(name, names.index(name))  # the value in force: new, or unchanged when refused

    def _on_command_long(self, msg: Any) -> None:
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(msg, int(msg.command), p)

    def _on_command_int(self, msg: Any) -> None:
        p = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        self._command(msg, int(msg.command), p)

    def _command(self, msg: Any, cmd: int, p: tuple[float, ...]) -> None:
        """Every command is acknowledged (COMMAND_ACK); what is not handled is MAV_RESULT_UNSUPPORTED."""
        m = self._m
        result = m.MAV_RESULT_UNSUPPORTED
        if cmd == m.MAV_CMD_REQUEST_MESSAGE:
            result = self._request_message(int(p[0]))
        elif cmd == m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            result = self._request_message(m.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        elif cmd == m.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(int(p[0]), p[1])
        elif cmd == m.MAV_CMD_GET_MESSAGE_INTERVAL:
            typ = _MSG_NAMES.get(int(p[0]))
            if typ is None:
                result = m.MAV_RESULT_DENIED
            else:
                self._reply_pending.append(("MESSAGE_INTERVAL", int(p[0])))  # after the ACK
                result = m.MAV_RESULT_ACCEPTED
        elif cmd == m.MAV_CMD_PREFLIGHT_STORAGE:
            result = self._storage(int(p[0]))
        elif cmd == m.MAV_CMD_COMPONENT_ARM_DISARM:
            result = m.MAV_RESULT_DENIED  # a navigation gateway has nothing to arm
        self.mav.command_ack_send(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        self._count("COMMAND_ACK")

    def _storage(self, action: int) -> int:
        m = self._m
        if action != 1 or self.params is None:  # 1 = write parameters; reading/reset are not offered
            return int(m.MAV_RESULT_UNSUPPORTED)
        try:
            path = self.params.save()
        except (OSError, ValueError) as e:
            self.statustext(m.MAV_SEVERITY_ERROR, f"params not saved: {e}")
            self.metrics.warn(f"{self.name}: parameters not saved: {e}")
            return int(m.MAV_RESULT_FAILED)
        self.statustext(m.MAV_SEVERITY_INFO, f"params saved: {path.name}")
        return int(m.MAV_RESULT_ACCEPTED)

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        m = self._m
        typ = _MSG_NAMES.get(msg_id)
        if typ is None:
            return int(m.MAV_RESULT_DENIED)  # not a message this endpoint streams
        if interval_us < 0:
            hz = 0.0
        elif interval_us == 0:  # the default rate of the endpoint's role/config
            hz = EndpointConfig(role=self.cfg.role, rates=self.cfg.rates).effective_rates().get(typ, 0.0)
        else:
            hz = 1e6 / interval_us
        if self.params is not None:
            from ins_hil.runtime.mavlink_params import RATE_PARAM, REAL32, ParamError

            try:
                self.params.set(self.params_index, RATE_PARAM[typ], hz, REAL32)  # validated, SR_* follows
            except ParamError as e:
                self.statustext(m.MAV_SEVERITY_WARNING, str(e))
                return int(m.MAV_RESULT_DENIED)
        else:
            self.set_rate(typ, hz)
        return int(m.MAV_RESULT_ACCEPTED)

    def _request_message(self, msg_id: int) -> int:
        m = self._m
        if msg_id == m.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._reply_pending.append("AUTOPILOT_VERSION")
            return int(m.MAV_RESULT_ACCEPTED)
        if msg_id == m.MAVLINK_MSG_ID_HOME_POSITION:
            # accepted before the home is known too: HOME_POSITION goes out the moment it is taken
            if self._home is not None:
                self._reply_pending.append("HOME_POSITION")
            return int(m.MAV_RESULT_ACCEPTED)
        if msg_id == m.MAVLINK_MSG_ID_SYSTEM_TIME:
            if self._gnss is None or self._gnss.gps_week <= 0:
                return int(m.MAV_RESULT_TEMPORARILY_REJECTED)  # no GPS time yet
            self._reply_pending.append("SYSTEM_TIME")
            return int(m.MAV_RESULT_ACCEPTED)
        typ = _MSG_NAMES.get(msg_id)
        if typ is None:
            return int(m.MAV_RESULT_UNSUPPORTED)  # includes PROTOCOL_VERSION (not in the dialect)
        if typ == "GPS_RAW_INT":
            if self._gnss is None:
                return int(m.MAV_RESULT_TEMPORARILY_REJECTED)
        elif typ not in _STATELESS and self._latest is None:
            return int(m.MAV_RESULT_TEMPORARILY_REJECTED)  # no state yet
        self._reply_pending.append(typ)
        return int(m.MAV_RESULT_ACCEPTED)

    def _on_mission_request_list(self, msg: Any) -> None:
        """No mission: MISSION_COUNT 0 of the requested type, so a ground station stops asking."""
        self.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type)
        self._count("MISSION_COUNT")

    def _on_file_transfer_protocol(self, msg: Any) -> None:
        """MAVLink FTP is not offered: every request gets a NAK (UnknownCommand) so the client stops."""
        req = bytes(msg.payload)
        seq = int.from_bytes(req[0:2], "little")
        opcode = req[3] if len(req) > 3 else 0
        if opcode in (128, 129):  # an ACK/NAK from the peer: not a request
            return
        head = struct.pack("<HBBBBBBI", (seq + 1) & 0xFFFF, req[2] if len(req) > 2 else 0, 129, 1, opcode, 0, 0, 0)
        payload = head + bytes((_FTP_ERR_UNKNOWN_COMMAND,))
        self.mav.file_transfer_protocol_send(0, msg.get_srcSystem(), msg.get_srcComponent(),
                                             list(payload.ljust(251, b"\x00")))  # fmt: skip
        self._count("FILE_TRANSFER_PROTOCOL")

    def _send_replies(self) -> None:
        while self._reply_pending:
            typ = self._reply_pending.pop(0)
            if isinstance(typ, tuple):  # ("MESSAGE_INTERVAL", message id): −1 = not streamed
                hz = self.rates.get(_MSG_NAMES.get(typ[1], ""), 0.0)
                self.mav.message_interval_send(typ[1], round(1e6 / hz) if hz > 0 else -1)
                typ = typ[0]
            elif typ == "AUTOPILOT_VERSION":
                self._send_autopilot_version()
            elif typ == "HOME_POSITION":
                if not self._send_home_position():
                    continue
            elif typ == "SYSTEM_TIME":
                self._send_system_time(self._latest[0] if self._latest is not None else None)
                continue  # counted by the builder
            else:
                st = self._latest[0] if self._latest is not None else None
                if st is None and typ not in _STATELESS:
                    continue
                if typ == "GPS_RAW_INT":
                    self._gnss_new = True
                getattr(self, "_send_" + typ.lower())(st)
            self._count(typ)

    def _send_autopilot_version(self) -> None:
        m = self._m
        caps = (
            m.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | m.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | m.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | m.MAV_PROTOCOL_CAPABILITY_MISSION_INT  # the (empty) mission is served with the INT messages
        )
        if self.cfg.param_encoding == "bytewise":
            caps |= m.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE  # INT32 parameters: their bytes in the float
        else:
            caps |= m.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST  # INT32 parameters: their value as a float
        from ins_hil import __version__

        parts = [int(x) if x.isdigit() else 0 for x in [*__version__.split("."), "0", "0"][:3]]
        sw = (parts[0] << 24) | (parts[1] << 16) | (parts[2] << 8) | 0xFF  # FIRMWARE_VERSION_TYPE_OFFICIAL
        self.mav.autopilot_version_send(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.cfg.sysid)

    def _send_home_position(self, st: Any = None) -> bool:
        """HOME_POSITION (streamed, requested, and sent when the home is taken or re-taken); False, nothing
        sent, while the home is unknown. Position: the home's lat/lon/MSL altitude; x, y, z its offset from
        the local origin, which is the home: 0."""
        if st is not None:
            self._track_home(st)
        if self._home is None:
            return False
        lat, lon, h = self._home
        self.mav.home_position_send(
            round(math.degrees(lat) * 1e7), round(math.degrees(lon) * 1e7), round(self._msl(lat, lon, h) * 1000),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
            round((time.monotonic_ns() - self._t0_ns) * 1e-3),
        )  # fmt: skip
        return True


def _param_name(pid: Any) -> str:
    """A PARAM_* param_id (16 chars, NUL-padded; pymavlink gives str or bytes) as a str."""
    if isinstance(pid, bytes | bytearray):
        pid = pid.decode("ascii", "replace")
    return str(pid).split("\x00", 1)[0].strip()
