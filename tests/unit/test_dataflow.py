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


def _cli_module_path(command: str) -> str:
    """The source file `cinetransfer COMMAND` runs (pyproject's package-dir mapping)."""
    from cinetransfer.cli import COMMANDS

    parts = COMMANDS[command][0].split(".")
    root = {"shared": "shared", "services": "services", "deploy": "deploy"}.get(parts[1], "cinetransfer")
    rest = parts[2:] if root != "cinetransfer" else parts[1:]
    return "/".join([root, *rest]) + ".py"


def test_the_cli_and_the_dataflow_list_the_same_nodes():
    """Every declared node is a CLI command running the module the dataflow names, and every CLI
    command that joins the bus as a node (shared.node's node_from_args) is declared."""
    from conftest import REPO

    from cinetransfer.cli import COMMANDS

    flow = dataflow.load()
    for n in flow.nodes.values():
        command = n.command.split()[0]
        assert command in COMMANDS, f"dataflow node {n.name} runs `cinetransfer {command}`, which the CLI lacks"
        assert _cli_module_path(command) == n.module, f"{n.name}: the CLI runs {_cli_module_path(command)}"
    declared = {n.command.split()[0] for n in flow.nodes.values()}
    joins = {c for c in COMMANDS if (REPO / _cli_module_path(c)).is_file()
             and "node_from_args(" in (REPO / _cli_module_path(c)).read_text()}
    assert {"source", "detector", "smoother", "planner", "autopilot_bridge", "camera", "relay"} <= joins
    assert joins - declared == set(), f"CLI nodes missing from deploy/dataflow.yaml: {sorted(joins - declared)}"


def test_dataflow_declares_the_mavlink_subject_input_and_the_file_detector():
    flow = dataflow.load()
    assert keys.SUBJECT_STATE in flow.nodes["autopilot_bridge"].inputs
    assert keys.SOURCE_FRAME in flow.nodes["file_detector"].outputs
    # a file played by the detector itself sends no end-of-stream: the smoother ends on idle
    assert flow.check(["file_detector", "smoother", "planner", "autopilot_bridge"]) == \
        ["smoother reads detector/end but no node of the deployment writes it"]
    assert "2 writers" in " ".join(flow.check(["source", "file_detector", "detector"]))
