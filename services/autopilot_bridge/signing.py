"""MAVLink 2 message signing on a pymavlink connection (the key: shared/signing_key.py).

Outgoing messages are signed; incoming ones must carry a valid signature with a timestamp newer
than the last one seen from that link: anything else is dropped by pymavlink before it is
parsed, and counted (the connection's `mav.signing.reject_count`).
"""
from __future__ import annotations

from typing import Any


def _refuse_unsigned(_mav: Any, _msg_id: int) -> bool:
    # also called for a wrong signature: every refusal lands in signing.reject_count
    return False


def enable_signing(conn: Any, key: bytes, link_id: int = 0) -> None:
    conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=_refuse_unsigned, link_id=link_id)
