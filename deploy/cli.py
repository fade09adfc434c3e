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
import errno
import fcntl
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from cinetransfer.deploy.config import DeployConfig, dataflow_problems, load_config
from cinetransfer.deploy.rundir import (
    ENV_PROC,
    ENV_RUN_DIR,
    FULL_BYTES,
    free_bytes,
    read_state,
    resolve_run_dir,
    running_procs,
    try_lock,
)
from cinetransfer.deploy.security import prepare_security, secrets_dir
from cinetransfer.deploy.supervision import Supervisor
from cinetransfer.shared.errors import ConfigError, report_config_error

log = logging.getLogger("cinetransfer.deploy")


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
    """`up` on a run folder that cannot be written (missing, read-only, full) is one line, exit 1,
    and leaves no folder it made behind."""
    made = not run_dir.exists()
    try:
        run_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        free = free_bytes(run_dir)
        if free is not None and free < FULL_BYTES:
            raise OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} ({free >> 10} KB free; a deployment needs "
                                        f"{FULL_BYTES >> 20} MB for its logs and state)")
        return _up(cfg, run_dir, wait, foreground, owner_pid)
    except OSError as e:
        print(f"cinetransfer deploy: cannot write the run folder {run_dir}: {e.strerror or e}", file=sys.stderr)
        if made:
            shutil.rmtree(run_dir, ignore_errors=True)
        return 1


def _up(cfg: DeployConfig, run_dir: Path, wait: bool, foreground: bool, owner_pid: int | None) -> int:
    lock_fd = try_lock(run_dir)
    if lock_fd is None:
        state = read_state(run_dir) or {}
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
    state = read_state(run_dir) or {}
    sup = by_name.get("supervisor")
    if sup is None:
        print(f"deploy {cfg.name}: NO SUPERVISOR, yet {len(procs)} process(es) of it are alive "
              f"({', '.join(f'{n} pid {p}' for p, n in sorted(procs.items()))}); "
              f"'cinetransfer deploy down {cfg.name}' stops them")
        return 1
    alive = _alive(cfg, run_dir, cfg.check_endpoint, cfg.rig, timeout=1.0)
    print(f"deploy {cfg.name} (rig {cfg.rig}): supervisor pid {sup}; run folder {run_dir}")
    free = free_bytes(run_dir)
    if free is not None and free < FULL_BYTES:
        print(f"  RUN FOLDER FULL ({free >> 10} KB free): logs and state.json are not being written; "
              "the nodes run on")
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
