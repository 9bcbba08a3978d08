"""The link's transport: one UDP MAVLink 2 endpoint (:class:`MavlinkEndpoint`: pack, sign, send; receive and parse
one datagram at a time, counting malformed, truncated, CRC-failed, unknown or wrongly signed datagrams), the
connection string (:func:`parse_connect`) and the telemetry log (:class:`TlogWriter`: every message sent and
received, an 8-byte big-endian microsecond UNIX timestamp + the raw bytes, readable by ``mavlogdump.py``; pymavlink's
own logging stays empty over UDP).

The transport is UDP only (``udpin:HOST:PORT`` listens, ``udpout:HOST:PORT`` sends first). A serial autopilot is
bridged with mavlink-router or MAVProxy (``--master=/dev/ttyACM0 --out=udpout:127.0.0.1:14540``)."""

from __future__ import annotations

import logging
import re
import socket
import struct
import threading
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link.errors import LinkError
from edge_explorer.runtime.mavlink_link.signing import signing_state

log = logging.getLogger(__name__)


_MAX_DATAGRAM_BYTES = 65535


class TlogWriter:
    """Appends MAVLink messages to a ``.tlog``: per message an 8-byte big-endian UNIX timestamp in µs + raw bytes."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._file = open(path, "wb")  # noqa: SIM115 - closed by close(); lives as long as the link
        self._lock = threading.Lock()
        self._last_flush_s = time.monotonic()

    def write(self, raw: bytes) -> None:
        stamp = struct.pack(">Q", int(time.time() * 1e6))
        with self._lock:
            if self._file.closed:
                return
            self._file.write(stamp + raw)
            if time.monotonic() - self._last_flush_s > 1.0:  # a crash loses at most a second of log
                self._file.flush()
                self._last_flush_s = time.monotonic()

    def close(self) -> None:
        with self._lock:
            self._file.close()


def parse_connect(connect: str) -> tuple[str, str, int]:
    """``udpin:HOST:PORT`` / ``udp:HOST:PORT`` (listen) or ``udpout:HOST:PORT`` (send first) → (mode, host, port)."""
    match = re.fullmatch(r"(udpin|udpout|udp):([^:]+|\[[0-9a-fA-F:]+\]):(\d+)", connect.strip())
    if not match:
        raise LinkError(
            f"unsupported MAVLink connection {connect!r}: use udpin:HOST:PORT (listen) or udpout:HOST:PORT (send); "
            "bridge a serial autopilot with mavlink-router or MAVProxy (--master=/dev/ttyACM0 "
            "--out=udpout:127.0.0.1:14540)"
        )
    scheme, host, port = match.groups()
    return ("udpout" if scheme == "udpout" else "udpin"), host.strip("[]"), int(port)


class MavlinkEndpoint:
    """One MAVLink 2 UDP endpoint: packs and sends messages, receives and parses one datagram at a time.

    Each datagram is parsed by a fresh parser, so a truncated datagram can never corrupt the next one; datagrams
    that yield no known, CRC-valid message (or leave bytes over) count in ``datagrams_bad``. With ``udpin`` the
    reply address follows the latest valid message from ``peer_system_id`` (any valid message when it is None), so
    garbage from another port cannot steal the link. Thread-safe: ``send`` and ``receive`` may run on different threads.
    """

    def __init__(
        self,
        connect: str,
        system_id: int,
        component_id: int,
        signing_key: bytes | None = None,
        tlog: TlogWriter | None = None,
        peer_system_id: int | None = None,
    ) -> None:
        mode, host, port = parse_connect(connect)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self._learns_remote = mode == "udpin"
        if self._learns_remote:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((host, port))
            self._remote: tuple | None = None
        else:
            self._sock.bind(("::" if family == socket.AF_INET6 else "0.0.0.0", 0))
            self._remote = socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM)[0][4]
        self._lock = threading.Lock()
        self._tlog = tlog
        self._peer_system_id = peer_system_id
        self._signing = signing_state(signing_key)
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.signing = self._signing
        self.datagrams_bad = 0
        self.signature_rejected = 0
        self.send_errors = 0

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]
        return host, port

    def send(self, msg: mavlink2.MAVLink_message) -> bool:
        """Pack (and sign) ``msg`` and send it; False when no peer is known yet (udpin before the first message)."""
        with self._lock:
            if self._remote is None:
                return False
            raw = bytes(msg.pack(self.mav))
            self.mav.seq = (self.mav.seq + 1) % 256
            try:
                self._sock.sendto(raw, self._remote)
            except OSError as exc:
                self.send_errors += 1
                log.debug("MAVLink send to %s failed: %s", self._remote, exc)
                return False
        if self._tlog is not None:
            self._tlog.write(raw)
        return True

    def receive(self, timeout_s: float) -> list[mavlink2.MAVLink_message]:
        """Messages of the next datagram (waits up to ``timeout_s``); [] on timeout or for a bad datagram."""
        self._sock.settimeout(timeout_s)
        try:
            data, address = self._sock.recvfrom(_MAX_DATAGRAM_BYTES)
        except (TimeoutError, BlockingIOError):
            return []
        except OSError as exc:  # e.g. ICMP port unreachable surfacing on some platforms
            log.debug("MAVLink receive error: %s", exc)
            return []
        with self._lock:
            messages, bad = self._parse(data)
            if bad:
                self.datagrams_bad += 1
            if self._learns_remote and self._is_peer(messages):
                self._remote = address
        if self._tlog is not None:
            for msg in messages:
                self._tlog.write(bytes(msg.get_msgbuf()))
        return messages

    def _parse(self, data: bytes) -> tuple[list[mavlink2.MAVLink_message], bool]:
        parser = mavlink2.MAVLink(None)
        parser.signing = self._signing
        parser.robust_parsing = True
        try:
            parsed = parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - pymavlink raises assorted errors on hostile input; the datagram is bad
            return [], True
        good = []
        bad = parser.buf_len() > 0  # a truncated trailing message
        for msg in parsed:
            if isinstance(msg, mavlink2.MAVLink_bad_data):
                bad = True
                if msg.reason == "Invalid signature":
                    self.signature_rejected += 1
            elif isinstance(msg, mavlink2.MAVLink_unknown):
                bad = True
            else:
                good.append(msg)
        return good, bad or not good

    def _is_peer(self, messages: list[mavlink2.MAVLink_message]) -> bool:
        """Whether valid ``messages`` come from the peer whose address replies go to (udpin only)."""
        if self._peer_system_id is None:
            return bool(messages)
        return any(m.get_srcSystem() == self._peer_system_id for m in messages)

    def close(self) -> None:
        self._sock.close()


def _enum_name(enum: str, value: int) -> str:
    entry = mavlink2.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum} {value}"
