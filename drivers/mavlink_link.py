"""The one MAVLink link layer of inputs and outputs: URL grammar, asyncio transports, signing.

URLs (MAVProxy's grammar; the same meaning for an input driver and an output endpoint):

- ``udpin:HOST:PORT``: listen on HOST:PORT (port 0 = any free one); replies go to the last
  sender of valid MAVLink;
- ``udpout:HOST:PORT``: send to HOST:PORT (a connected datagram socket; answers come back
  on it);
- ``tcp:HOST:PORT``: connect to a TCP server (e.g. SITL's 5760); re-connects when lost;
- ``tcpin:HOST:PORT``: TCP server; every connected client receives what is written and is
  read;
- serial: ``serial:DEVICE[:BAUD]``, ``DEVICE[,BAUD]`` for a ``/dev/...`` path (115200 baud
  when none is given).

``udp:`` is refused with a one-line error: pymavlink's ``udp:`` listens while MAVProxy's
``--out udp:`` sends, and this project used both meanings; the message says to write
``udpin:`` or ``udpout:``.

:class:`Link` is the one transport (asyncio protocols for UDP, TCP client/server and
serial): ``write`` never blocks (a stream whose kernel buffer is full drops the message and
counts ``backpressure``), bytes read are handed to a callback in the loop, errors are
counted by reason in ``Link.errors`` (and passed to an optional callback).

Signing (MAVLink 2): :func:`signing_key_from` (32 raw bytes, 64 hex digits or a passphrase →
SHA-256, as MAVProxy's ``signing setup``), :func:`signing_timestamp` (10 µs units since
2015-01-01), :func:`configure_signing` (sign everything sent and accept only correctly
signed messages) and :class:`MavReceiver` (parses bytes, classifies every rejected frame:
``unsigned``, ``bad_signature``, ``crc``, ``length``, ``garbage_bytes``, ``bad_data``,
``parse_error``).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import time
from collections.abc import Callable
from typing import Any, NamedTuple

from ins_hil.drivers.base import Backoff

SCHEMES = ("udpin", "udpout", "tcp", "tcpin", "serial")
DEFAULT_BAUD = 115200
#: seconds between 1970-01-01 and 2015-01-01 (MAVLink signing timestamps count from 2015)
SIGNING_EPOCH = 1420070400


def dialect() -> Any:
    """The MAVLink 2 dialect used everywhere (pymavlink's ardupilotmega ⊃ common)."""
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


# ------------------------------------------------------------------ URL grammar
class LinkUrl(NamedTuple):
    """A parsed link URL: ``scheme`` (udpin, udpout, tcp, tcpin, serial), ``host`` (or serial
    device), ``port`` (or baud)."""

    scheme: str
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.scheme}:{self.host}:{self.port}"

    @property
    def listens(self) -> bool:
        """True for the schemes that wait for the peer (udpin, tcpin)."""
        return self.scheme in ("udpin", "tcpin")


def parse_url(url: str) -> LinkUrl:
    """Parse a MAVLink link URL (module docstring); ValueError with a one-line reason otherwise."""
    if not isinstance(url, str) or not url.strip():
        raise ValueError(f"MAVLink url {url!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                         "tcpin:HOST:PORT or serial:DEVICE[:BAUD]")  # fmt: skip
    u = url.strip()
    if u.startswith("/"):  # MAVProxy/pymavlink: a device path, optionally ",BAUD"
        dev, sep, baud = u.rpartition(",")
        return _serial(url, dev, baud) if sep else _serial(url, u, "")
    scheme, sep, rest = u.partition(":")
    if not sep:
        raise ValueError(f"MAVLink url {url!r}: expected SCHEME:..., SCHEME one of {', '.join(SCHEMES)}")
    if scheme == "udp":
        raise ValueError(
            f"MAVLink url {url!r}: 'udp:' is ambiguous (pymavlink listens, MAVProxy --out sends): "
            f"write 'udpin:{rest}' to listen or 'udpout:{rest}' to send"
        )
    if scheme in ("udpin", "udpout", "tcp", "tcpin"):
        host, _, port = rest.rpartition(":")
        host = host[1:-1] if host.startswith("[") and host.endswith("]") else host  # [::1]
        if not host or not port.isdigit():
            raise ValueError(f"MAVLink url {url!r}: expected {scheme}:HOST:PORT")
        p = int(port)
        lo = 0 if scheme in ("udpin", "tcpin") else 1  # a listener may take any free port (0)
        if not lo <= p <= 65535:
            raise ValueError(f"MAVLink url {url!r}: port {p} out of range ({lo}..65535)")
        return LinkUrl(scheme, host, p)
    if scheme == "serial":  # the baud after the last ':' or ',' (by-path device names hold ':')
        if "," in rest:
            dev, _, baud = rest.rpartition(",")
            return _serial(url, dev, baud)
        dev, sep, baud = rest.rpartition(":")
        return _serial(url, dev, baud) if sep and baud.isdigit() else _serial(url, rest, "")
    raise ValueError(f"MAVLink url {url!r}: unknown scheme {scheme!r} (one of {', '.join(SCHEMES)})")


def _serial(url: str, dev: str, baud: str) -> LinkUrl:
    if not dev:
        raise ValueError(f"MAVLink url {url!r}: expected serial:DEVICE[:BAUD] or /dev/DEVICE[,BAUD]")
    if baud and (not baud.isdigit() or int(baud) == 0):
        raise ValueError(f"MAVLink url {url!r}: baud {baud!r} is not a positive number")
    return LinkUrl("serial", dev, int(baud or DEFAULT_BAUD))


# ------------------------------------------------------------------ signing
def signing_timestamp() -> int:
    """Current MAVLink signing timestamp (10 µs units since 2015-01-01 UTC)."""
    return int((time.time() - SIGNING_EPOCH) * 1e5)


def signing_key_from(value: str | bytes) -> bytes:
    """A 32-byte MAVLink 2 key: raw 32 bytes, 64 hex digits, or a passphrase (SHA-256, as MAVProxy's)."""
    if isinstance(value, bytes):
        if len(value) != 32:
            raise ValueError(f"MAVLink signing key must be 32 bytes, got {len(value)}")
        return value
    v = value.strip()
    if len(v) == 64:
        with contextlib.suppress(ValueError):
            return bytes.fromhex(v)
    if not v:
        raise ValueError("MAVLink signing key is empty")
    return hashlib.sha256(v.encode()).digest()


def configure_signing(mav: Any, key: bytes | None, link_id: int = 0, sign_outgoing: bool = True) -> None:
    """With ``key``: sign what ``mav`` sends (``link_id``, timestamp from now) and reject every
    incoming message that is not correctly signed with it. ``None``: leave ``mav`` unsigned."""
    if key is None:
        return
    s = mav.signing
    s.secret_key = key
    s.link_id = link_id
    s.timestamp = signing_timestamp()
    s.sign_outgoing = sign_outgoing
    s.allow_unsigned_callback = None  # unsigned → rejected


class MavReceiver:
    """MAVLink bytes → messages; with ``key`` (32 bytes) only correctly signed ones are accepted.

    ``feed(data)`` returns the decoded messages (pymavlink's ``UNKNOWN_<id>`` for message ids
    the dialect does not know). ``counts``: ``messages``, ``unsigned``, ``bad_signature`` and
    ``bad_data`` (any other rejected frame or run of garbage bytes); ``on_reject(reason, n)``,
    when given, receives the finer reason of every rejection: ``unsigned``, ``bad_signature``,
    ``crc``, ``length``, ``garbage_bytes`` (n = bytes), ``bad_data``, ``parse_error``.
    """

    def __init__(
        self, key: bytes | None = None, link_id: int = 0, on_reject: Callable[[str, int], None] | None = None
    ) -> None:
        self.mav = dialect().MAVLink(None, srcSystem=0, srcComponent=0)
        self.mav.robust_parsing = True
        configure_signing(self.mav, key, link_id, sign_outgoing=False)
        self.on_reject = on_reject
        self.counts: dict[str, int] = {"messages": 0, "unsigned": 0, "bad_signature": 0, "bad_data": 0}

    def _reject(self, reason: str, n: int = 1) -> None:
        k = reason if reason in ("unsigned", "bad_signature") else "bad_data"
        self.counts[k] += 1
        if self.on_reject is not None:
            self.on_reject(reason, n)

    def feed(self, data: bytes) -> list[Any]:
        out: list[Any] = []
        mav = self.mav
        s = mav.signing
        chunk: bytes = data
        while True:
            bad0 = s.badsig_count
            try:
                m = mav.parse_char(chunk)
            except Exception:  # pymavlink raises on some malformed input even when robust
                self._reject("parse_error")
                mav.buf = bytearray()
                mav.buf_index = 0
                return out
            chunk = b""
            if m is None:
                return out
            if m.get_type() == "BAD_DATA":
                reason = str(getattr(m, "reason", ""))
                if s.badsig_count > bad0:
                    self._reject("bad_signature")
                elif "signature" in reason:
                    self._reject("unsigned")
                elif "CRC" in reason:
                    self._reject("crc")
                elif "prefix" in reason:
                    self._reject("garbage_bytes", len(m.get_msgbuf()))
                elif "length" in reason:
                    self._reject("length")
                else:
                    self._reject("bad_data")
                continue
            self.counts["messages"] += 1
            out.append(m)


# ------------------------------------------------------------------ transport
class _Datagram(asyncio.DatagramProtocol):
    def __init__(self, link: Link) -> None:
        self.link = link

    def datagram_received(self, data: bytes, addr: Any) -> None:
        link = self.link
        if link.url.scheme == "udpin":
            old = link.peer
            link.peer = addr  # replies made while parsing go to this sender
            if link.on_data(data) is False and old is not None:
                link.peer = old  # no valid MAVLink in it: keep the previous peer
        else:
            link.on_data(data)

    def error_received(self, exc: Exception) -> None:  # ICMP port unreachable etc.
        self.link._error("refused" if isinstance(exc, ConnectionRefusedError) else "socket_error", exc)


class _Stream(asyncio.Protocol):
    def __init__(self, link: Link, client: bool = False) -> None:
        self.link = link
        self.client = client  # a client of our tcpin server
        self.transport: Any = None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport
        if self.client:
            self.link._clients.add(transport)

    def data_received(self, data: bytes) -> None:
        self.link.on_data(data)

    def connection_lost(self, exc: Exception | None) -> None:
        link = self.link
        if self.client:
            link._clients.discard(self.transport)
        elif self.transport is link._tr:
            link._tr = None
            if link.lost is not None and not link.lost.done():
                link.lost.set_result(f"connection lost: {exc}" if exc else "connection closed by the peer")


class Link:
    """One MAVLink transport over asyncio (module docstring): bytes in → ``on_data``, ``write`` out.

    ``on_data(data)`` is called in the loop for every datagram or chunk read; on ``udpin`` a
    return value of ``False`` (no valid MAVLink in it) keeps the previous peer. ``connect()``
    opens once (raises on failure); ``open()`` keeps it open: datagram and ``tcpin`` links
    open at once (raising), ``tcp`` and serial links connect in the background and re-connect
    with backoff (0.2 s … 5 s). ``lost`` resolves with a reason when a tcp/serial connection
    ends. ``errors`` counts by reason: ``refused``, ``socket_error``, ``backpressure``,
    ``tx_error``, ``connect_failed``, ``disconnected``.
    """

    def __init__(
        self,
        url: str | LinkUrl,
        on_data: Callable[[bytes], bool | None],
        on_error: Callable[[str], None] | None = None,
        max_buffer: int = 65536,
    ) -> None:
        self.url = url if isinstance(url, LinkUrl) else parse_url(url)
        self.on_data = on_data
        self.on_error = on_error
        self.max_buffer = max_buffer
        self.errors: dict[str, int] = {}
        self.last_error = ""
        self.peer: Any = None  # udpin: where replies go
        self.local_address: Any = None
        self.lost: asyncio.Future[str] | None = None
        self._tr: Any = None
        self._server: Any = None
        self._clients: set[Any] = set()
        self._task: asyncio.Task[None] | None = None

    # -- state -----------------------------------------------------------------
    @property
    def scheme(self) -> str:
        return self.url.scheme

    @property
    def connected(self) -> bool:
        """Bytes can go out: udpout/tcp/serial open, udpin with a known peer, tcpin with a client."""
        s = self.url.scheme
        if s == "udpin":
            return self._tr is not None and self.peer is not None
        if s == "tcpin":
            return bool(self._clients)
        return self._tr is not None

    def _error(self, reason: str, exc: BaseException | str | None = None) -> None:
        self.errors[reason] = self.errors.get(reason, 0) + 1
        if exc is not None:
            self.last_error = f"{self.url}: {reason}: {exc}"
        if self.on_error is not None:
            self.on_error(reason)

    # -- open / close ------------------------------------------------------------
    async def connect(self) -> None:
        """Open the transport once (bind, connect or open the device); raises on failure."""
        loop = asyncio.get_running_loop()
        self.lost = loop.create_future()
        self.peer = None
        scheme, host, port = self.url
        tr: Any
        if scheme == "udpin":
            tr, _ = await loop.create_datagram_endpoint(lambda: _Datagram(self), local_addr=(host, port))
        elif scheme == "udpout":
            tr, _ = await loop.create_datagram_endpoint(lambda: _Datagram(self), remote_addr=(host, port))
        elif scheme == "tcp":
            tr, _ = await loop.create_connection(lambda: _Stream(self), host, port)
        elif scheme == "tcpin":
            self._server = await loop.create_server(lambda: _Stream(self, client=True), host, port)
            self.local_address = self._server.sockets[0].getsockname()
            return
        else:
            import serial_asyncio_fast

            tr, _ = await serial_asyncio_fast.create_serial_connection(loop, lambda: _Stream(self), host, baudrate=port)
        self._tr = tr
        with contextlib.suppress(Exception):
            self.local_address = tr.get_extra_info("sockname")

    async def open(self) -> None:
        """Open and keep open (class docstring)."""
        if self.url.scheme in ("tcp", "serial"):
            self._task = asyncio.create_task(self.keep_open(), name=f"link {self.url}")
        else:
            await self.connect()

    async def keep_open(self, backoff: Backoff | None = None) -> None:
        """Connect, wait for the loss, re-connect with backoff; until cancelled."""
        bo = backoff or Backoff(0.2, 5.0)
        while True:
            try:
                await self.connect()
            except (OSError, ValueError) as e:
                self._error("connect_failed", e)
                await bo.wait()
                continue
            bo.reset()
            assert self.lost is not None
            why = await self.lost
            self._error("disconnected", why)

    def close(self) -> None:
        """Close the transport (and stop re-connecting)."""
        if self._task is not None:
            self._task.cancel()
            self._task = None
        for c in list(self._clients):
            c.close()
        self._clients.clear()
        if self._server is not None:
            self._server.close()
            self._server = None
        tr, self._tr = self._tr, None
        if tr is not None:
            tr.close()
        if self.lost is not None and not self.lost.done():
            self.lost.set_result("closed")

    # -- output ------------------------------------------------------------------
    def write(self, data: bytes) -> bool:
        """Send ``data`` without blocking; False if it could not go out (no peer, not connected,
        kernel buffer full: counted)."""
        s = self.url.scheme
        if s == "tcpin":
            sent = False
            for c in list(self._clients):
                if c.get_write_buffer_size() > self.max_buffer:
                    self._error("backpressure")
                    continue
                c.write(data)
                sent = True
            return sent
        tr = self._tr
        if tr is None:
            return False
        try:
            if tr.get_write_buffer_size() > self.max_buffer:  # slow link: drop rather than buffer without bound
                self._error("backpressure")
                return False
            if s == "udpout":
                tr.sendto(data)
            elif s == "udpin":
                if self.peer is None:
                    return False
                tr.sendto(data, self.peer)
            else:
                tr.write(data)
        except Exception as e:
            self._error("tx_error", e)
            return False
        return True
