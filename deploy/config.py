"""Deploy configs: find one by name or path, parse and check it into a DeployConfig.

CONFIG is a path to a YAML file or the name of a shipped config (local, ground, onboard).
Values may use ${VAR} or ${VAR:-default} environment substitution. `dataflow_problems` checks
configs that form one deployment against the declared dataflow (deploy/dataflow.yaml).
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

import yaml

from cinetransfer.shared import keys, zenoh_config
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.nodeconfig import substitute_env
from cinetransfer.shared.paths import resolve_named_yaml

CONFIG_DIR = Path(__file__).resolve().parent / "configs"


@dataclasses.dataclass(frozen=True)
class Proc:
    name: str
    kind: str  # 'router' | 'node'
    argv: tuple[str, ...]  # arguments after `python -m cinetransfer`
    identity: str | None = None  # who it joins the bus as (secure deployments)
    role: str | None = None  # its node in deploy/dataflow.yaml (default: its name)


@dataclasses.dataclass(frozen=True)
class DeployConfig:
    name: str
    path: str
    rig: str
    routers: tuple[Proc, ...]
    nodes: tuple[Proc, ...]
    check_endpoint: str | None  # where `up`/`status` connect to see liveliness
    backoff_initial_s: float = 0.5
    backoff_max_s: float = 10.0
    backoff_reset_s: float = 30.0
    stop_grace_s: float = 10.0
    startup_timeout_s: float = 90.0
    secure: bool = True
    secrets: str | None = None  # explicit secrets folder; None: <run dir>/secrets, generated
    grants: tuple[tuple[str, tuple[str, ...]], ...] = ()  # extra (identity, keys it may publish)
    shipped: bool = False

    @property
    def procs(self) -> tuple[Proc, ...]:
        return self.routers + self.nodes


def _subst(value: Any) -> Any:
    return substitute_env(value) if isinstance(value, str) else value


def resolve_config_path(name_or_path: str) -> Path:
    return resolve_named_yaml(name_or_path, CONFIG_DIR, missing="deploy config {path} does not exist",
                              unknown="no deploy config named {name}; shipped configs: {shipped}")


def _zenoh_flags(z: dict, where: str) -> list[str]:
    flags: list[str] = []
    unknown = set(z) - {"mode", "listen", "connect", "shm", "config", "tls_root_ca", "tls_cert", "tls_key", "mtls"}
    if unknown:
        raise ConfigError(f"{where}.zenoh: unknown keys {sorted(unknown)}")
    if "mode" in z:
        flags += ["--mode", str(z["mode"])]
    for ep in z.get("listen", []) or []:
        flags += ["--listen", str(ep)]
    for ep in z.get("connect", []) or []:
        flags += ["--connect", str(ep)]
    if z.get("shm"):
        flags.append("--shm")
    if z.get("mtls"):
        flags.append("--mtls")
    for key, flag in (("config", "--zenoh-config"), ("tls_root_ca", "--tls-root-ca"), ("tls_cert", "--tls-cert"),
                      ("tls_key", "--tls-key")):
        if z.get(key):
            flags += [flag, str(z[key])]
    return flags


def _check_exposure(z: dict, args: list[str], raw: dict, where: str) -> None:
    """The exposure rule every Zenoh session passes (shared/exposure.py), checked on the config
    before anything starts: its zenoh settings, the zenoh flags among its args, $CT_ZENOH_CONFIG.
    A secure deployment gives each process its secrets, which turn on mutual TLS."""
    sec = raw.get("security")
    secure = not isinstance(sec, dict) or bool(sec.get("enabled", True))
    parser = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    zenoh_config.add_arguments(parser)
    try:
        flags, _ = parser.parse_known_args(args)
        zenoh_config.options_from_args(
            flags, files=False, mode=str(z.get("mode", "peer")), listen=tuple(map(str, z.get("listen") or ())),
            connect=tuple(map(str, z.get("connect") or ())), config_file=z.get("config") or None,
            tls_mtls=bool(z.get("mtls") or secure))
    except (ConfigError, argparse.ArgumentError) as e:
        raise ConfigError(f"{where}: {e}") from None


def _load_routers(raw: dict, path: Path) -> list[Proc]:
    routers = []
    for i, r in enumerate(raw.get("routers") or []):
        if not isinstance(r, dict) or "name" not in r:
            raise ConfigError(f"{path}: routers[{i}] needs a name")
        z = {"mode": "router", **(r.get("zenoh") or {})}
        argv = ["router", *_zenoh_flags(z, f"routers[{i}]")]
        _check_exposure(z, [], raw, f"{path}: routers[{i}] ({r['name']})")
        routers.append(Proc(str(r["name"]), "router", tuple(argv), r.get("identity")))
    return routers


def _load_node(n: Any, i: int, raw: dict, path: Path) -> Proc:
    """One node; its `settings` stay in the file: the node reads them itself (--config FILE --section NAME)."""
    if not isinstance(n, dict) or "name" not in n or "command" not in n:
        raise ConfigError(f"{path}: nodes[{i}] needs 'name' and 'command'")
    unknown = set(n) - {"name", "command", "args", "settings", "zenoh", "identity", "role"}
    if unknown:
        raise ConfigError(f"{path}: nodes[{i}] ({n['name']}): unknown keys {sorted(unknown)}")
    args = n.get("args") or []
    if not isinstance(args, list):
        raise ConfigError(f"{path}: nodes[{i}].args must be a list")
    if "settings" in n and not isinstance(n["settings"], (dict, type(None))):
        raise ConfigError(f"{path}: nodes[{i}].settings ({n['name']}) must be a mapping of the node's settings")
    settings = ["--config", str(path.resolve()), "--section", str(n["name"])] if n.get("settings") else []
    z = {**((raw.get("defaults") or {}).get("zenoh") or {}), **(n.get("zenoh") or {})}
    argv = [str(n["command"]), *settings, *map(str, args), "--rig", str(raw.get("rig", "rig0")),
            *_zenoh_flags(z, f"nodes[{i}]")]
    _check_exposure(z, list(map(str, args)), raw, f"{path}: nodes[{i}] ({n['name']})")
    return Proc(str(n["name"]), "node", tuple(argv), str(n.get("identity", n["name"])), str(n.get("role", n["name"])))


def _check_endpoint(raw: dict, path: Path) -> str | None:
    check = raw.get("check_endpoint")
    if check is None and raw.get("routers"):
        listen = ((raw["routers"][0].get("zenoh") or {}).get("listen") or [None])[0]
        if listen is not None and not isinstance(listen, str):
            raise ConfigError(f"{path}: routers[0].zenoh.listen entries must be strings like tcp/127.0.0.1:7447")
        check = listen.replace("0.0.0.0", "127.0.0.1") if listen else None
    return check


def _security(raw: dict, path: Path) -> dict[str, Any]:
    sec = raw.get("security") or {}
    if not isinstance(sec, dict) or set(sec) - {"enabled", "secrets", "grants"}:
        raise ConfigError(f"{path}: security must be a mapping with keys enabled, secrets, grants")
    grants = sec.get("grants") or {}
    if not isinstance(grants, dict) or not all(isinstance(v, list) for v in grants.values()):
        raise ConfigError(f"{path}: security.grants must map an identity to a list of key expressions")
    return dict(secure=bool(sec.get("enabled", True)),
                secrets=str(Path(sec["secrets"]).expanduser().resolve()) if sec.get("secrets") else None,
                grants=tuple((str(k), tuple(map(str, v))) for k, v in grants.items()))


def _restart(raw: dict, path: Path) -> dict[str, float]:
    restart = raw.get("restart") or {}
    defaults = {"backoff_initial_s": 0.5, "backoff_max_s": 10.0, "backoff_reset_s": 30.0, "stop_grace_s": 10.0,
                "startup_timeout_s": 90.0}
    unknown = set(restart) - set(defaults)
    if unknown:
        raise ConfigError(f"{path}: restart: unknown keys {sorted(unknown)}")
    out = {}
    for k, v in defaults.items():
        try:
            out[k] = float(restart.get(k, v))
        except (TypeError, ValueError):
            raise ConfigError(f"{path}: restart.{k} = {restart[k]!r}: must be a number") from None
    return out


def load_config(name_or_path: str) -> DeployConfig:
    path = resolve_config_path(name_or_path)
    try:
        # Substitute before parsing so that ${VAR} may stand inside flow sequences too.
        raw = yaml.safe_load(_subst(path.read_text()))
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: top level must be a mapping")
    unknown = set(raw) - {"rig", "routers", "nodes", "defaults", "restart", "check_endpoint", "description",
                          "security"}
    if unknown:
        raise ConfigError(f"{path}: unknown top-level keys {sorted(unknown)}")
    routers = _load_routers(raw, path)
    nodes = [_load_node(n, i, raw, path) for i, n in enumerate(raw.get("nodes") or [])]
    names = [p.name for p in routers + nodes]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"{path}: duplicate process names {sorted(dup)}")
    if not nodes and not routers:
        raise ConfigError(f"{path}: nothing to run (no routers, no nodes)")
    return DeployConfig(name=path.stem, path=str(path.resolve()), rig=str(raw.get("rig", "rig0")),
                        routers=tuple(routers), nodes=tuple(nodes), check_endpoint=_check_endpoint(raw, path),
                        shipped=path.resolve().parent == CONFIG_DIR, **_security(raw, path), **_restart(raw, path))



def dataflow_problems(cfgs: list[DeployConfig], *, grants: bool = True) -> list[str]:
    """What is wrong with these configs (one deployment, e.g. ground + onboard) against the
    declared dataflow: unknown nodes, keys read but never written, two writers of an exclusive
    key, and (with `grants`) granted keys outside the topic table."""
    from cinetransfer.shared import dataflow

    flow = dataflow.load()
    problems = flow.check({f"{p.name}" if len(cfgs) == 1 else f"{c.name}/{p.name}": p.role or p.name
                           for c in cfgs for p in c.nodes})
    if not grants:
        return problems
    relays = {p.identity for c in cfgs for p in c.nodes if p.role == "relay"}
    known = {f"{keys.ROOT}/*/{t.service}/{t.topic}" for t in keys.TOPICS}
    for c in cfgs:
        for who, exprs in c.grants:
            bad = [e for e in exprs if e not in known and who not in relays]
            problems += [f"{c.name}: security.grants.{who}: unknown key {e!r}" for e in bad]
    return problems
