"""The config idiom (shared/nodeconfig.py): one dataclass per node whose fields carry flag, unit,
range and help; one function makes the flags, one builds the config from defaults, the deploy
config's settings and the flags given."""
import argparse
import dataclasses
from dataclasses import dataclass

import pytest
import yaml

from cinetransfer.shared import nodeconfig
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.nodeconfig import setting


@dataclass(frozen=True)
class DemoConfig:
    window: int = setting(8, flag="--window", unit="frames", range=">= 1", help="frames ahead")
    rate_hz: float = setting(5.0, flag="--rate", unit="Hz", range="(0, 50]", help="how often")
    mode: str = setting("a", flag="--mode", choices=("a", "b"), help="which")
    names: tuple[str, ...] = setting(("x", "y"), flag="--names", help="comma-separated names")
    focus: bool = setting(True, flag="--no-focus", help="skip focus")
    quiet: bool = setting(False, flag="--quiet", help="say less")
    file_only: float = 1.5  # a setting without a flag

    def validate(self):
        if self.window > 100:
            raise ConfigError(f"demo config: window={self.window} is invalid; allowed: <= 100")
        return self


def parser():
    ap = argparse.ArgumentParser()
    nodeconfig.add_config_arguments(ap, "demo")
    nodeconfig.add_settings_arguments(ap, DemoConfig, "demo")
    return ap


def test_defaults_then_settings_then_flags(tmp_path):
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump({"nodes": [{"name": "demo", "settings": {"window": 3, "rate_hz": 10,
                                                                            "names": ["p"], "file_only": 2.0}}]}))
    assert nodeconfig.config_from_args(DemoConfig, parser().parse_args([]), "demo") == DemoConfig()
    cfg = nodeconfig.config_from_args(DemoConfig, parser().parse_args(["--config", str(path)]), "demo")
    assert (cfg.window, cfg.rate_hz, cfg.names, cfg.file_only, cfg.mode) == (3, 10, ("p",), 2.0, "a")
    args = parser().parse_args(["--config", str(path), "--window", "4", "--names", "q, r", "--no-focus", "--quiet"])
    cfg = nodeconfig.config_from_args(DemoConfig, args, "demo")
    assert (cfg.window, cfg.rate_hz, cfg.names, cfg.focus, cfg.quiet) == (4, 10, ("q", "r"), False, True)


@pytest.mark.parametrize("settings, field", [({"window": 0}, "window"), ({"rate_hz": 0}, "rate_hz"),
                                             ({"rate_hz": 50.5}, "rate_hz"), ({"mode": "c"}, "mode"),
                                             ({"windw": 3}, "windw"), ({"window": 101}, "window"),
                                             ({"window": 2.5}, "window"), ({"focus": "yes"}, "focus"),
                                             ({"rate_hz": "fast"}, "rate_hz"), ({"names": "p"}, "names")])
def test_a_bad_setting_is_a_config_error_naming_the_field(settings, field):
    with pytest.raises(ConfigError, match=field):
        nodeconfig.settings_from(DemoConfig, settings, "demo")


def test_ranges_against_hand_checked_values():
    ok = nodeconfig._in_range
    assert ok(1, ">= 1") and not ok(0.999, ">= 1") and not ok(0, "> 0") and ok(1e-9, "> 0")
    assert ok(0.5, "(0, 0.5]") and not ok(0.0, "(0, 0.5]") and ok(0.0, "[0, 1)") and not ok(1.0, "[0, 1)")
    assert not ok("near", ">= 0")
    with pytest.raises(ValueError):
        ok(1, "between 0 and 1")


def test_flags_carry_unit_range_and_default_in_their_help():
    text = parser().format_help()
    assert "--window FRAMES" in text and "[frames], >= 1 (default 8)" in text
    assert "{a,b}" in text and "(default x,y)" in text
    rows = {r["field"]: r for r in nodeconfig.describe(DemoConfig)}
    assert rows["rate_hz"] == {"field": "rate_hz", "flag": "--rate", "unit": "Hz", "range": "(0, 50]",
                               "default": 5.0, "help": "how often"}
    assert rows["file_only"]["flag"] is None


@dataclass(frozen=True)
class Inner:
    steps: int = setting(15, flag="--steps", range="[1, 100]", help="stages")
    tol: float = 1e-5


@dataclass(frozen=True)
class Outer:
    inner: Inner = dataclasses.field(default_factory=Inner)
    rate_hz: float = setting(20.0, flag="--rate", unit="Hz", range="(0, 200]", help="rate")


def test_groups_take_a_mapping_of_their_own_and_their_flags_reach_into_them(tmp_path):
    ap = argparse.ArgumentParser()
    nodeconfig.add_settings_arguments(ap, Outer, "outer")
    cfg = nodeconfig.config_from_args(Outer, ap.parse_args(["--steps", "7"]), "outer",
                                      section={"inner": {"tol": 1e-3}, "rate_hz": 10})
    assert cfg == Outer(inner=Inner(steps=7, tol=1e-3), rate_hz=10.0)
    with pytest.raises(ConfigError, match=r"inner\.steps=0"):
        nodeconfig.settings_from(Outer, {"inner": {"steps": 0}}, "outer")
    with pytest.raises(ConfigError, match=r"\['inner\.stps'\]"):
        nodeconfig.settings_from(Outer, {"inner": {"stps": 3}}, "outer")
    with pytest.raises(ConfigError, match="inner must be a mapping"):
        nodeconfig.settings_from(Outer, {"inner": 3}, "outer")


def _node_configs():
    from cinetransfer.services.autopilot_bridge.camera_node import CameraConfig
    from cinetransfer.services.autopilot_bridge.config import BridgeConfig, MavlinkConfig, SafetyConfig
    from cinetransfer.services.detector.config import DetectorConfig
    from cinetransfer.services.smoother.config import SmootherConfig
    from cinetransfer.services.planner.config import PlannerConfig, Structure
    from cinetransfer.services.source.config import SourceConfig

    return [SourceConfig, DetectorConfig, SmootherConfig, PlannerConfig, Structure, BridgeConfig, SafetyConfig,
            MavlinkConfig, CameraConfig]


@pytest.mark.parametrize("cls", _node_configs(), ids=lambda c: c.__name__)
def test_every_node_config_field_with_a_flag_says_what_it_is_and_its_default_is_valid(cls):
    flagged = [f for f in dataclasses.fields(cls) if (s := nodeconfig.setting_of(f)) and s.flag]
    assert flagged
    for f in flagged:
        s = nodeconfig.setting_of(f)
        assert s.help and s.flag.startswith("--"), f.name
    if cls.__name__ != "CameraConfig":  # a camera has no valid default: it needs a source
        assert nodeconfig.validated(cls(), cls.__name__) == cls()
