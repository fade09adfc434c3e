"""One way to configure a node: its section of one YAML file, then its flags.

`--config FILE` names the file: a deploy config (deploy/configs/*.yaml), where the node's
settings are `nodes[i].settings` of the node named by `--section` (default: the node's own
name; the supervisor passes both), or a file of the node's own, where they are the node's
top-level section (`planner:`) or, without one, the whole file. `${VAR}` and `${VAR:-default}`
are substituted from the environment as the supervisor does. Each node turns the section into
its validated dataclasses and lets flags override it; every error is a
shared.errors.ConfigError naming the field.

The config idiom: a node's config is one frozen dataclass whose fields are `setting(...)`s, each
carrying its flag, unit, range and help. `add_settings_arguments` makes the flags from it and
`config_from_args` builds the config: code defaults, then the deploy config's `settings`, then
the flags given. A class may accept earlier spellings of its fields in settings files: its
`SETTING_ALIASES` maps each to the field's name.

    @dataclass(frozen=True)
    class SourceConfig:
        window: int = setting(8, flag="--window", unit="frames", range=">= 1", help="frames ahead")

    add_config_arguments(ap, "source"); add_settings_arguments(ap, SourceConfig, "source")
    cfg = config_from_args(SourceConfig, ap.parse_args(argv), "source")
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
from dataclasses import dataclass, field
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


# -- config dataclasses whose fields carry their flag, unit, range and help ---------------------

@dataclass(frozen=True)
class Setting:
    """What a config field says about itself: its flag (None: settings file only), unit, allowed
    range ('[a, b]', '(a, b)', '[a, b)', '>= a', '> a'; checked by `validated`), choices and help."""

    flag: str | None = None
    unit: str | None = None
    range: str | None = None
    choices: tuple[Any, ...] | None = None
    help: str = ""
    metavar: str | None = None
    const: Any = None  # a flag that takes no value and sets this one (a bool's flag sets `not default`)


def setting(default: Any = dataclasses.MISSING, *, flag: str | None = None, unit: str | None = None,
            range: str | None = None, choices: tuple[Any, ...] | None = None, help: str = "",
            metavar: str | None = None, const: Any = None, default_factory: Any = dataclasses.MISSING) -> Any:
    """A dataclass field with its `Setting` (see the module's config idiom)."""
    meta = {"setting": Setting(flag, unit, range, choices and tuple(choices), help, metavar, const)}
    if default_factory is not dataclasses.MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


def setting_of(f: dataclasses.Field) -> Setting | None:
    return f.metadata.get("setting")


def settings_parser(cls: type, node: str, prog: str, description: str) -> argparse.ArgumentParser:
    """A parser with `--config`/`--section` and the flags of config class `cls`."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_config_arguments(parser, node)
    add_settings_arguments(parser, cls, node)
    return parser


def add_settings_arguments(parser: argparse.ArgumentParser, cls: type, title: str, *,
                           skip: tuple[str, ...] = ()) -> None:
    """One flag per field of `cls` that names one, groups (a field holding a config dataclass)
    included, but the fields in `skip` (e.g. a node's own flags on a batch tool). Each flag
    defaults to None: it overrides only when given."""
    groups: dict[str, Any] = {}
    for path, s, default in _flagged(cls):
        if path in skip:
            continue
        group = path.rpartition(".")[0]
        g = groups.get(group) or groups.setdefault(group, parser.add_argument_group(group or title))
        text = s.help + (f" [{s.unit}]" if s.unit else "") + (f", {s.range}" if s.range else "")
        if isinstance(default, bool) or s.const is not None:
            const = (not default) if s.const is None else s.const
            g.add_argument(s.flag, dest=path, action="store_const", const=const, default=None, help=text)
            continue
        kind = _tuple_of(default) if isinstance(default, tuple) else (type(default) if default is not None else str)
        metavar = s.metavar or (None if s.choices else s.unit.upper() if s.unit and s.unit.isalpha()
                                else path.rpartition(".")[2].upper())
        g.add_argument(s.flag, dest=path, type=kind, default=None, choices=s.choices, metavar=metavar,
                       help=f"{text} (default {_shown(default)})")


def _flagged(cfg: Any, prefix: str = "") -> list[tuple[str, Setting, Any]]:
    """(dotted field path, Setting, value) of every field with a flag, groups included; for a
    class, its defaults (a class whose defaults alone are not valid, e.g. a camera without a
    source, still lists its flags)."""
    out = []
    for f in dataclasses.fields(cfg):
        v, s = _value(cfg, f), setting_of(f)
        if dataclasses.is_dataclass(v):
            out += _flagged(v, f"{prefix}{f.name}.")
        elif s is not None and s.flag:
            out.append((f"{prefix}{f.name}", s, v))
    return out


def _value(cfg: Any, f: dataclasses.Field) -> Any:
    if not isinstance(cfg, type):
        return getattr(cfg, f.name)
    return f.default_factory() if f.default is dataclasses.MISSING else f.default  # type: ignore[misc]


def settings_from(cls: type, section: dict[str, Any], node: str, base: Any = None, prefix: str = "") -> Any:
    """`base` (default: the code defaults) with a settings mapping (a deploy config's `settings`):
    keys are field names, a group's a mapping of its own; unknown keys and bad values are
    ConfigErrors naming the field."""
    section = renamed_aliases(cls, section, node, prefix)
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(section) - set(names))
    if unknown:
        raise ConfigError(f"{node} config: unknown field(s) {[prefix + k for k in unknown]}; "
                          f"allowed: {sorted(names)}")
    base = base if base is not None else cls()
    values = {}
    for k, v in section.items():
        current = getattr(base, k)
        if dataclasses.is_dataclass(current):
            if not isinstance(v, dict):
                raise ConfigError(f"{node} config: {prefix}{k} must be a mapping")
            values[k] = settings_from(type(current), v, node, current, f"{prefix}{k}.")
        else:
            values[k] = _typed(node, prefix + k, v, current)
    try:
        return validated(dataclasses.replace(base, **values), node, prefix)
    except TypeError as e:  # a value of the wrong kind the check above let through
        raise ConfigError(f"{node} config: {e}") from None


def renamed_aliases(cls: type, section: dict[str, Any], node: str, prefix: str = "") -> dict[str, Any]:
    """`section` with every key that is an alias of `cls` (its `SETTING_ALIASES`: an earlier
    spelling -> the field's name) under the field's name; an alias given beside its field is an error."""
    aliases = getattr(cls, "SETTING_ALIASES", {})
    out: dict[str, Any] = {}
    for k, v in section.items():
        name = aliases.get(k, k)
        if name in out:
            raise ConfigError(f"{node} config: {prefix}{name} is given twice (an earlier spelling of it too); "
                              "give it once")
        out[name] = v
    return out


def _typed(node: str, name: str, v: Any, default: Any) -> Any:
    """`v` as the kind of value the field's default is (a list for a tuple, an int for a float)."""
    kinds = {bool: "true or false", int: "an integer", float: "a number", str: "a string", tuple: "a list"}
    want = next((k for k in kinds if isinstance(default, k)), None)
    ok = {None: True, bool: isinstance(v, bool), tuple: isinstance(v, (list, tuple)), str: isinstance(v, str),
          int: isinstance(v, int) and not isinstance(v, bool),
          float: isinstance(v, (int, float)) and not isinstance(v, bool)}[want]
    if not ok:
        raise ConfigError(f"{node} config: {name}={v!r} is invalid; allowed: {kinds[want]}")
    return tuple(v) if want is tuple else float(v) if want is float else v


def config_from_args(cls: type, args: argparse.Namespace, node: str, base: Any = None,
                     section: dict[str, Any] | None = None) -> Any:
    """The node's config: code defaults (or `base`), then its settings (`section`, else read
    from `--config`/`--section`), then the flags that were given. Raises ConfigError naming
    the field."""
    cfg = settings_from(cls, args_section(args, node) if section is None else section, node, base)
    given: dict[str, Any] = {}
    for path, _, _ in _flagged(cfg):
        v = getattr(args, path, None)
        if v is not None:
            given[path] = v
    return validated(_replace_path(cfg, given), node) if given else cfg


def _replace_path(cfg: Any, changes: dict[str, Any]) -> Any:
    """dataclasses.replace with dotted paths into groups: {'structure.dt_s': 0.2}."""
    top: dict[str, Any] = {}
    groups: dict[str, dict[str, Any]] = {}
    for path, v in changes.items():
        head, _, rest = path.partition(".")
        if rest:
            groups.setdefault(head, {})[rest] = v
        else:
            top[head] = v
    top.update({g: _replace_path(getattr(cfg, g), sub) for g, sub in groups.items()})
    return dataclasses.replace(cfg, **top)


def validated(cfg: Any, node: str, prefix: str = "") -> Any:
    """Each field (groups included) within its Setting's range and choices, then the class's own
    `validate()`."""
    for f in dataclasses.fields(cfg):
        s, v = setting_of(f), getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            validated(v, node, f"{prefix}{f.name}.")
        if s is None:
            continue
        if s.choices is not None and v not in s.choices:
            raise ConfigError(f"{node} config: {prefix}{f.name}={v!r} is invalid; allowed: "
                              + " | ".join(map(str, s.choices)))
        if s.range and not _in_range(v, s.range):
            raise ConfigError(f"{node} config: {prefix}{f.name}={v!r} is invalid; allowed: {s.range}")
    check = getattr(cfg, "validate", None)
    out = check() if callable(check) else None
    return cfg if out is None else out


_RANGE = re.compile(r"^([\[(])\s*(\S+)\s*,\s*(\S+)\s*([\])])$|^(>=|>|<=|<)\s*(\S+)$")


def _in_range(v: Any, text: str) -> bool:
    m = _RANGE.match(text.strip())
    if m is None:
        raise ValueError(f"range {text!r}: write '[a, b]', '(a, b)', '>= a' or '> a'")
    try:
        x = float(v)
    except (TypeError, ValueError):
        return False
    if m.group(5):
        bound = float(m.group(6))
        return {">=": x >= bound, ">": x > bound, "<=": x <= bound, "<": x < bound}[m.group(5)]
    lo, hi = float(m.group(2)), float(m.group(3))
    return (x >= lo if m.group(1) == "[" else x > lo) and (x <= hi if m.group(4) == "]" else x < hi)


def _csv(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def _tuple_of(default: tuple[Any, ...]) -> Any:
    """A flag's parser for a tuple field: names, or as many numbers as the default holds."""
    if not default or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in default):
        return _csv

    def numbers(text: str) -> tuple[float, ...]:
        try:
            vals = tuple(float(x) for x in text.split(","))
        except ValueError:
            vals = ()
        if len(vals) != len(default):
            raise argparse.ArgumentTypeError(f"expected {len(default)} comma-separated numbers, got {text!r}")
        return vals
    return numbers


def _shown(default: Any) -> str:
    if isinstance(default, tuple):
        return ",".join(map(str, default))
    return str(default) if default != "" else "none"


def describe(cls: type) -> list[dict[str, Any]]:
    """Every field of a config class: name, flag, unit, range, default, help (docs and tests)."""
    d = cls()
    return [{"field": f.name, "flag": s.flag if s else None, "unit": s.unit if s else None,
             "range": s.range if s else None, "default": getattr(d, f.name), "help": s.help if s else ""}
            for f in dataclasses.fields(cls) for s in [setting_of(f)]]
