"""The supervisor process of a deployment: start its routers and nodes, restart, stop.

Runs detached (started by `cinetransfer deploy up`): one log file per process, restarts any that
exits with exponential back-off, records its state in RUN_DIR/state.json, and stops nodes with
SIGINT (then SIGKILL after a grace period), routers last.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from cinetransfer.deploy.config import DeployConfig, Proc
from cinetransfer.deploy.rundir import ENV_PROC, ENV_RUN_DIR, pid_alive, write_atomic
from cinetransfer.deploy.security import security_flags

log = logging.getLogger("cinetransfer.deploy")


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
        self.write_error: OSError | None = None  #: the first write to the run folder that failed

    def _start(self, proc: Proc) -> None:
        logf = open(self.run_dir / f"{proc.name}.log", "ab")  # (opening needs no free space; writing may)
        try:
            logf.write(f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')} start: cinetransfer {' '.join(proc.argv)}\n"
                       .encode())
            logf.flush()
        except OSError as e:
            self._cannot_write(e)
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
        try:
            write_atomic(self.run_dir / "state.json", json.dumps(state, indent=2))
        except OSError as e:
            self._cannot_write(e)

    def _cannot_write(self, e: OSError) -> None:
        """A full (or failing) run folder costs the state file and the logs, never the supervision:
        the nodes fly on, restarts and `down` still work (processes are found by their mark, not
        by state.json); said once on stderr and in `deploy status`."""
        if self.write_error is None:
            self.write_error = e
            with contextlib.suppress(OSError):
                print(f"cinetransfer deploy: cannot write the run folder {self.run_dir}: {e.strerror or e}; "
                      "supervising on without state.json and logs", file=sys.stderr, flush=True)

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
        if pid_alive(self.owner_pid):
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
