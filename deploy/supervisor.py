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
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

log = logging.getLogger("cinetransfer.deploy")
CONFIG_DIR = Path(__file__).resolve().parent / "configs"
_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


class ConfigError(ValueError):
    """The deploy config is invalid; the message names the field."""


# ----------------------------------------------------------------------------- config
@dataclasses.dataclass(frozen=True)
class Proc:
    name: str
    kind: str  # 'router' | 'node'
    argv: tuple[str, ...]  # arguments after `python -m cinetransfer`


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

    @property
    def procs(self) -> tuple[Proc, ...]:
        return self.routers + self.nodes


def _subst(value: Any) -> Any:
    if isinstance(value, str):
        return _VAR.sub(lambda m: os.environ.get(m.group(1), m.group(2) if m.group(2) is not None else ""), value)
    return value


def resolve_config_path(name_or_path: str) -> Path:
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise ConfigError(f"deploy config {p} does not exist")
        return p
    shipped = CONFIG_DIR / f"{name_or_path}.yaml"
    if not shipped.is_file():
        names = ", ".join(sorted(f.stem for f in CONFIG_DIR.glob("*.yaml")))
        raise ConfigError(f"no deploy config named {name_or_path!r}; shipped configs: {names}")
    return shipped


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


def load_config(name_or_path: str) -> DeployConfig:
    path = resolve_config_path(name_or_path)
    try:
        # Substitute before parsing so that ${VAR} may stand inside flow sequences too.
        raw = yaml.safe_load(_subst(path.read_text()))
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: top level must be a mapping")
    unknown = set(raw) - {"rig", "routers", "nodes", "defaults", "restart", "check_endpoint", "description"}
    if unknown:
        raise ConfigError(f"{path}: unknown top-level keys {sorted(unknown)}")
    rig = str(raw.get("rig", "rig0"))
    defaults = raw.get("defaults") or {}
    routers = []
    for i, r in enumerate(raw.get("routers") or []):
        if not isinstance(r, dict) or "name" not in r:
            raise ConfigError(f"{path}: routers[{i}] needs a name")
        argv = ["router", *_zenoh_flags({"mode": "router", **(r.get("zenoh") or {})}, f"routers[{i}]")]
        routers.append(Proc(str(r["name"]), "router", tuple(argv)))
    nodes = []
    for i, n in enumerate(raw.get("nodes") or []):
        if not isinstance(n, dict) or "name" not in n or "command" not in n:
            raise ConfigError(f"{path}: nodes[{i}] needs 'name' and 'command'")
        args = n.get("args") or []
        if not isinstance(args, list):
            raise ConfigError(f"{path}: nodes[{i}].args must be a list")
        z = {**(defaults.get("zenoh") or {}), **(n.get("zenoh") or {})}
        argv = [str(n["command"]), *map(str, args), "--rig", rig, *_zenoh_flags(z, f"nodes[{i}]")]
        nodes.append(Proc(str(n["name"]), "node", tuple(argv)))
    names = [p.name for p in routers + nodes]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"{path}: duplicate process names {sorted(dup)}")
    if not nodes and not routers:
        raise ConfigError(f"{path}: nothing to run (no routers, no nodes)")
    restart = raw.get("restart") or {}
    check = raw.get("check_endpoint")
    if check is None and raw.get("routers"):
        listen = ((raw["routers"][0].get("zenoh") or {}).get("listen") or [None])[0]
        if listen is not None and not isinstance(listen, str):
            raise ConfigError(f"{path}: routers[0].zenoh.listen entries must be strings like tcp/127.0.0.1:7447")
        check = listen.replace("0.0.0.0", "127.0.0.1") if listen else None
    try:
        return DeployConfig(name=path.stem, path=str(path.resolve()), rig=rig, routers=tuple(routers), nodes=tuple(nodes), check_endpoint=check,
                            backoff_initial_s=float(restart.get("backoff_initial_s", 0.5)),
                            backoff_max_s=float(restart.get("backoff_max_s", 10.0)),
                            backoff_reset_s=float(restart.get("backoff_reset_s", 30.0)),
                            stop_grace_s=float(restart.get("stop_grace_s", 10.0)),
                            startup_timeout_s=float(restart.get("startup_timeout_s", 90.0)))
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{path}: restart: {e}") from None


# ----------------------------------------------------------------------------- supervisor
class Supervisor:
    """Runs in the detached supervisor process: start, watch, restart, stop."""

    def __init__(self, cfg: DeployConfig, run_dir: Path) -> None:
        self.cfg, self.run_dir = cfg, run_dir
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
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.children[proc.name] = subprocess.Popen([sys.executable, "-m", "cinetransfer", *proc.argv], stdout=logf,
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
        tmp = self.run_dir / "state.json.tmp"
        tmp.write_text(json.dumps(state, indent=2))
        tmp.replace(self.run_dir / "state.json")

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


def alive_nodes(endpoint: str | None, rig: str, timeout: float = 2.0) -> set[str] | None:
    """Names of nodes whose liveliness tokens are present (None if no endpoint to ask)."""
    if not endpoint:
        return None
    from cinetransfer.shared import keys, zenoh_config

    opts = zenoh_config.ZenohOptions(mode="client", connect=(endpoint,))
    try:
        with zenoh_config.open_session(opts) as s:
            replies = s.liveliness().get(keys.all_alive(rig), timeout=timeout)
            return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}
    except Exception as e:  # zenoh raises ZError for an unreachable router
        log.debug("liveliness query failed: %s", e)
        return set()


def cmd_up(cfg: DeployConfig, run_dir: Path, wait: bool, foreground: bool) -> int:
    state = _read_state(run_dir)
    if state and _pid_alive(state.get("supervisor_pid")):
        print(f"deploy {cfg.name}: already running (supervisor pid {state['supervisor_pid']}); "
              f"use 'cinetransfer deploy down {cfg.name}' first", file=sys.stderr)
        return 1
    run_dir.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "cinetransfer", "deploy", "_supervise", cfg.path,
            "--run-dir", str(run_dir)]
    if foreground:
        return subprocess.call(argv)
    with open(run_dir / "supervisor.log", "ab") as logf:
        sup = subprocess.Popen(argv, stdout=logf, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               start_new_session=True)
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
        seen = alive_nodes(cfg.check_endpoint, cfg.rig, timeout=1.0)
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


def cmd_down(cfg: DeployConfig, run_dir: Path, timeout: float) -> int:
    state = _read_state(run_dir)
    if not state:
        print(f"deploy {cfg.name}: not running")
        return 0
    pids = [v["pid"] for v in state["procs"].values() if v.get("pid")]
    sup = state.get("supervisor_pid")
    if _pid_alive(sup):
        os.kill(sup, signal.SIGTERM)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and (_pid_alive(sup) or any(_pid_alive(p) for p in pids)):
        time.sleep(0.1)
    leftovers = [p for p in [sup, *pids] if _pid_alive(p)]
    for p in leftovers:
        with_kill = f"killing leftover pid {p}"
        print(f"deploy {cfg.name}: {with_kill}", file=sys.stderr)
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    (run_dir / "state.json").unlink(missing_ok=True)
    print(f"deploy {cfg.name}: down")
    return 0


def cmd_status(cfg: DeployConfig, run_dir: Path) -> int:
    state = _read_state(run_dir)
    if not state or not _pid_alive(state.get("supervisor_pid")):
        print(f"deploy {cfg.name}: not running")
        return 3
    alive = alive_nodes(state.get("check_endpoint"), state["rig"], timeout=1.0)
    print(f"deploy {cfg.name} (rig {state['rig']}): supervisor pid {state['supervisor_pid']}")
    print(f"  {'name':<20} {'kind':<7} {'pid':>8} {'restarts':>8}  alive")
    for name, v in state["procs"].items():
        live = "-" if v["kind"] == "router" or alive is None else ("yes" if name in alive else "NO")
        pid = v["pid"] if v["pid"] and _pid_alive(v["pid"]) else "down"
        print(f"  {name:<20} {v['kind']:<7} {pid!s:>8} {v['restarts']:>8}  {live}")
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
    p = argparse.ArgumentParser(prog="cinetransfer deploy", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("config", help="config name (local, ground, onboard) or path to a YAML file")
        sp.add_argument("--run-dir", default=None, help="state and logs folder (default runs/deploy/<config>)")

    up = sub.add_parser("up", help="start the config's routers and nodes under a supervisor")
    common(up)
    up.add_argument("--no-wait", action="store_true", help="return without waiting for the nodes to be alive")
    up.add_argument("--foreground", action="store_true", help="supervise in this terminal (Ctrl-C stops all)")
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
    sv = sub.add_parser("_supervise", help=argparse.SUPPRESS)
    common(sv)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_config(args.config)
    except ConfigError as e:
        print(f"cinetransfer deploy: {e}", file=sys.stderr)
        return 2
    run_dir = Path(args.run_dir or Path("runs") / "deploy" / cfg.name).resolve()
    if args.cmd == "_supervise":
        run_dir.mkdir(parents=True, exist_ok=True)
        return Supervisor(cfg, run_dir).run()
    if args.cmd == "up":
        return cmd_up(cfg, run_dir, wait=not args.no_wait, foreground=args.foreground)
    if args.cmd == "down":
        return cmd_down(cfg, run_dir, args.timeout)
    if args.cmd == "status":
        return cmd_status(cfg, run_dir)
    return cmd_logs(cfg, run_dir, args.node, args.follow, args.lines)
