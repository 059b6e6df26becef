"""A lean MQTT 3.1.1 client for the fleet view: subscribe, read many messages per wake-up.

The fleet view receives every printer's status (1,000 printers: 1,000 messages a
second). A general client that handles one packet per socket event spends most
of the view's CPU on that; this one reads the socket in large chunks and parses
every complete packet in them. It speaks plain MQTT 3.1.1 (no v5 feature):
CONNECT with optional credentials, SUBSCRIBE (its SUBACK awaitable) and
UNSUBSCRIBE, PUBLISH in (QoS 0 and 1, acked) and out (QoS 1, for commands and
requests), PINGREQ keep-alive.
"""

from __future__ import annotations

import asyncio
import contextlib
import ssl
import struct
from collections.abc import AsyncIterator
from dataclasses import dataclass

CONNECT, CONNACK, PUBLISH, PUBACK, SUBSCRIBE, SUBACK = 1, 2, 3, 4, 8, 9
UNSUBSCRIBE = 10
PINGREQ, PINGRESP, DISCONNECT = 12, 13, 14
REFUSALS = {
    1: "unacceptable protocol version",
    2: "client identifier rejected",
    3: "server unavailable",
    4: "bad user name or password",
    5: "not authorised",
}


class WireError(OSError):
    """The connection failed, was refused or broke; the message says how."""


@dataclass(frozen=True)
class Incoming:
    """One PUBLISH received."""

    topic: str
    payload: bytes
    retain: bool


def _text(value: str) -> bytes:
    data = value.encode()
    return struct.pack("!H", len(data)) + data


def _packet(kind: int, flags: int, body: bytes) -> bytes:
    length = len(body)
    encoded = bytearray()
    while True:
        digit, length = length % 128, length // 128
        encoded.append(digit | (0x80 if length else 0))
        if not length:
            break
    return bytes([(kind << 4) | flags]) + bytes(encoded) + body


class WireClient:
    """One connection to a broker; use ``async with`` and iterate ``messages()``."""

    def __init__(self, host: str, port: int, *, client_id: str, username: str | None = None,
                 password: str | None = None, tls: ssl.SSLContext | None = None,
                 keepalive: int = 15, timeout: float = 10.0) -> None:
        self.host, self.port = host, port
        self.client_id = client_id
        self.username, self.password = username, password
        self.tls = tls
        self.keepalive = keepalive
        self.timeout = timeout
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._buffer = bytearray()
        self._next_id = 0
        self._pinger: asyncio.Task[None] | None = None
        self._subacks: dict[int, asyncio.Future[int]] = {}  # packet id -> granted QoS

    async def __aenter__(self) -> WireClient:
        try:
            async with asyncio.timeout(self.timeout):
                self._reader, self._writer = await asyncio.open_connection(
                    self.host, self.port, ssl=self.tls)
                self._send(self._connect_packet())
                kind, _, body = await self._read_packet()
        except (OSError, TimeoutError, ssl.SSLError, asyncio.IncompleteReadError) as exc:
            await self.__aexit__()
            raise WireError(f"cannot connect to {self.host}:{self.port}: {exc or 'timeout'}") \
                from exc
        if kind != CONNACK or len(body) < 2:
            await self.__aexit__()
            raise WireError(f"{self.host}:{self.port} did not answer CONNECT")
        if body[1] != 0:
            await self.__aexit__()
            reason = REFUSALS.get(body[1], f"code {body[1]}")
            raise WireError(f"{self.host}:{self.port} refused the connection: {reason}")
        self._pinger = asyncio.create_task(self._ping(), name="mqtt-ping")
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._pinger is not None:
            self._pinger.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pinger
        if self._writer is not None:
            with contextlib.suppress(OSError, RuntimeError):
                self._writer.write(_packet(DISCONNECT, 0, b""))
                self._writer.close()
                async with asyncio.timeout(2):
                    await self._writer.wait_closed()
            self._writer = None

    def _connect_packet(self) -> bytes:
        flags = 0x02  # clean session
        payload = _text(self.client_id)
        if self.username is not None:
            flags |= 0x80
            payload += _text(self.username)
            if self.password is not None:
                flags |= 0x40
                payload += _text(self.password)
        header = _text("MQTT") + bytes([4, flags]) + struct.pack("!H", self.keepalive)
        return _packet(CONNECT, 0, header + payload)

    def _send(self, data: bytes) -> None:
        if self._writer is None or self._writer.is_closing():
            raise WireError("not connected")
        self._writer.write(data)

    def _packet_id(self) -> int:
        self._next_id = self._next_id % 65535 + 1
        return self._next_id

    async def _ping(self) -> None:
        with contextlib.suppress(WireError):
            while True:
                await asyncio.sleep(self.keepalive / 2)
                self._send(_packet(PINGREQ, 0, b""))

    def subscribe(self, topic: str, qos: int = 0) -> asyncio.Future[int]:
        """Ask for ``topic`` (wildcards allowed). The SUBACK is read with the messages:
        the future returned gets its granted QoS (0x80: refused) while they are read."""
        packet_id = self._packet_id()
        body = struct.pack("!H", packet_id) + _text(topic) + bytes([qos])
        self._send(_packet(SUBSCRIBE, 0x02, body))
        acked: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._subacks[packet_id] = acked
        return acked

    def unsubscribe(self, topic: str) -> None:
        """Stop receiving ``topic`` (as it was subscribed)."""
        body = struct.pack("!H", self._packet_id()) + _text(topic)
        self._send(_packet(UNSUBSCRIBE, 0x02, body))

    async def publish(self, topic: str, payload: bytes, qos: int = 1,
                      retain: bool = False) -> None:
        """Send one message (QoS 0 or 1; commands are never retained)."""
        body = _text(topic) + (struct.pack("!H", self._packet_id()) if qos else b"") + payload
        self._send(_packet(PUBLISH, qos << 1 | int(retain), body))
        assert self._writer is not None
        await self._writer.drain()

    def _split(self) -> tuple[int, int, bytes] | None:
        """The first complete packet of the buffer (removed from it), or None."""
        buffer = self._buffer
        length, shift, pos = 0, 0, 1
        while True:
            if pos >= len(buffer):
                return None
            digit = buffer[pos]
            length |= (digit & 0x7F) << shift
            pos += 1
            if not digit & 0x80:
                break
            shift += 7
            if shift > 21:
                raise WireError("malformed packet length from the broker")
        if len(buffer) < pos + length:
            return None
        first = buffer[0]
        body = bytes(buffer[pos:pos + length])
        del buffer[:pos + length]
        return first >> 4, first & 0x0F, body

    async def _fill(self) -> None:
        assert self._reader is not None
        try:
            async with asyncio.timeout(self.keepalive * 1.5 + 5):
                data = await self._reader.read(1 << 16)
        except TimeoutError as exc:
            raise WireError(f"{self.host}:{self.port} went silent") from exc
        except OSError as exc:
            raise WireError(f"connection to {self.host}:{self.port} broke: {exc}") from exc
        if not data:
            raise WireError(f"{self.host}:{self.port} closed the connection")
        self._buffer += data

    async def _read_packet(self) -> tuple[int, int, bytes]:
        while (packet := self._split()) is None:
            await self._fill()
        return packet

    async def messages(self) -> AsyncIterator[Incoming]:
        """Every PUBLISH received, in order; QoS 1 ones are acknowledged."""
        while True:
            await self._fill()
            while (packet := self._split()) is not None:
                kind, flags, body = packet
                if kind != PUBLISH:
                    if kind == SUBACK and len(body) >= 3:
                        acked = self._subacks.pop(struct.unpack_from("!H", body)[0], None)
                        if acked is not None and not acked.done():
                            acked.set_result(body[2])
                    continue  # PUBACK, UNSUBACK, PINGRESP
                size = struct.unpack_from("!H", body)[0]
                topic = body[2:2 + size].decode(errors="replace")
                start = 2 + size
                if flags & 0x06:
                    self._send(_packet(PUBACK, 0, body[start:start + 2]))
                    start += 2
                yield Incoming(topic, body[start:], bool(flags & 0x01))
