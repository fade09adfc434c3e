"""Settings of `cinetransfer sim-vehicle` (shared/nodeconfig.py: defaults, then `--config`, then flags)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.nodeconfig import setting

NODE = "sim-vehicle"
AUTOPILOTS = ("px4", "ardupilot")
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")


@dataclass(frozen=True)
class SimVehicleConfig:
    """The simulated vehicle's MAVLink endpoint, autopilot flavour, start and rates. Its limits and
    camera are the vehicle profile's (`vehicle`, or --vehicle)."""

    #: the keys settings files wrote before (named like the flags) -> the field
    SETTING_ALIASES: ClassVar[dict[str, str]] = {
        "rate": "rate_hz", "telemetry_rate": "telemetry_rate_hz", "telemetry-rate": "telemetry_rate_hz",
        "offboard_timeout": "offboard_timeout_s", "offboard-timeout": "offboard_timeout_s",
        "system-id": "system_id", "signing-key": "signing_key", "log-level": "log_level"}

    mavlink: str = setting("udpout:127.0.0.1:14540", flag="--mavlink", metavar="URL",
                           help="pymavlink endpoint (e.g. udpin:127.0.0.1:14550)")
    autopilot: str = setting("px4", flag="--autopilot", choices=AUTOPILOTS, help="autopilot to emulate")
    system_id: int = setting(1, flag="--system-id", range="[1, 255]", metavar="ID", help="MAVLink system id")
    start: tuple[float, float, float] = setting((0.0, 0.0, 0.0), flag="--start", unit="m", metavar="X,Y,Z",
                                                help="start position, world ENU z-up (default on the ground at home)")
    rate_hz: float = setting(100.0, flag="--rate", unit="Hz", range="> 0", metavar="HZ", help="physics rate")
    telemetry_rate_hz: float = setting(50.0, flag="--telemetry-rate", unit="Hz", range="> 0", metavar="HZ",
                                       help="LOCAL_POSITION_NED / ATTITUDE rate")
    offboard_timeout_s: float = setting(0.5, flag="--offboard-timeout", unit="s", range="> 0", metavar="S",
                                        help="PX4: leave OFFBOARD when no setpoint for this long")
    signing_key: str = setting("", flag="--signing-key", metavar="FILE",
                               help="MAVLink 2 signing key (cinetransfer deploy certs writes mavlink-signing.key)")
    #: vehicle profile (deploy/vehicles NAME or a path; '' = the default); --vehicle overrides it
    vehicle: str = ""
    log_level: str = setting("INFO", flag="--log-level", choices=LOG_LEVELS, help="log level")

    def validate(self) -> None:
        if len(self.start) != 3 or not all(math.isfinite(x) for x in self.start):
            raise ConfigError(f"{NODE} config: start={list(self.start)!r} is invalid; allowed: x, y, z "
                              "(3 finite numbers)")
        for name in ("rate_hz", "telemetry_rate_hz", "offboard_timeout_s"):
            if not math.isfinite(getattr(self, name)):
                raise ConfigError(f"{NODE} config: {name}={getattr(self, name)!r} is invalid; allowed: finite > 0")
