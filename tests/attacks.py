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


def jpeg_bomb_frame(side: int = 30000) -> bytes:
    """A Frame of under 1 KB whose JPEG image declares side x side pixels, in its own frame header
    and in the message: decoding it cost the detector 28 s and 5.4 GB before sizes were checked."""
    import cv2
    import numpy as np

    from cinetransfer.shared import codec
    from cinetransfer.shared import messages as M

    small = M.Frame(stamp_ns=1, index=0, fps=24.0, image=np.full((10, 20, 3), 128, np.uint8))
    payload = bytearray(codec.encode(small, jpeg_quality=90))
    ok, jpg = cv2.imencode(".jpg", small.image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    at = payload.index(jpg.tobytes())
    sof = at + next(i for i in range(2, len(jpg) - 1) if jpg[i] == 0xFF and jpg[i + 1] == 0xC0)
    payload[sof + 5:sof + 9] = side.to_bytes(2, "big") * 2  # height, width

    def bigger(h: dict) -> dict:
        h["d"]["image"]["sh"] = [side, side, 3]
        return h

    return with_header(bytes(payload), bigger)
