"""MAVLink 2 message signing: the 32-byte key (:func:`load_signing_key`, from 64 hex digits or a key file) and the
signing state of an endpoint (:func:`signing_state`). With a key, everything sent is signed, and unsigned or wrongly
signed messages are dropped and counted by the endpoint (``signature_rejected``)."""

from __future__ import annotations

import re
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from edge_explorer.runtime.mavlink_link.errors import LinkError

_SIGNING_EPOCH_UNIX_S = 1420070400  # MAVLink signing timestamps count 10 µs units from 2015-01-01


def load_signing_key(spec: str) -> bytes:
    """A 32-byte MAVLink 2 signing key from 64 hex digits, or from a file holding 32 raw bytes or 64 hex digits."""
    text = spec.strip()
    if re.fullmatch(r"[0-9a-fA-F]{64}", text):
        return bytes.fromhex(text)
    path = Path(text)
    if not path.is_file():
        raise LinkError(f"signing key {spec!r}: not 64 hex digits and no such file")
    data = path.read_bytes()
    if len(data) == 32:
        return data
    stripped = data.strip()
    if re.fullmatch(rb"[0-9a-fA-F]{64}", stripped):
        return bytes.fromhex(stripped.decode())
    raise LinkError(f"signing key file {path}: expected 32 raw bytes or 64 hex digits, found {len(data)} bytes")


def signing_state(key: bytes | None) -> mavlink2.MAVLinkSigning:
    """pymavlink's signing state for one endpoint: signs what it sends and checks what it receives when ``key`` is
    given (a 32-byte secret), off otherwise."""
    signing = mavlink2.MAVLinkSigning()
    if key is not None:
        if len(key) != 32:
            raise LinkError(f"MAVLink 2 signing keys are 32 bytes, got {len(key)}")
        signing.secret_key = key
        signing.sign_outgoing = True
        signing.timestamp = int((time.time() - _SIGNING_EPOCH_UNIX_S) * 100_000)
    return signing
