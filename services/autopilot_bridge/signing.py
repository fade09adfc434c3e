"""MAVLink 2 message signing on a pymavlink connection (the key: shared/signing_key.py).

Outgoing messages are signed; incoming ones must carry a valid signature with a timestamp newer
than the last one seen on their stream (link id, system, component): anything else is dropped by
pymavlink before it is parsed, and counted (the connection's `mav.signing.reject_count`).

pymavlink 2.4.50 records a stream's timestamp *before* it checks the signature, so one forged
message with a far-future timestamp on the vehicle's stream would make every genuine message after
it 'old' (a denial of service by anyone who can reach the port). `verify_then_advance` replaces
that check on our connections: the signature first, the timestamp only once it is genuine.
"""
from __future__ import annotations

import hashlib
import types
from typing import Any

#: a new stream may start at most this far [10 us] behind our own timestamp (one minute)
NEW_STREAM_SLACK = 6000 * 1000


def _refuse_unsigned(_mav: Any, _msg_id: int) -> bool:
    # also called for a wrong signature: every refusal lands in signing.reject_count
    return False


def verify_then_advance(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """True when `msgbuf` (a whole signed MAVLink 2 frame) is genuine and newer than its stream's last."""
    signing = mav.signing
    digest = hashlib.sha256(signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if digest != bytes(msgbuf[-6:]):
        return False
    timestamp = int.from_bytes(bytes(msgbuf[-12:-6]), "little")
    stream = (msgbuf[-13], src_system, src_component)
    last = signing.stream_timestamps.get(stream)
    if (last is not None and timestamp <= last) or (last is None and timestamp + NEW_STREAM_SLACK < signing.timestamp):
        return False
    signing.stream_timestamps[stream] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True


def enable_signing(conn: Any, key: bytes, link_id: int = 0) -> None:
    conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=_refuse_unsigned, link_id=link_id)
    conn.mav.check_signature = types.MethodType(verify_then_advance, conn.mav)
