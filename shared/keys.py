"""Key expressions and the topic table — the only place key strings are spelled.

Every key is ``{root}/{rig}/{service}/{topic}``; `root` is "ct". One rig = one vehicle, so
several rigs can share a Zenoh network. The topic table gives, for each topic, its message
type, expected rate and queue policy; who writes and reads it is declared in
deploy/dataflow.yaml (shared/dataflow.py). Health checks and docs derive from both.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from cinetransfer.shared import messages as M

ROOT = "ct"
_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")


def rig_name(part: str) -> str:
    """`part` if it is a valid rig name; ValueError saying what is wrong otherwise."""
    return _check(part, "rig name")


def _check(part: str, what: str) -> str:
    if not _NAME.match(part):
        raise ValueError(f"invalid {what} {part!r}: use letters, digits, '_' or '-'")
    return part


@dataclass(frozen=True)
class Topic:
    service: str
    topic: str
    msg_type: type
    rate_hz: float  # expected rate; 0 = event-driven
    policy: str  # 'drop-oldest' (latest wins) or 'no-drop' (commands, whole sequences)
    doc: str

    def key(self, rig: str) -> str:
        return f"{ROOT}/{_check(rig, 'rig name')}/{self.service}/{self.topic}"


FRAME = Topic("camera", "frame", M.Frame, 24.0,
              "drop-oldest", "camera frames with the lens state they were taken with")
MEASUREMENT = Topic("detector", "measurement", M.Measurement, 24.0, "no-drop",
                    "people, skeletons and focus map of one frame")
INSTRUCTIONS = Topic("smoother", "instructions", M.Instructions, 2.0, "no-drop",
                     "recording instructions: a streaming window, or the whole sequence (final)")
SETPOINT = Topic("planner", "setpoint", M.Setpoint, 20.0, "drop-oldest",
                 "next state to track and the planned horizon")
PLANNER_COMMAND = Topic("planner", "command", M.Command, 0.0, "no-drop",
                        "start / pause / resume / stop a recording")
VEHICLE_STATE = Topic("vehicle", "state", M.VehicleState, 50.0, "drop-oldest",
                      "pose, velocity, gimbal, lens, mode")
SUBJECT_STATE = Topic("subject", "state", M.SubjectState, 50.0,
                      "drop-oldest", "3-D joints of the filmed subject")
BRIDGE_COMMAND = Topic("vehicle", "command", M.Command, 0.0, "no-drop",
                       "arm / takeoff / hold / land requests to the bridge")

SMOOTHER_COMMAND = Topic("smoother", "command", M.Command, 0.0, "no-drop",
                         "'end' (end of stream: publish the whole-sequence instructions) or 'reset'")

SIM_TRUTH = Topic("sim", "truth", M.GroundTruth, 24.0, "no-drop",
                  "exact ground truth of each rendered frame")

SOURCE_FRAME = Topic("source", "frame", M.Frame, 24.0, "no-drop",
                     "frames of the source clip whose style is imitated (never dropped: credit flow control)")
SOURCE_COMMAND = Topic("source", "command", M.Command, 0.0, "no-drop",
                       "'play' (args: path, stop) or 'stop' the source clip")
SOURCE_END = Topic("source", "end", M.StreamEnd, 0.0, "no-drop",
                   "end of the source clip's frames (how many were sent)")
DETECTOR_END = Topic("detector", "end", M.StreamEnd, 0.0, "no-drop",
                     "end of the measurements of one source stream (after its last frame)")
OUTPUT_MEASUREMENT = Topic("output", "measurement", M.Measurement, 24.0, "drop-oldest",
                           "live measurements of the drone's own camera (output-style view; never feeds the planner)")
SIM_CLOCK = Topic("sim", "clock", M.SimClock, 20.0, "no-drop",
                  "simulation time: one tick per control step; nodes that see it take 'now' from it")

TOPICS: tuple[Topic, ...] = (FRAME, MEASUREMENT, INSTRUCTIONS, SETPOINT, PLANNER_COMMAND, VEHICLE_STATE,
                             SUBJECT_STATE, BRIDGE_COMMAND, SIM_TRUTH, SMOOTHER_COMMAND, SIM_CLOCK,
                             SOURCE_FRAME, SOURCE_COMMAND, SOURCE_END, DETECTOR_END, OUTPUT_MEASUREMENT)


def health(rig: str, node: str) -> str:
    """Key of a node's periodic Health message."""
    return f"{ROOT}/{_check(rig, 'rig name')}/health/{_check(node, 'node name')}"


def alive(rig: str, node: str) -> str:
    """Key of a node's liveliness token."""
    return f"{ROOT}/{_check(rig, 'rig name')}/alive/{_check(node, 'node name')}"


def config(rig: str, node: str) -> str:
    """Key of a node's effective-config queryable."""
    return f"{ROOT}/{_check(rig, 'rig name')}/{_check(node, 'node name')}/config"


def all_alive(rig: str = "*") -> str:
    return f"{ROOT}/{rig}/alive/*"


def lease(rig: str, holder: str = "*") -> str:
    """Key of the liveliness token a take holds on its rig (one take at a time: cinetransfer/lease.py)."""
    return f"{ROOT}/{_check(rig, 'rig name')}/lease/{holder if holder == '*' else _check(holder, 'lease holder')}"


def everything(rig: str = "*") -> str:
    return f"{ROOT}/{rig}/**" if rig != "*" else f"{ROOT}/**"


def topic_for_key(key: str) -> Topic | None:
    """The topic-table entry a concrete key belongs to (None for health/alive/unknown keys)."""
    parts = key.split("/")
    if len(parts) != 4 or parts[0] != ROOT:
        return None
    for t in TOPICS:
        if parts[2] == t.service and parts[3] == t.topic:
            return t
    return None
