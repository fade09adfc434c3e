"""Which MAVLink peer the bridge listens to: the configured vehicle and nothing else.

- Ids: the vehicle is `target_system` / `target_component` when configured, else the first
  autopilot HEARTBEAT's. Messages from other systems, and from components of the vehicle's system
  that are neither its autopilot, its camera nor a camera or gimbal component id, are ignored and
  counted.
- Address (udpin): a listening UDP socket hears anyone who can reach its port. The first source
  address that sends the vehicle's HEARTBEAT becomes the only one heard and the only one sent to
  (pymavlink would otherwise answer every address that ever wrote to the port); datagrams from
  any other address are dropped unparsed and counted.
- Signing: with a MAVLink 2 signing key (signing.py) unsigned or wrongly signed messages are
  dropped by pymavlink; they are counted from its signing statistics.
"""
from __future__ import annotations

import collections
import errno
import socket
from typing import Any

#: MAV_COMP_ID_CAMERA..CAMERA6, MAV_COMP_ID_GIMBAL and GIMBAL2..6: the vehicle's payload may speak
#: for itself (a camera's telemetry is heard before its HEARTBEAT names it the camera)
PAYLOAD_COMPONENTS = frozenset({100, 101, 102, 103, 104, 105, 154, 171, 172, 173, 174, 175})


class VehicleLock:
    """Filters what the bridge hears (see the module docstring)."""

    def __init__(self, target_system: int, target_component: int) -> None:
        self.system = target_system
        self.component = target_component
        self.address: tuple[str, int] | None = None
        self.rx_address: tuple[str, int] | None = None  # source of the datagram being parsed
        self.foreign: collections.Counter[str] = collections.Counter()
        self.conn: Any = None

    # ------------------------------------------------------------------ address (udpin)
    def attach(self, conn: Any) -> None:
        """Filter a listening UDP connection's datagrams by source address (no-op for others)."""
        self.conn = conn
        if not getattr(conn, "udp_server", False):
            return
        conn.recv = self._recv_udp
        if self.address is not None:
            conn.clients = {self.address}

    def _recv_udp(self, n: int | None = None) -> bytes | str:
        conn = self.conn
        while True:
            try:
                data, addr = conn.port.recvfrom(65535)
            except socket.error as e:
                if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                    return ""
                raise
            if self.address is None or addr == self.address:
                self.rx_address = addr
                if self.address is None:
                    conn.clients.add(addr)
                return data
            self.foreign["address"] += 1

    def lock_address(self) -> None:
        """The vehicle's HEARTBEAT just arrived: lock to where it came from (udpin)."""
        if self.address is None and self.rx_address is not None and getattr(self.conn, "udp_server", False):
            self.address = self.rx_address
            self.conn.clients = {self.address}

    # ------------------------------------------------------------------ ids
    def is_vehicle_heartbeat(self, system: int, component: int) -> bool:
        """An autopilot HEARTBEAT (the caller checked its type): the vehicle's? The first one
        heard names the vehicle when no ids are configured."""
        if self.system == 0:
            self.system = system
        if self.component == 0 and system == self.system:
            self.component = component
        return system == self.system and component == self.component

    def accepts(self, system: int, component: int, camera_component: int) -> bool:
        """A message from the vehicle (autopilot, camera or gimbal); counts what it rejects once
        the vehicle is known."""
        if self.system == 0:
            return False
        if system == self.system and (component in (self.component, camera_component)
                                      or component in PAYLOAD_COMPONENTS):
            return True
        self.foreign["system" if system != self.system else "component"] += 1
        return False

    def counters(self, conn: Any) -> dict[str, int]:
        out = {"mav_foreign_address": self.foreign["address"], "mav_foreign_system": self.foreign["system"],
               "mav_foreign_component": self.foreign["component"]}
        signing = getattr(getattr(conn, "mav", None), "signing", None)
        if signing is not None and signing.secret_key is not None:
            out["mav_signature_rejected"] = int(signing.reject_count)
        return out
