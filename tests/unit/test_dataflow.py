"""The declared dataflow: every topic has a writer, the main job's chain is closed, access rules
and the monitor derive from it."""
import pytest

from cinetransfer.shared import access, dataflow, keys
from cinetransfer.monitor import silent_keys


def test_every_topic_is_written_and_every_input_is_a_topic():
    flow = dataflow.load()
    for t in keys.TOPICS:
        assert flow.publishers(t), f"{dataflow.key_path(t)} has no writer"
    # the main job: source -> detector -> smoother -> planner -> bridge, and back to the planner
    assert flow.check(["source", "detector", "smoother", "planner", "autopilot_bridge"]) == []
    assert flow.subscribers(keys.SOURCE_FRAME) == ("detector",)
    assert flow.subscribers(keys.MEASUREMENT)[:2] == ("source", "smoother")  # credit, style
    # the drone's own camera never feeds the smoother: only the output view reads it
    assert "smoother" not in flow.subscribers(keys.FRAME) and "detector" not in flow.subscribers(keys.FRAME)


def test_access_rules_are_the_declared_outputs():
    flow = dataflow.load()
    for t in keys.TOPICS:
        assert access.PUBLISHERS[t] == flow.publishers(t)
    assert access.PUBLISHERS[keys.SETPOINT] == ("planner",)


def test_unknown_keys_and_malformed_files_are_refused():
    with pytest.raises(dataflow.DataflowError, match="unknown key 'planner/setpoints'"):
        dataflow.parse({"nodes": {"x": {"module": "m", "command": "c", "outputs": ["planner/setpoints"]}}})
    with pytest.raises(dataflow.DataflowError, match="lacks 'command'"):
        dataflow.parse({"nodes": {"x": {"module": "m"}}})


def test_monitor_marks_silent_declared_outputs_of_live_nodes():
    alive = ["ct/r1/alive/planner", "ct/r1/alive/autopilot_bridge", "ct/r1/alive/someone_else"]
    seen = {"ct/r1/vehicle/state", "ct/r1/camera/frame", "ct/r1/sim/truth"}
    silent = silent_keys(alive, seen)
    assert "ct/r1/planner/setpoint" in silent and "ct/r1/subject/state" in silent and "ct/r1/sim/clock" in silent
    assert "ct/r1/vehicle/state" not in silent
    assert not [k for k in silent if k.endswith("/end")]  # event-driven keys are quiet by nature


def test_command_tool_parses_typed_arguments():
    from cinetransfer.command import parse_args_kv

    assert parse_args_kv(["path=/a b.mp4", "stop=120", "preroll_s=2.5", "fast=true"]) == \
        {"path": "/a b.mp4", "stop": 120, "preroll_s": 2.5, "fast": True}
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_args_kv(["oops"])
