"""A MAVLink spoofer, run as its own process: it claims to be the vehicle (system 1, component 1).

    python tests/mav_spoofer.py HOST:PORT SECONDS [--key FILE]

For SECONDS it sends, at 50 Hz, a PX4 HEARTBEAT (armed, POSCTL: 'the pilot took over') and a
LOCAL_POSITION_NED far from anywhere real (north 150 m, up 60 m), unsigned or signed with FILE
(a wrong key, for the signing test). It counts the messages that come back to it and prints
`{"sent": N, "received": M}` on exit.
"""
from __future__ import annotations

import json
import os
import socket
import sys
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mav  # noqa: E402


def main(argv: list[str]) -> int:
    host, port = argv[0].rsplit(":", 1)
    seconds = float(argv[1])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    out = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    if "--key" in argv:
        with open(argv[argv.index("--key") + 1]) as f:
            out.signing.secret_key = bytes.fromhex(f.read().strip())
        out.signing.sign_outgoing = True
        out.signing.timestamp = int((time.time() - 1420070400) * 1e5) + 10**9  # far 'newer' than the real link
    parser = mav.MAVLink(None)
    sent = received = 0
    t_end = time.monotonic() + seconds
    posctl = 3 << 16
    armed = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_SAFETY_ARMED
    while time.monotonic() < t_end:
        for msg in (mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, armed, posctl,
                                                  mav.MAV_STATE_ACTIVE, 3),
                    mav.MAVLink_local_position_ned_message(0, 150.0, 0.0, -60.0, 0.0, 0.0, 0.0)):
            sock.sendto(msg.pack(out), (host, int(port)))
            sent += 1
        deadline = time.monotonic() + 0.02
        while time.monotonic() < deadline:
            try:
                data = sock.recv(65535)
            except BlockingIOError:
                time.sleep(0.002)
                continue
            received += len(parser.parse_buffer(data) or [])
    print(json.dumps({"sent": sent, "received": received}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
