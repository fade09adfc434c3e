"""`cinetransfer deploy up|down|status|logs CONFIG`: run a set of nodes from a config file.

`up` starts a detached supervisor process that launches the config's Zenoh router(s) and
nodes as child processes, one log file per process, restarts any that exit with exponential
back-off, and records its state in RUN_DIR/state.json. `up` returns once every node has
declared its liveliness token (or fails, naming the nodes that did not come up). `down` asks
the supervisor to stop: nodes get SIGINT (clean exit), then SIGKILL after a grace period,
routers last. `status` prints each process, its pid, restarts and liveness; `logs NODE` prints
(or follows) a node's log.

CONFIG is a path to a YAML file or the name of a shipped config (local, ground, onboard).
Values may use ${VAR} or ${VAR:-default} environment substitution.

One deployment, one run folder: RUN_DIR is `--run-dir`, else
$CT_STATE_DIR/deploy/<config> (default $XDG_STATE_HOME/cinetransfer, i.e.
~/.local/state/cinetransfer), the same wherever the command runs. The supervisor holds an
exclusive lock on RUN_DIR/lock for its whole life, so a second `up` of a running deployment is
refused. Every process it starts carries CT_DEPLOY_RUN_DIR in its environment; `status` and
`down` find processes by that mark and their command line, not by a state file.

Secure by default (docs/security.md): unless the config says `security: {enabled: false}`,
every process joins the router as an identity with a password, the router enforces the
access-control rules of shared/access.py, and tls/ links use mutual TLS. The credentials come
from `security.secrets` ($CT_SECRETS in the shipped configs) or are generated on the first `up`
into RUN_DIR/secrets (0700). `cinetransfer deploy certs DIR` creates them for a split deployment.
"""
from __future__ import annotations

import argparse
import dataclasses
import fcntl
import hashlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from cinetransfer.shared import keys
from cinetransfer.shared.atomic import atomic_write
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.nodeconfig import substitute_env
from cinetransfer.shared.paths import named_yaml

log = logging.getLogger("cinetransfer.deploy")
CONFIG_DIR = Path(__file__).resolve().parent / "configs"


# ----------------------------------------------------------------------------- config
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
    p, as_path = named_yaml(name_or_path, CONFIG_DIR)
    if p.is_file():
        return p
    if as_path:
        raise ConfigError(f"deploy config {p} does not exist")
    names = ", ".join(sorted(f.stem for f in CONFIG_DIR.glob("*.yaml")))
    raise ConfigError(f"no deploy config named {name_or_path!r}; shipped configs: {names}")


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


def _check_listeners(listen: list, where: str) -> None:
    from cinetransfer.shared.zenoh_config import _is_local, endpoint_host

    for ep in listen:
        proto, host = endpoint_host(str(ep))
        if proto not in ("tls", "quic") and not _is_local(proto, host):
            raise ConfigError(f"{where}: listener {ep} would accept unauthenticated connections from the "
                              f"network; listen on 127.0.0.1, or on tls/{host}:PORT (mutual TLS, see "
                              f"docs/security.md)")


def _load_routers(raw: dict, path: Path) -> list[Proc]:
    routers = []
    for i, r in enumerate(raw.get("routers") or []):
        if not isinstance(r, dict) or "name" not in r:
            raise ConfigError(f"{path}: routers[{i}] needs a name")
        argv = ["router", *_zenoh_flags({"mode": "router", **(r.get("zenoh") or {})}, f"routers[{i}]")]
        _check_listeners((r.get("zenoh") or {}).get("listen") or [], f"{path}: routers[{i}]")
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


# ----------------------------------------------------------------------------- run folder, lock, security
ENV_RUN_DIR = "CT_DEPLOY_RUN_DIR"  # marks every process of a deployment (value: its run folder)
ENV_PROC = "CT_DEPLOY_PROC"  # the process's name in the config ("supervisor" for the supervisor)


def state_home() -> Path:
    """Where run folders live: $CT_STATE_DIR, else $XDG_STATE_HOME/cinetransfer (~/.local/state/...)."""
    if os.environ.get("CT_STATE_DIR"):
        return Path(os.environ["CT_STATE_DIR"]).expanduser().resolve()
    xdg = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(xdg).expanduser().resolve() / "cinetransfer"


def resolve_run_dir(cfg: DeployConfig, run_dir: str | os.PathLike | None = None) -> Path:
    """The one absolute run folder of `cfg`: `run_dir` if given, else under state_home().

    A shipped config is known by its name; any other by its file name and a hash of its absolute
    path, so two different 'transfer.yaml' files never share a folder.
    """
    if run_dir:
        return Path(run_dir).expanduser().resolve()
    key = cfg.name if cfg.shipped else f"{cfg.name}-{hashlib.sha256(cfg.path.encode()).hexdigest()[:10]}"
    return state_home() / "deploy" / key


def secrets_dir(cfg: DeployConfig, run_dir: Path) -> Path:
    return Path(cfg.secrets) if cfg.secrets else run_dir / "secrets"


def identities(cfg: DeployConfig) -> list[str]:
    from cinetransfer.shared import access

    return list(dict.fromkeys([*(p.identity for p in cfg.procs if p.identity), *access.TOOL_IDENTITIES,
                               *(g for g, _ in cfg.grants)]))


def prepare_security(cfg: DeployConfig, run_dir: Path) -> None:
    """Credentials (generated into RUN_DIR/secrets unless the config names a folder) and ACL files."""
    if not cfg.secure:
        return
    from cinetransfer.deploy import certs
    from cinetransfer.shared import access

    sec = secrets_dir(cfg, run_dir)
    from cinetransfer.shared.zenoh_config import endpoint_host

    links = [ep for r in cfg.routers for i, ep in enumerate(r.argv) if i and r.argv[i - 1] in ("--listen", "--connect")
             and endpoint_host(ep)[0] in ("tls", "quic")]
    if links and cfg.secrets is None:
        raise ConfigError(f"this deployment links hosts over TLS ({', '.join(links)}); every host needs the same "
                          f"credentials: run 'cinetransfer deploy certs DIR --host <drone address>', copy DIR to "
                          f"each host and set CT_SECRETS=DIR (docs/security.md)")
    if cfg.secrets is None:
        certs.ensure(sec, users=identities(cfg))
    elif not (sec / certs.USERS_FILE).is_file():
        raise ConfigError(f"security.secrets: {sec} has no {certs.USERS_FILE}; create it with "
                          f"'cinetransfer deploy certs {sec}'")
    for ident in identities(cfg):
        try:
            access.read_password(sec, ident)
        except ValueError as e:
            raise ConfigError(f"security: {e}") from None
    acl = access.access_control(grants={k: list(v) for k, v in cfg.grants})
    for r in cfg.routers:
        _write_atomic(run_dir / f"{r.name}.acl.json", json.dumps(acl, indent=1))


def _write_atomic(path: Path, text: str) -> None:
    """Write via a unique temporary file in the same folder and rename (readers never see half)."""
    with atomic_write(path, mode=0o600) as f:
        f.write(text)


def security_flags(cfg: DeployConfig, run_dir: Path, proc: Proc) -> list[str]:
    """Flags that make `proc` join as its identity (and a router enforce the rules)."""
    if not cfg.secure:
        return []
    flags = ["--secrets", str(secrets_dir(cfg, run_dir))]
    if proc.identity:
        flags += ["--identity", proc.identity]
    if proc.kind == "router":
        flags += ["--access-control", str(run_dir / f"{proc.name}.acl.json")]
    return flags


def _try_lock(run_dir: Path) -> int | None:
    """An fd holding the deployment's exclusive lock, or None if another process holds it."""
    fd = os.open(run_dir / "lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def _lock_held(run_dir: Path) -> bool:
    if not (run_dir / "lock").exists():
        return False
    fd = _try_lock(run_dir)
    if fd is None:
        return True
    os.close(fd)
    return False


def running_procs(run_dir: Path) -> dict[int, str]:
    """{pid: process name} of the live processes this deployment started (found in /proc).

    A process belongs to the deployment when its environment carries CT_DEPLOY_RUN_DIR=<run_dir>
    and its command line runs cinetransfer — a pid reused by another program never matches.
    """
    mark = f"{ENV_RUN_DIR}={run_dir}".encode()
    found: dict[int, str] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry.name}/environ", "rb") as f:
                env = f.read().split(b"\0")
            if mark not in env:
                continue
            with open(f"/proc/{entry.name}/cmdline", "rb") as f:
                cmd = f.read().split(b"\0")
        except OSError:  # gone, or another user's process
            continue
        if b"cinetransfer" not in cmd or not _pid_alive(int(entry.name)):
            continue
        name = next((e.split(b"=", 1)[1].decode() for e in env if e.startswith(f"{ENV_PROC}=".encode())), "?")
        found[int(entry.name)] = name
    return found


# ----------------------------------------------------------------------------- supervisor
class Supervisor:
    """Runs in the detached supervisor process: start, watch, restart, stop."""

    def __init__(self, cfg: DeployConfig, run_dir: Path, owner_pid: int | None = None) -> None:
        self.cfg, self.run_dir = cfg, run_dir
        self.owner_pid = owner_pid  # the deployment ends with this process (a transfer's own nodes)
        self._owner_checked = 0.0
        self.children: dict[str, subprocess.Popen] = {}
        self.restarts: dict[str, int] = {p.name: 0 for p in cfg.procs}
        self.backoff: dict[str, float] = {p.name: cfg.backoff_initial_s for p in cfg.procs}
        self.next_start: dict[str, float] = {}
        self.started_at: dict[str, float] = {}
        self.stopping = False

    def _start(self, proc: Proc) -> None:
        logf = open(self.run_dir / f"{proc.name}.log", "ab")
        logf.write(f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')} start: cinetransfer {' '.join(proc.argv)}\n".encode())
        logf.flush()
        env = {**os.environ, "PYTHONUNBUFFERED": "1", ENV_RUN_DIR: str(self.run_dir), ENV_PROC: proc.name}
        argv = [*proc.argv, *security_flags(self.cfg, self.run_dir, proc)]
        self.children[proc.name] = subprocess.Popen([sys.executable, "-m", "cinetransfer", *argv], stdout=logf,
                                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
        logf.close()
        self.started_at[proc.name] = time.monotonic()
        log.info("started %s (pid %d)", proc.name, self.children[proc.name].pid)

    def write_state(self) -> None:
        state = {
            "config": self.cfg.name, "rig": self.cfg.rig, "supervisor_pid": os.getpid(),
            "check_endpoint": self.cfg.check_endpoint, "stopping": self.stopping,
            "procs": {p.name: {"kind": p.kind, "pid": (self.children[p.name].pid if p.name in self.children and
                                                        self.children[p.name].poll() is None else None),
                               "restarts": self.restarts[p.name], "argv": list(p.argv)} for p in self.cfg.procs},
        }
        _write_atomic(self.run_dir / "state.json", json.dumps(state, indent=2))

    def run(self) -> int:
        signal.signal(signal.SIGTERM, lambda *_: setattr(self, "stopping", True))
        signal.signal(signal.SIGINT, lambda *_: setattr(self, "stopping", True))
        for r in self.cfg.routers:
            self._start(r)
        if self.cfg.routers:
            time.sleep(0.3)  # let routers bind before nodes try to connect (they retry anyway)
        for n in self.cfg.nodes:
            self._start(n)
        self.write_state()
        while not self.stopping:
            now = time.monotonic()
            if self._owner_gone(now):
                break
            changed = False
            for p in self.cfg.procs:
                child = self.children.get(p.name)
                if child is not None and child.poll() is not None:
                    rc = child.returncode
                    ran = now - self.started_at[p.name]
                    if ran > self.cfg.backoff_reset_s:
                        self.backoff[p.name] = self.cfg.backoff_initial_s
                    delay = self.backoff[p.name]
                    self.backoff[p.name] = min(delay * 2, self.cfg.backoff_max_s)
                    log.warning("%s exited with %s after %.1fs; restarting in %.1fs", p.name, rc, ran, delay)
                    del self.children[p.name]
                    self.next_start[p.name] = now + delay
                    changed = True
                if p.name not in self.children and now >= self.next_start.get(p.name, now):
                    self.restarts[p.name] += 1
                    self._start(p)
                    self.next_start.pop(p.name, None)
                    changed = True
            if changed:
                self.write_state()
            time.sleep(0.05)
        self.shutdown()
        return 0

    def _owner_gone(self, now: float) -> bool:
        """True once the owner process has died (checked once a second): its nodes would otherwise
        run on as orphans, e.g. after the transfer that started them was SIGKILLed."""
        if self.owner_pid is None or now - self._owner_checked < 1.0:
            return False
        self._owner_checked = now
        if _pid_alive(self.owner_pid):
            return False
        log.warning("owner process %d is gone: stopping the deployment", self.owner_pid)
        return True

    def shutdown(self) -> None:
        log.info("stopping all processes")
        self.write_state()
        for group in (self.cfg.nodes, self.cfg.routers):  # nodes first, routers last
            live = [(p.name, self.children[p.name]) for p in group if p.name in self.children]
            for _, c in live:
                if c.poll() is None:
                    c.send_signal(signal.SIGINT)
            deadline = time.monotonic() + self.cfg.stop_grace_s
            for name, c in live:
                try:
                    c.wait(max(0.0, deadline - time.monotonic()))
                    log.info("%s exited with %s", name, c.returncode)
                except subprocess.TimeoutExpired:
                    log.warning("%s did not exit within %.0fs; killing", name, self.cfg.stop_grace_s)
                    c.kill()
                    c.wait()
        (self.run_dir / "state.json").unlink(missing_ok=True)
        log.info("all stopped")


# ----------------------------------------------------------------------------- client side
def _read_state(run_dir: Path) -> dict | None:
    try:
        return json.loads((run_dir / "state.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def _pid_alive(pid: int | None) -> bool:
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # A zombie still answers kill(0); treat it as gone.
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


def alive_nodes(endpoint: str | None, rig: str, timeout: float = 2.0, *, secrets: str | os.PathLike | None = None,
                identity: str = "observer") -> set[str] | None:
    """Names of nodes whose liveliness tokens are present (None if no endpoint to ask).

    A secure deployment answers only an authenticated identity: pass its `secrets` folder.
    """
    if not endpoint:
        return None
    from cinetransfer.shared import keys, zenoh_config

    opts = zenoh_config.ZenohOptions(mode="client", connect=(endpoint,), secrets=str(secrets) if secrets else None,
                                     identity=identity if secrets else None)
    try:
        with zenoh_config.open_session(opts) as s:
            replies = s.liveliness().get(keys.all_alive(rig), timeout=timeout)
            return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}
    except Exception as e:  # zenoh raises ZError for an unreachable router
        log.debug("liveliness query failed: %s", e)
        return set()


def _alive(cfg: DeployConfig, run_dir: Path, endpoint: str | None, rig: str, timeout: float) -> set[str] | None:
    return alive_nodes(endpoint, rig, timeout, secrets=secrets_dir(cfg, run_dir) if cfg.secure else None)


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


def cmd_check(names: list[str]) -> int:
    try:
        cfgs = [load_config(n) for n in names]
    except ConfigError as e:
        print(f"cinetransfer deploy check: {e}", file=sys.stderr)
        return 2
    problems = dataflow_problems(cfgs)
    for msg in problems:
        print(f"cinetransfer deploy check: {msg}", file=sys.stderr)
    if problems:
        return 1
    n = sum(len(c.nodes) for c in cfgs)
    print(f"deploy check: {' + '.join(c.name for c in cfgs)}: {n} nodes, every key read is written, "
          f"no exclusive key has two writers")
    return 0


def cmd_up(cfg: DeployConfig, run_dir: Path, wait: bool, foreground: bool, owner_pid: int | None = None) -> int:
    run_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    lock_fd = _try_lock(run_dir)
    if lock_fd is None:
        state = _read_state(run_dir) or {}
        print(f"deploy {cfg.name}: already running (supervisor pid {state.get('supervisor_pid', '?')}, run folder "
              f"{run_dir}); use 'cinetransfer deploy down {cfg.name}' first", file=sys.stderr)
        return 1
    try:
        leftovers = running_procs(run_dir)
        if leftovers:
            print(f"deploy {cfg.name}: processes of an earlier run are still alive "
                  f"({', '.join(f'{n} pid {p}' for p, n in sorted(leftovers.items()))}); "
                  f"use 'cinetransfer deploy down {cfg.name}' first", file=sys.stderr)
            return 1
        try:
            prepare_security(cfg, run_dir)
        except ConfigError as e:
            print(f"deploy {cfg.name}: {e}", file=sys.stderr)
            return 2
        (run_dir / "state.json").unlink(missing_ok=True)
        argv = [sys.executable, "-m", "cinetransfer", "deploy", "_supervise", cfg.path,
                "--run-dir", str(run_dir), "--lock-fd", str(lock_fd),
                *(["--owner-pid", str(owner_pid)] if owner_pid else [])]
        env = {**os.environ, ENV_RUN_DIR: str(run_dir), ENV_PROC: "supervisor"}
        if foreground:
            sup = subprocess.Popen(argv, pass_fds=(lock_fd,), env=env)
            while True:
                try:
                    return sup.wait()
                except KeyboardInterrupt:  # the supervisor got the same Ctrl-C and is stopping the nodes;
                    continue  # killing it now (what subprocess.call does) would orphan them
        with open(run_dir / "supervisor.log", "ab") as logf:
            # The supervisor inherits the locked file: the lock lives exactly as long as it does.
            sup = subprocess.Popen(argv, stdout=logf, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                   start_new_session=True, pass_fds=(lock_fd,), env=env)
    finally:
        os.close(lock_fd)
    print(f"deploy {cfg.name}: supervisor pid {sup.pid}; logs in {run_dir}/")
    if not wait:
        return 0
    want = {p.name for p in cfg.nodes}
    deadline = time.monotonic() + cfg.startup_timeout_s
    seen: set[str] | None = set()
    while time.monotonic() < deadline:
        if sup.poll() is not None:
            print(f"deploy {cfg.name}: supervisor exited ({sup.returncode}); see {run_dir}/supervisor.log",
                  file=sys.stderr)
            return 1
        seen = _alive(cfg, run_dir, cfg.check_endpoint, cfg.rig, timeout=1.0)
        if seen is None:  # no router to ask: being started is all we can check
            break
        if want <= seen:
            break
        time.sleep(0.3)
    else:
        missing = sorted(want - (seen or set()))
        print(f"deploy {cfg.name}: not alive after {cfg.startup_timeout_s:.0f}s: {', '.join(missing)} "
              f"(see {run_dir}/<node>.log); still supervised — 'deploy down {cfg.name}' to stop", file=sys.stderr)
        return 1
    print(f"deploy {cfg.name}: up — {', '.join(p.name for p in cfg.procs)}")
    return 0


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


def cmd_down(cfg: DeployConfig, run_dir: Path, timeout: float) -> int:
    procs = running_procs(run_dir)
    if not procs:
        (run_dir / "state.json").unlink(missing_ok=True)
        print(f"deploy {cfg.name}: not running (run folder {run_dir})")
        return 0
    sups = [p for p, n in procs.items() if n == "supervisor"]
    if sups:  # the supervisor stops its children in order (nodes, then routers)
        for p in sups:
            _signal(p, signal.SIGTERM)
    else:  # orphans (their supervisor was killed): stop them directly
        for p in procs:
            _signal(p, signal.SIGINT)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and running_procs(run_dir):
        time.sleep(0.1)
    leftovers = running_procs(run_dir)
    for p, n in sorted(leftovers.items()):
        print(f"deploy {cfg.name}: killing leftover {n} (pid {p})", file=sys.stderr)
        _signal(p, signal.SIGKILL)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and running_procs(run_dir):
        time.sleep(0.1)
    still = running_procs(run_dir)
    if still:
        print(f"deploy {cfg.name}: could not stop pids {sorted(still)}", file=sys.stderr)
        return 1
    (run_dir / "state.json").unlink(missing_ok=True)
    print(f"deploy {cfg.name}: down")
    return 0


def cmd_status(cfg: DeployConfig, run_dir: Path) -> int:
    procs = running_procs(run_dir)
    if not procs:
        print(f"deploy {cfg.name}: not running (run folder {run_dir})")
        return 3
    by_name = {n: p for p, n in procs.items()}
    state = _read_state(run_dir) or {}
    sup = by_name.get("supervisor")
    if sup is None:
        print(f"deploy {cfg.name}: NO SUPERVISOR, yet {len(procs)} process(es) of it are alive "
              f"({', '.join(f'{n} pid {p}' for p, n in sorted(procs.items()))}); "
              f"'cinetransfer deploy down {cfg.name}' stops them")
        return 1
    alive = _alive(cfg, run_dir, cfg.check_endpoint, cfg.rig, timeout=1.0)
    print(f"deploy {cfg.name} (rig {cfg.rig}): supervisor pid {sup}; run folder {run_dir}")
    print(f"  {'name':<20} {'kind':<7} {'pid':>8} {'restarts':>8}  alive")
    for p in cfg.procs:
        restarts = (state.get("procs", {}).get(p.name) or {}).get("restarts", "?")
        live = "-" if p.kind == "router" or alive is None else ("yes" if p.name in alive else "NO")
        print(f"  {p.name:<20} {p.kind:<7} {by_name.get(p.name, 'down')!s:>8} {restarts!s:>8}  {live}")
    return 0


def cmd_logs(cfg: DeployConfig, run_dir: Path, node: str, follow: bool, lines: int) -> int:
    names = [p.name for p in cfg.procs] + ["supervisor"]
    if node not in names:
        print(f"deploy {cfg.name}: no process named {node!r}; one of {', '.join(names)}", file=sys.stderr)
        return 2
    path = run_dir / f"{node}.log"
    if not path.exists():
        print(f"deploy {cfg.name}: no log yet at {path}", file=sys.stderr)
        return 1
    with open(path, "rb") as f:
        data = f.read().decode(errors="replace").splitlines()
        sys.stdout.write("\n".join(data[-lines:]) + "\n")
        sys.stdout.flush()
        while follow:
            chunk = f.read()
            if chunk:
                sys.stdout.write(chunk.decode(errors="replace"))
                sys.stdout.flush()
            else:
                time.sleep(0.2)
    return 0


def main(argv: list[str]) -> int:
    if argv[:1] == ["certs"]:
        from cinetransfer.deploy import certs

        return certs.main(argv[1:])
    if argv[:1] == ["check"]:
        if len(argv) < 2 or argv[1] in ("-h", "--help"):
            print("usage: cinetransfer deploy check CONFIG [CONFIG ...]\n\ncheck configs that form one deployment "
                  "against the declared dataflow (deploy/dataflow.yaml)")
            return 0 if len(argv) > 1 else 2
        return cmd_check(argv[1:])
    p = argparse.ArgumentParser(prog="cinetransfer deploy", description=__doc__.splitlines()[0],
                                epilog="'cinetransfer deploy certs DIR' creates a CA, certificates and passwords "
                                       "for a secure split deployment (docs/security.md).")
    # the metavar lists the public commands: the internal '_supervise' has no help row and no mention
    sub = p.add_subparsers(dest="cmd", required=True, metavar="{up,down,status,logs,certs,check}")

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("config", help="config name (local, ground, onboard) or path to a YAML file")
        sp.add_argument("--run-dir", default=None,
                        help="state, logs and generated credentials (default $CT_STATE_DIR/deploy/<config>, "
                             "$CT_STATE_DIR defaulting to $XDG_STATE_HOME/cinetransfer)")

    up = sub.add_parser("up", help="start the config's routers and nodes under a supervisor")
    common(up)
    up.add_argument("--no-wait", action="store_true", help="return without waiting for the nodes to be alive")
    up.add_argument("--foreground", action="store_true", help="supervise in this terminal (Ctrl-C stops all)")
    up.add_argument("--owner-pid", type=int, default=None, metavar="PID",
                    help="stop the deployment when process PID ends (the transfer passes its own)")
    down = sub.add_parser("down", help="stop everything the config started")
    common(down)
    down.add_argument("--timeout", type=float, default=30.0)
    st = sub.add_parser("status", help="processes, pids, restarts and liveliness")
    common(st)
    lg = sub.add_parser("logs", help="print a node's log")
    common(lg)
    lg.add_argument("node")
    lg.add_argument("-f", "--follow", action="store_true")
    lg.add_argument("-n", "--lines", type=int, default=50)
    sub.add_parser("certs", help="create a CA, per-node certificates and passwords in DIR")
    sub.add_parser("check", help="check configs (one deployment) against the declared dataflow")
    sv = sub.add_parser("_supervise")
    common(sv)
    sv.add_argument("--lock-fd", type=int, default=None)
    sv.add_argument("--owner-pid", type=int, default=None)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_config(args.config)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer deploy")
    return _run_command(args, cfg, resolve_run_dir(cfg, args.run_dir))


def _run_command(args: argparse.Namespace, cfg: DeployConfig, run_dir: Path) -> int:
    if args.cmd == "_supervise":
        if os.environ.get(ENV_RUN_DIR) != str(run_dir) or args.lock_fd is None:
            print("cinetransfer deploy _supervise is started by 'deploy up' (use 'up --foreground')", file=sys.stderr)
            return 2
        fcntl.flock(args.lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # ours already (inherited); fails otherwise
        return Supervisor(cfg, run_dir, owner_pid=args.owner_pid).run()
    if args.cmd == "up":
        problems = dataflow_problems([cfg], grants=False)  # (test rigs may grant keys of their own)
        if problems:
            for msg in problems:
                print(f"cinetransfer deploy up: {msg}", file=sys.stderr)
            print("cinetransfer deploy up: refused (see deploy/dataflow.yaml; 'cinetransfer deploy check')",
                  file=sys.stderr)
            return 2
        return cmd_up(cfg, run_dir, wait=not args.no_wait, foreground=args.foreground, owner_pid=args.owner_pid)
    if args.cmd == "down":
        return cmd_down(cfg, run_dir, args.timeout)
    if args.cmd == "status":
        return cmd_status(cfg, run_dir)
    return cmd_logs(cfg, run_dir, args.node, args.follow, args.lines)
