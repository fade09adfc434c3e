"""One way to configure a node: its section of one YAML file, then its flags.

`--config FILE` names the file: a deploy config (deploy/configs/*.yaml), where the node's
settings are `nodes[i].settings` of the node named by `--section` (default: the node's own
name; the supervisor passes both), or a file of the node's own, where they are the node's
top-level section (`planner:`) or, without one, the whole file. `${VAR}` and `${VAR:-default}`
are substituted from the environment as the supervisor does. Each node turns the section into
its validated dataclasses and lets flags override it; every error is a
shared.errors.ConfigError naming the field.
"""
from __future__ import annotations

import argparse
import os
import re
from pathlib import Path
from typing import Any

from cinetransfer.shared.errors import ConfigError

_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


def substitute_env(text: str) -> str:
    """`${VAR}` -> $VAR ('' if unset), `${VAR:-default}` -> $VAR or default."""
    return _VAR.sub(lambda m: os.environ.get(m.group(1), m.group(2) if m.group(2) is not None else ""), text)


def add_config_arguments(p: argparse.ArgumentParser, node: str) -> None:
    p.add_argument("--config", metavar="YAML", default=None,
                   help=f"settings file: a deploy config (the node's 'settings') or a file with a '{node}:' "
                        "section; flags override it")
    p.add_argument("--section", default=node, metavar="NAME",
                   help=f"which node's settings to read from a deploy config (default {node})")


def read_yaml(path: str | os.PathLike) -> Any:
    import yaml

    p = Path(path)
    try:
        return yaml.safe_load(substitute_env(p.read_text()))
    except OSError as e:
        raise ConfigError(f"config: cannot read {p} ({e.strerror})") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"config: {p} is not valid YAML ({e})") from None


def load_section(path: str | os.PathLike | None, section: str) -> dict[str, Any]:
    """The node's settings from `path` (see the module doc); {} without a file."""
    if not path:
        return {}
    doc = read_yaml(path)
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(f"config: {path}: the top level must be a mapping")
    if isinstance(doc.get("nodes"), list):  # a deploy config
        for n in doc["nodes"]:
            if isinstance(n, dict) and n.get("name") == section:
                return _mapping(n.get("settings"), f"{path}: nodes[{section}].settings")
        raise ConfigError(f"config: {path}: no node named {section!r}")
    if section in doc:
        return _mapping(doc[section], f"{path}: {section}")
    return doc


def args_section(args: argparse.Namespace, node: str) -> dict[str, Any]:
    """load_section for the --config/--section flags of `add_config_arguments`."""
    return load_section(getattr(args, "config", None), getattr(args, "section", None) or node)


def _mapping(v: Any, where: str) -> dict[str, Any]:
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ConfigError(f"config: {where} must be a mapping")
    return dict(v)


def parse_with_settings(parser: argparse.ArgumentParser, argv: list[str] | None, node: str,
                        fields: dict[str, str] | None = None) -> argparse.Namespace:
    """Parse `argv` with the node's settings (`--config`/`--section`) as the flags' defaults.

    For nodes whose configuration is their flags. `fields` maps a settings key to the flag's dest;
    without it every flag is a setting, named like its flag (`system_id` or `system-id` for
    `--system-id`). A value is converted and checked as the flag would be; a flag given on the
    command line wins. The parser must have `add_config_arguments`. Raises ConfigError naming
    the field for an unknown setting or a bad value."""
    pre = argparse.ArgumentParser(add_help=False)
    add_config_arguments(pre, node)
    known, _ = pre.parse_known_args(argv)
    actions = {a.dest: a for a in parser._actions if a.dest not in ("help", "config", "section")}
    if fields is None:
        fields = {dest: dest for dest in actions}
    defaults = {}
    for key, value in load_section(known.config, known.section or node).items():
        action = actions.get(fields.get(str(key).replace("-", "_"), ""))
        if action is None:
            raise ConfigError(f"{node} config: unknown field {key!r}; allowed: {sorted(fields)}")
        defaults[action.dest] = _flag_value(node, key, action, value)
        action.required = False
    parser.set_defaults(**defaults)
    return parser.parse_args(argv)


def _flag_value(node: str, key: str, action: argparse.Action, value: Any) -> Any:
    where = f"{node}.{key}"
    if action.nargs == 0:  # store_true / store_false
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: must be true or false, got {value!r}")
        return value
    text = ",".join(str(v) for v in value) if isinstance(value, list) else str(value)
    try:
        out = action.type(text) if action.type is not None else text
    except (ValueError, TypeError, argparse.ArgumentTypeError) as e:
        raise ConfigError(f"{where}: {value!r} is not valid ({e})") from None
    if action.choices is not None and out not in action.choices:
        raise ConfigError(f"{where}: must be one of {list(action.choices)}, got {value!r}")
    return out
