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


def parse_with_settings(parser: argparse.ArgumentParser, argv: list[str], node: str,
                        fields: dict[str, str]) -> argparse.Namespace:
    """For a node whose settings are its flags: the section's values become the flags' defaults.

    `fields` maps a settings key to the flag's dest; values are converted by the flag's own type,
    so a bad one is a ConfigError naming the key. Flags given on the command line win."""
    args = parser.parse_args(argv)
    section = args_section(args, node)
    unknown = sorted(set(section) - set(fields))
    if unknown:
        raise ConfigError(f"{node} config: unknown field(s) {unknown}; allowed: {sorted(fields)}")
    actions = {a.dest: a for a in parser._actions}
    defaults = {}
    for key, value in section.items():
        conv = actions[fields[key]].type or str
        try:
            defaults[fields[key]] = conv(value) if isinstance(conv, type) else conv(str(value))
        except (TypeError, ValueError, argparse.ArgumentTypeError):
            raise ConfigError(f"{node} config: {key} = {value!r} is invalid") from None
    parser.set_defaults(**defaults)
    return parser.parse_args(argv)
