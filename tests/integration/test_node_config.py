"""One config path: every node reads its section of the deploy config, then flags; a broken
setting is refused before the node joins the bus (stderr, exit 2, the field named)."""
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cinetransfer.deploy.config import load_config
from cinetransfer.shared import nodeconfig
from cinetransfer.shared.errors import ConfigError


def deploy_config(tmp_path, command, settings, name=None):
    doc = {"rig": "cfgtest", "nodes": [{"name": name or command, "command": command, "settings": settings}]}
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def run_node(*argv):
    # the node must refuse before it connects anywhere: a port nothing listens on, and a short timeout
    bus = [] if argv[0] == "sim-vehicle" else ["--connect", "tcp/127.0.0.1:9"]
    return subprocess.run([sys.executable, "-m", "cinetransfer", *argv, *bus],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("command, settings, field", [
    ("planner", {"bounds": {"focus_distance_min_m": -1.0}}, "focus_distance_min_m"),
    ("planner", {"vehicle": "no_such_drone"}, "vehicle"),
    ("autopilot_bridge", {"backend": "sim", "safety": {"speed_max_mps": -2.0}}, "speed_max_mps"),
    ("autopilot_bridge", {"rate_hz": 0}, "rate_hz"),
    ("smoother", {"theta": 1.5}, "theta"),
    ("smoother", {"windw_s": 3}, "windw_s"),
    ("source", {"window": 0}, "window"),
    ("camera", {"video": "clip.mp4", "jpeg_quality": 300}, "jpeg_quality"),
    ("camera", {"vidoe": "clip.mp4"}, "vidoe"),
    ("sim-vehicle", {"autopilot": "betaflight"}, "autopilot"),
    ("sim-vehicle", {"rate": -5}, "rate"),
    ("sim-vehicle", {"start": [0, 0]}, "start"),
    ("relay", {"from": "ct/a/**", "to": "ct/b/x", "queue": "many"}, "queue"),
    ("relay", {"form": "ct/a/**"}, "form"),
    ("camera", {"video": "clip.mp4", "focus_distance_m": "near"}, "focus_distance_m"),
])
def test_a_broken_node_setting_is_refused_on_stderr_with_exit_2_naming_the_field(tmp_path, command, settings, field):
    path = deploy_config(tmp_path, command, settings)
    cfg = load_config(str(path))  # the supervisor passes the file and the node's name
    argv = list(cfg.nodes[0].argv)
    if command == "sim-vehicle":  # not a bus node (MAVLink only): run alone with the same two flags
        argv = argv[:5]
    assert argv[1:5] == ["--config", str(path.resolve()), "--section", command]
    r = run_node(*argv)
    assert r.returncode == 2, r.stdout + r.stderr
    assert field in r.stderr and "config error" in r.stderr
    assert field not in r.stdout  # the smoother used to print its config errors on stdout


def test_flags_override_the_section_and_the_section_overrides_the_defaults(tmp_path):
    import argparse

    from cinetransfer.services.autopilot_bridge.service import build_parser, config_from_args
    from cinetransfer.services.smoother.service import build_parser as smoother_parser
    from cinetransfer.services.smoother.service import node_config

    path = deploy_config(tmp_path, "autopilot_bridge", {"scene": "focus_hedge", "vehicle": "inspire3",
                                                        "safety": {"watchdog_timeout_s": 0.8}})
    cfg = config_from_args(build_parser().parse_args(["--config", str(path), "--scene", "open_country"]))
    assert cfg.scene == "open_country" and cfg.vehicle == "inspire3"  # the flag wins over the file
    assert cfg.safety.watchdog_timeout_s == 0.8 and cfg.safety.focal_length_max_mm == 28.0  # file, then profile
    assert cfg.mavlink.sensor_width_mm == 35.9  # the profile's camera
    path = deploy_config(tmp_path, "smoother", {"end_idle_s": 0, "theta": 0.4})
    s = node_config(smoother_parser().parse_args(["--config", str(path), "--theta", "0.6"]))
    assert (s.end_idle_s, s.theta) == (0.0, 0.6)
    assert nodeconfig.args_section(argparse.Namespace(config=None, section="x"), "x") == {}


def test_camera_settings_then_flags(tmp_path):
    from cinetransfer.services.autopilot_bridge import camera_node as cn

    path = deploy_config(tmp_path, "camera", {"video": "clip.mp4", "width": 320, "loop": True, "f_number": 2.8})
    parse = cn.build_parser().parse_args
    cfg = cn.config_from_args(a := parse(["--config", str(path)]), nodeconfig.args_section(a, "camera"))
    assert (cfg.kind, cfg.source, cfg.width, cfg.loop, cfg.f_number, cfg.queue_len) == \
        ("video", "clip.mp4", 320, True, 2.8, 2)  # the file, then the defaults
    cfg = cn.config_from_args(a := parse(["--config", str(path), "--url", "rtsp://10.0.0.2/cam", "--width", "640"]),
                              nodeconfig.args_section(a, "camera"))
    assert (cfg.kind, cfg.source, cfg.width, cfg.loop) == ("url", "rtsp://10.0.0.2/cam", 640, True)  # flags win
    with pytest.raises(ConfigError, match="one source"):
        cn.config_from_args(parse([]), {})


def test_sim_vehicle_and_relay_settings_then_flags_earlier_keys_too(tmp_path):
    from cinetransfer import relay
    from cinetransfer.services.autopilot_bridge import sim_vehicle as sv

    path = deploy_config(tmp_path, "sim-vehicle", {"autopilot": "ardupilot", "start": [1, 2, 0], "rate": 50,
                                                   "system-id": 7, "vehicle": "inspire3"})
    cfg = sv.config_from_args(sv.build_parser().parse_args(["--config", str(path), "--rate", "25"]))
    # the flag given wins; the keys named like the flags ("rate", "system-id") still set their fields
    assert (cfg.autopilot, cfg.start, cfg.rate_hz, cfg.system_id, cfg.vehicle) == \
        ("ardupilot", (1.0, 2.0, 0.0), 25.0, 7, "inspire3")
    cfg = sv.config_from_args(sv.build_parser().parse_args(["--config", str(path), "--vehicle", "cinempc"]))
    assert (cfg.rate_hz, cfg.vehicle) == (50.0, "cinempc")
    assert sv.config_from_args(sv.build_parser().parse_args([])) == sv.SimVehicleConfig()
    path = deploy_config(tmp_path, "relay", {"from": "ct/x/**", "to": "ct/y/z", "no_drop": True, "queue": 8})
    cfg = relay.config_from_args(relay.build_parser().parse_args(["--config", str(path), "--queue", "16"]))
    # a required flag satisfied by the file; the flag given wins; a switch from the file
    assert (cfg.from_key, cfg.to_key, cfg.no_drop, cfg.queue) == ("ct/x/**", "ct/y/z", True, 16)
    for bad, field in (({"no_drop": "yes"}, "no_drop"), ({"queue": 0}, "queue"), ({"to": ""}, "to_key")):
        path = deploy_config(tmp_path, "relay", {"from": "ct/x/**", "to": "ct/y/z", **bad})
        with pytest.raises(ConfigError, match=field):
            relay.config_from_args(relay.build_parser().parse_args(["--config", str(path)]))


def test_a_node_missing_from_the_deploy_config_is_an_error(tmp_path):
    path = deploy_config(tmp_path, "planner", {"rate_hz": 10})
    with pytest.raises(ConfigError, match="no node named 'smoother'"):
        nodeconfig.load_section(path, "smoother")


def test_shipped_deploy_configs_carry_settings_not_env_switches():
    for name in ("local", "onboard"):
        path = load_config(name).path
        body = Path(path).read_text()
        assert "CT_SCENE" not in body and "CT_BRIDGE_BACKEND" not in body
        bridge = nodeconfig.load_section(path, "autopilot_bridge")
        assert bridge["backend"] == "sim" and bridge["vehicle"] == "cinempc"
