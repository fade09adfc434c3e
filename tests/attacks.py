"""Payloads of the hostile-input attacks, built byte for byte, shared by the contract and integration tests."""
from __future__ import annotations

import struct

import msgpack

DEEP_ARGS_DEPTH = 500


def deep_args_command(depth: int = DEEP_ARGS_DEPTH) -> bytes:
    """The 576-byte Command whose `args` nest 500 lists deep: it raised RecursionError in the
    codec's `_plain` and ended the bridge, planner and smoother loops."""
    v: object = 1
    for _ in range(depth):
        v = [v]
    header = msgpack.packb({"t": "Command", "v": 1, "d": {"stamp_ns": 0, "seq": 0, "valid": True, "action": "hold",
                                                          "args": {"x": v}}}, use_bin_type=True)
    head = struct.pack("<3sBI", b"CTM", 1, len(header)) + header
    return head + b"\0" * ((-len(head)) % 16)


def with_header(payload: bytes, mutate) -> bytes:
    """`payload` with its msgpack header replaced by `mutate(header dict)` (array blobs kept)."""
    (hlen,) = struct.unpack_from("<I", payload, 4)
    start = 8 + hlen
    blob = payload[start + ((-start) % 16):]
    header = msgpack.unpackb(payload[8:start], raw=False)
    new = msgpack.packb(mutate(header), use_bin_type=True)
    head = struct.pack("<3sBI", b"CTM", 1, len(new)) + new
    return head + b"\0" * ((-len(head)) % 16) + blob
