"""Configuration of the autopilot_bridge service, its safety layer and its MAVLink backend.

Three frozen dataclasses, each validated on construction (`validate()` names the field and
its allowed values). Units are in the field names; frames are the world frame of
cinetransfer.shared.messages (z up, metres, radians) unless stated.

    SafetyConfig   limits every backend shares (geofence, altitude band, speed, acceleration,
                   subject distance, gimbal and lens ranges, watchdog)
    MavlinkConfig  link, autopilot flavour, stream rates, link-loss detection
    BridgeConfig   backend choice, loop rate, scene, frame encoding + the two above
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.nodeconfig import setting
from cinetransfer.shared.obstacles import obstacles_setting
from cinetransfer.shared.signing_key import read_signing_key
from cinetransfer.shared.limits import (EnvelopeLimits, GimbalLimits, LensLimits, MotionLimits, profile_default,
                                        vehicle_fields)
from cinetransfer.shared.vehicle import GEOFENCE_SHAPES, VehicleProfile, load_vehicle

BACKENDS = ("sim", "mavlink")
AUTOPILOTS = ("auto", "px4", "ardupilot")
SIM_CLOCKS = ("lockstep", "realtime")


def _finite(name: str, v: float) -> None:
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
        raise ConfigError(f"{name} = {v!r}: must be a finite number")


def _positive(name: str, v: float) -> None:
    _finite(name, v)
    if v <= 0:
        raise ConfigError(f"{name} = {v!r}: must be > 0")


def _range(lo_name: str, lo: float, hi_name: str, hi: float) -> None:
    _finite(lo_name, lo)
    _finite(hi_name, hi)
    if not lo < hi:
        raise ConfigError(f"{lo_name} = {lo!r} must be < {hi_name} = {hi!r}")


@dataclass(frozen=True)
class SafetyConfig(LensLimits, GimbalLimits, EnvelopeLimits, MotionLimits):
    """Limits the bridge enforces on every setpoint, whatever the backend.

    The vehicle's limits (envelope, speed, acceleration, gimbal and lens ranges) come from its
    profile (`from_vehicle`, shared/vehicle.py): the planner plans within the same numbers and
    the simulator flies them. The defaults are the default profile's (deploy/vehicles/cinempc.yaml).
    The planner bounds each axis of v and a; the safety layer bounds their norm (what the
    simulated autopilot saturates too). The limit fields are declared once in shared/limits.py
    under the profile's names; the ones with a flag are declared again here for it.
    SETTING_ALIASES are the earlier spellings settings files may use.

    Besides the fields below: `climb_max_mps` clamps the vertical velocity feed-forward and how
    fast the commanded position may move up or down; the gimbal band (`pitch_min_rad`,
    `pitch_max_rad`, `roll_max_rad`) and the lens ranges (`focal_length_*_mm`,
    `focus_distance_*_m`, `f_number_*`) clamp the camera setpoint.
    """

    SETTING_ALIASES: ClassVar[dict[str, str]] = {
        "max_speed_mps": "speed_max_mps", "max_climb_mps": "climb_max_mps", "max_accel_mps2": "accel_max_mps2",
        "gimbal_pitch_min_rad": "pitch_min_rad", "gimbal_pitch_max_rad": "pitch_max_rad",
        "gimbal_roll_max_rad": "roll_max_rad", "focus_min_m": "focus_distance_min_m",
        "focus_max_m": "focus_distance_max_m"}

    #: home point [m], world frame: centre of the geofence; altitudes are measured from its z.
    home_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), flag="--home", unit="m", metavar="X,Y,Z",
                                                 help="geofence centre, world frame")
    #: 'cylinder' (radius around home, in x/y) or 'box' (x/y half-extents around home).
    geofence_shape: str = setting(default_factory=profile_default("geofence_shape"), flag="--geofence",
                                  choices=GEOFENCE_SHAPES, help="geofence shape")
    #: cylinder radius [m] (shape 'cylinder'), 1..10000.
    geofence_radius_m: float = setting(default_factory=profile_default("geofence_radius_m"), flag="--geofence-radius",
                                       unit="m", metavar="M",
                                       help="cylinder radius around home")
    #: box half-extents (x, y) [m] around home (shape 'box').
    geofence_half_extent_m: tuple[float, float] = setting(default_factory=profile_default("geofence_half_extent_m"),
                                                          flag="--geofence-half-extent", unit="m", metavar="X,Y",
                                                          help="box half-extents around home")
    #: altitude band above home [m]: setpoints below/above are clamped.
    altitude_min_m: float = setting(default_factory=profile_default("altitude_min_m"), flag="--alt-min", unit="m",
                                    metavar="M", help="altitude band above home")
    altitude_max_m: float = setting(default_factory=profile_default("altitude_max_m"), flag="--alt-max", unit="m",
                                    metavar="M", help="altitude band above home")
    #: speed limit [m/s]: clamps the velocity feed-forward AND how fast the commanded position
    #: may move (a jump in the position setpoint is approached at this speed).
    speed_max_mps: float = setting(default_factory=profile_default("speed_max_mps"), flag="--max-speed", unit="m/s",
                                   metavar="M/S", help="speed limit")
    #: acceleration limit [m/s^2]: clamps the acceleration feed-forward and the change of the
    #: velocity feed-forward between ticks.
    accel_max_mps2: float = setting(default_factory=profile_default("accel_max_mps2"), flag="--max-accel",
                                    unit="m/s^2", metavar="M/S2", help="acceleration limit")
    #: minimum horizontal distance [m] between the commanded position and the subject's centre
    #: (CineMPC: 2 m, DESIGN §4); 0 disables.
    min_subject_distance_m: float = setting(default_factory=profile_default("min_subject_distance_m"),
                                            flag="--min-subject-distance", unit="m", metavar="M",
                                            help="minimum horizontal distance to the subject; 0 disables")
    #: keep-out obstacles, each [x_m, y_m, radius_m, z_min_m, z_max_m] in the world frame (shared/obstacles.py): the
    #: measured vehicle nearer than `min_obstacle_distance_m` to one's surface (by more than the breach tolerance) is
    #: an envelope breach. The transfer gives the scene's own (sim/obstacles.py).
    obstacles_m: tuple[tuple[float, ...], ...] = ()
    #: subject state older than this [s] is ignored by the distance rule.
    subject_timeout_s: float = 1.0
    #: watchdog [s]: no fresh accepted setpoint for this long -> hold position.
    watchdog_timeout_s: float = setting(0.5, flag="--watchdog", unit="s", metavar="S",
                                        help="hold when no fresh setpoint for this long")
    #: the measured vehicle counts as outside the envelope (geofence or altitude band) once it is
    #: more than this [m] beyond it (tracking noise at the fence is not a breach), 0..10.
    breach_tolerance_m: float = 0.25
    #: on a breach the bridge commands the nearest point this far [m] inside the envelope and
    #: ignores the plan until the vehicle is half this far inside (PX4-style geofence return), 0..50.
    breach_return_margin_m: float = 1.0
    #: a setpoint stamped more than this [s] after the bridge's clock is rejected (clock skew
    #: between the planner's machine and the bridge's must stay below it), 0..60.
    max_stamp_ahead_s: float = 1.0

    def __post_init__(self) -> None:
        self.validate()

    @classmethod
    def from_vehicle(cls, v: VehicleProfile, **changes: Any) -> "SafetyConfig":
        """The vehicle's envelope and limits (the planner and the simulator read the same numbers)."""
        return cls(**{**vehicle_fields(cls, v), **changes})

    def validate(self) -> None:
        self._validate_envelope()
        self._validate_gimbal_and_lens()
        _positive("watchdog_timeout_s", self.watchdog_timeout_s)
        for name, hi in (("breach_tolerance_m", 10.0), ("breach_return_margin_m", 50.0),
                         ("max_stamp_ahead_s", 60.0)):
            v = getattr(self, name)
            _finite(name, v)
            if not 0 <= v <= hi:
                raise ConfigError(f"{name} = {v!r}: must be in [0, {hi}]")

    def _validate_envelope(self) -> None:
        if len(self.home_m) != 3:
            raise ConfigError(f"home_m = {self.home_m!r}: needs 3 values (x, y, z)")
        for i, v in enumerate(self.home_m):
            _finite(f"home_m[{i}]", v)
        if self.geofence_shape not in GEOFENCE_SHAPES:
            raise ConfigError(f"geofence_shape = {self.geofence_shape!r}: must be one of {GEOFENCE_SHAPES}")
        _positive("geofence_radius_m", self.geofence_radius_m)
        if len(self.geofence_half_extent_m) != 2:
            raise ConfigError("geofence_half_extent_m needs 2 values (x, y)")
        for i, v in enumerate(self.geofence_half_extent_m):
            _positive(f"geofence_half_extent_m[{i}]", v)
        _range("altitude_min_m", self.altitude_min_m, "altitude_max_m", self.altitude_max_m)
        _positive("speed_max_mps", self.speed_max_mps)
        _positive("climb_max_mps", self.climb_max_mps)
        _positive("accel_max_mps2", self.accel_max_mps2)
        _finite("min_subject_distance_m", self.min_subject_distance_m)
        if self.min_subject_distance_m < 0:
            raise ConfigError("min_subject_distance_m must be >= 0 (0 disables)")
        _finite("min_obstacle_distance_m", self.min_obstacle_distance_m)
        if self.min_obstacle_distance_m < 0:
            raise ConfigError("min_obstacle_distance_m must be >= 0")
        object.__setattr__(self, "obstacles_m", obstacles_setting(self.obstacles_m))
        _positive("subject_timeout_s", self.subject_timeout_s)

    def _validate_gimbal_and_lens(self) -> None:
        _range("pitch_min_rad", self.pitch_min_rad, "pitch_max_rad", self.pitch_max_rad)
        if self.pitch_min_rad < -math.pi / 2 - 1e-9 or self.pitch_max_rad > math.pi / 2 + 1e-9:
            raise ConfigError("gimbal pitch band must lie within [-pi/2, pi/2]")
        _finite("roll_max_rad", self.roll_max_rad)
        if not 0 <= self.roll_max_rad <= math.pi / 2:
            raise ConfigError("roll_max_rad must be in [0, pi/2]")
        _range("focal_length_min_mm", self.focal_length_min_mm, "focal_length_max_mm", self.focal_length_max_mm)
        _range("focus_distance_min_m", self.focus_distance_min_m, "focus_distance_max_m", self.focus_distance_max_m)
        _range("f_number_min", self.f_number_min, "f_number_max", self.f_number_max)
        if self.focal_length_min_mm <= 0 or self.focus_distance_min_m <= 0 or self.f_number_min <= 0:
            raise ConfigError("lens lower limits must be > 0")


@dataclass(frozen=True)
class MavlinkConfig:
    """The MAVLink link to a PX4 / ArduPilot flight controller (or `cinetransfer sim-vehicle`)."""

    #: pymavlink connection string: 'udpin:0.0.0.0:14540' (listen), 'udpout:127.0.0.1:14550'
    #: (send first), 'tcp:127.0.0.1:5760', '/dev/ttyACM0' (serial, see baud_rate).
    url: str = setting("udpin:127.0.0.1:14540", flag="--mavlink", metavar="URL", help="pymavlink connection string")
    baud_rate: int = 921600
    #: 'px4' (OFFBOARD), 'ardupilot' (GUIDED) or 'auto' (from the vehicle's HEARTBEAT).
    autopilot: str = setting("auto", flag="--autopilot", choices=AUTOPILOTS, help="autopilot flavour")
    #: our own MAVLink ids (an onboard computer: MAV_COMP_ID_ONBOARD_COMPUTER = 191).
    source_system: int = 245
    source_component: int = 191
    #: vehicle ids; 0 = take them from the first autopilot HEARTBEAT.
    target_system: int = setting(0, flag="--target-system", help="vehicle system id; 0 = from its HEARTBEAT")
    target_component: int = 0
    #: camera / gimbal component ids; 0 = send to the autopilot component (it forwards).
    camera_component: int = 0
    gimbal_device_id: int = 0
    #: rate of the SET_POSITION_TARGET_LOCAL_NED stream [Hz] (PX4 OFFBOARD needs > 2 Hz).
    setpoint_rate_hz: float = setting(20.0, flag="--setpoint-rate", unit="Hz", metavar="HZ",
                                      help="rate of the setpoint stream")
    #: most lens commands (zoom / focus / aperture) sent per second, per parameter [Hz].
    lens_command_rate_hz: float = 5.0
    #: rate of our HEARTBEAT [Hz].
    heartbeat_rate_hz: float = 1.0
    #: telemetry rates we ask the vehicle for (MAV_CMD_SET_MESSAGE_INTERVAL) [Hz]; 0 = don't ask.
    telemetry_rate_hz: float = 50.0
    #: nothing (HEARTBEAT or telemetry) from the vehicle for this long [s] -> link lost
    #: (VehicleState invalid, hold). The link comes back with the next HEARTBEAT.
    link_timeout_s: float = setting(1.5, flag="--link-timeout", unit="s", metavar="S",
                                    help="nothing from the vehicle for this long: link lost")
    #: link lost for this long [s] -> close and reopen the connection (then every period).
    reopen_period_s: float = 3.0
    #: wait at most this long [s] in start() for the first HEARTBEAT.
    connect_timeout_s: float = setting(10.0, flag="--connect-timeout", unit="s", metavar="S",
                                       help="wait this long at start for the first HEARTBEAT")
    #: after a link loss, re-enter OFFBOARD/GUIDED by itself once the link is back (else wait
    #: for an 'engage' command).
    reengage_after_link_loss: bool = setting(False, flag="--reengage",
                                             help="re-enter OFFBOARD/GUIDED by itself after a link loss")
    #: arm and switch to OFFBOARD/GUIDED on start (also: the 'engage' bridge command).
    engage_on_start: bool = setting(False, flag="--engage",
                                    help="arm and enter OFFBOARD/GUIDED at start (else wait for an 'engage' command)")
    #: ArduPilot needs a take-off when landed before GUIDED position targets move it [m].
    takeoff_altitude_m: float = 3.0
    #: offset of the autopilot's local NED origin in the world frame [m] (ENU, z up).
    local_origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: camera sensor [mm]: converts CAMERA_FOV_STATUS's field of view to a focal length (the
    #: vehicle profile's: the service builds these four from it, the defaults are the default profile's).
    sensor_width_mm: float = field(default_factory=lambda: load_vehicle().camera.sensor_width_mm)
    sensor_height_mm: float = field(default_factory=lambda: load_vehicle().camera.sensor_height_mm)
    coc_mm: float = field(default_factory=lambda: load_vehicle().camera.coc_mm)  # derived from the sensor width
    #: the lens's focal-length range [mm]: zoom by range (0..100 %) maps onto it.
    focal_length_range_mm: tuple[float, float] = field(default_factory=lambda: load_vehicle().lens.focal_length_mm)
    #: a lens or land command without acknowledgement is resent this many times, every
    #: command_retry_s [s]; then a lens axis is unsupported, a land falls back to the land mode.
    command_retries: int = 3
    command_retry_s: float = 1.0
    #: MAVLink 2 signing key file ('cinetransfer deploy certs' writes mavlink-signing.key); '' = unsigned.
    signing_key_file: str = ""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        self._validate_camera_and_retries()
        if not self.url or not isinstance(self.url, str):
            raise ConfigError("mavlink url must be a pymavlink connection string, e.g. udpin:0.0.0.0:14540")
        if self.autopilot not in AUTOPILOTS:
            raise ConfigError(f"autopilot = {self.autopilot!r}: must be one of {AUTOPILOTS}")
        for name in ("source_system", "source_component", "target_system", "target_component",
                     "camera_component", "gimbal_device_id"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 0 <= v <= 255:
                raise ConfigError(f"{name} = {v!r}: must be an integer in 0..255")
        if self.source_system == 0:
            raise ConfigError("source_system must be 1..255")
        _positive("setpoint_rate_hz", self.setpoint_rate_hz)
        if self.setpoint_rate_hz <= 2.0:
            raise ConfigError("setpoint_rate_hz must be > 2 Hz (PX4 leaves OFFBOARD below that)")
        _positive("heartbeat_rate_hz", self.heartbeat_rate_hz)
        _positive("lens_command_rate_hz", self.lens_command_rate_hz)
        _finite("telemetry_rate_hz", self.telemetry_rate_hz)
        if self.telemetry_rate_hz < 0:
            raise ConfigError("telemetry_rate_hz must be >= 0")
        _positive("link_timeout_s", self.link_timeout_s)
        _positive("reopen_period_s", self.reopen_period_s)
        _positive("connect_timeout_s", self.connect_timeout_s)
        _positive("takeoff_altitude_m", self.takeoff_altitude_m)
        _positive("baud_rate", self.baud_rate)
        if len(self.local_origin_m) != 3:
            raise ConfigError("local_origin_m needs 3 values")
        _positive("sensor_width_mm", self.sensor_width_mm)
        _positive("sensor_height_mm", self.sensor_height_mm)
        _positive("coc_mm", self.coc_mm)

    def _validate_camera_and_retries(self) -> None:
        if len(self.focal_length_range_mm) != 2:
            raise ConfigError("focal_length_range_mm needs 2 values (min, max)")
        _range("focal_length_range_mm[0]", self.focal_length_range_mm[0], "focal_length_range_mm[1]",
               self.focal_length_range_mm[1])
        if not isinstance(self.command_retries, int) or isinstance(self.command_retries, bool) or \
                not 0 <= self.command_retries <= 20:
            raise ConfigError(f"command_retries = {self.command_retries!r}: must be an integer in 0..20")
        _positive("command_retry_s", self.command_retry_s)
        if not isinstance(self.signing_key_file, str):
            raise ConfigError("signing_key_file must be a path (or '' for unsigned MAVLink)")
        if self.signing_key_file:
            read_signing_key(self.signing_key_file)  # a missing or malformed key is refused at start


@dataclass(frozen=True)
class BridgeConfig:
    """The autopilot_bridge node."""

    #: 'sim' (built-in simulator, the default) or 'mavlink' (flight controller / sim-vehicle).
    backend: str = setting("sim", flag="--backend", choices=BACKENDS, help="vehicle backend")
    #: simulator scene: a bundled scene name or a path to a scene file (sim backend only).
    scene: str = setting("lawn_juggler", flag="--scene", help="simulator scene name or file (sim backend)")
    #: simulator subject: a person from the subject library in place of the scene's own ('' = the scene's).
    subject: str = setting("", flag="--subject", help="simulator subject from the library in place of the scene's")
    #: vehicle profile (deploy/vehicles NAME or a path; '' = the default): the simulator flies it;
    #: `safety` and `mavlink`'s sensor are built from it by the service.
    vehicle: str = ""
    #: control loop rate [Hz]: setpoints are checked, the backend stepped and state published.
    rate_hz: float = setting(50.0, flag="--rate", unit="Hz", metavar="HZ", help="control loop rate")
    #: publish frames as JPEG of this quality (1..100) for a radio link; 0 = raw (one host).
    jpeg_quality: int = setting(0, flag="--jpeg", metavar="QUALITY",
                                help="publish frames as JPEG of this quality (radio links); 0 = raw")
    #: publish VehicleState every n-th tick (1 = every tick).
    state_every_n: int = 1
    #: sim backend: 'lockstep' (the bridge owns simulation time, steps wait for the planner,
    #: no frame is ever skipped) or 'realtime' (wall clock, late frames skipped and counted).
    sim_clock: str = setting("lockstep", flag="--realtime", const="realtime",
                             help="sim backend: run on the wall clock (frames may be skipped) instead of owning "
                                  "simulation time in lockstep with the planner")
    #: sim clock: simulated seconds per control step (one planner setpoint per step).
    step_s: float = setting(0.05, flag="--step", unit="s", metavar="S",
                            help="sim clock: simulated seconds per control step (0.05 = the planner's 20 Hz)")
    #: sim clock: simulated seconds per wall second to aim at; 0 = as fast as possible.
    pace: float = setting(1.0, flag="--pace", metavar="X",
                          help="sim clock: simulated seconds per wall second to aim at (0 = as fast as possible)")
    #: sim clock: render camera frames before the first 'reset' (a transfer's own deployment
    #: idles until its take resets the simulation: nobody records those frames).
    frames_before_reset: bool = setting(True, flag="--no-frames-before-reset",
                                        help="sim clock: render no camera frame until the first 'reset' "
                                             "(truth and states still flow)")
    #: sim clock: longest wall wait [s] for the planner's setpoint of a step (counted when hit).
    setpoint_wait_s: float = setting(30.0, flag="--setpoint-wait", unit="s", metavar="S",
                                     help="sim clock: longest wall wait for the planner's setpoint of a step")
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        if self.backend not in BACKENDS:
            raise ConfigError(f"backend = {self.backend!r}: must be one of {BACKENDS}")
        _positive("rate_hz", self.rate_hz)
        if self.rate_hz > 1000:
            raise ConfigError("rate_hz must be <= 1000")
        if not isinstance(self.jpeg_quality, int) or not 0 <= self.jpeg_quality <= 100:
            raise ConfigError(f"jpeg_quality = {self.jpeg_quality!r}: must be 0 (raw) or 1..100")
        if not isinstance(self.state_every_n, int) or self.state_every_n < 1:
            raise ConfigError("state_every_n must be an integer >= 1")
        if self.sim_clock not in SIM_CLOCKS:
            raise ConfigError(f"sim_clock = {self.sim_clock!r}: must be one of {SIM_CLOCKS}")
        _positive("step_s", self.step_s)
        if self.step_s > 1.0:
            raise ConfigError(f"step_s = {self.step_s!r}: must be <= 1 s")
        _finite("pace", self.pace)
        if not 0 <= self.pace <= 1000:
            raise ConfigError(f"pace = {self.pace!r}: must be in 0..1000 (0 = as fast as possible)")
        _positive("setpoint_wait_s", self.setpoint_wait_s)
        # the take-off altitude is a command argument like any other: inside the same altitude band
        lo, hi = self.safety.altitude_min_m, self.safety.altitude_max_m
        if not lo <= self.mavlink.takeoff_altitude_m <= hi:
            raise ConfigError(f"mavlink.takeoff_altitude_m = {self.mavlink.takeoff_altitude_m!r}: must lie in the "
                              f"safety altitude band [{lo}, {hi}] m")


def replace_nested(cfg: Any, **changes: Any) -> Any:
    """dataclasses.replace that re-validates (frozen configs validate in __post_init__)."""
    return dataclasses.replace(cfg, **changes)
