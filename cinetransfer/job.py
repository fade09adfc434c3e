"""The deployment a transfer runs on: its own (a router and the five nodes, started and stopped
here as separate processes) or a running one it joins as the operator."""
from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import yaml

from cinetransfer.deploy import join
from cinetransfer.shared import zenoh_config
from cinetransfer.shared.node import Presence

log = logging.getLogger("cinetransfer.transfer")


class TransferError(RuntimeError):
    """A step of the transfer failed; the message says which and where its log is."""


def run_cli(args: list[str], what: str) -> None:
    """Run `cinetransfer ARGS` as a child process (progress bars go to the terminal)."""
    Background(args, what).wait()


class Background:
    """`cinetransfer ARGS` running as a child process while the transfer goes on; `wait()` for it."""

    def __init__(self, args: list[str], what: str, then: Any = None) -> None:
        self.args, self.what, self.then = args, what, then
        log.info("%s: %s", what, " ".join(args))
        self.proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", *args])

    def wait(self) -> None:
        """Wait for it to end (a Ctrl-C meanwhile does not orphan it); TransferError if it failed."""
        while True:
            try:
                rc = self.proc.wait()
                break
            except KeyboardInterrupt:  # the child got the same Ctrl-C; let it finish what it does
                continue
        if self.then is not None:
            self.then()
        if rc != 0:
            raise TransferError(f"{self.what} failed (exit {rc}): cinetransfer {' '.join(self.args)}")


class DeployDown:
    """`cinetransfer deploy ARGS` (down) on a thread of this process while the transfer goes on; `wait()`
    for it, as for a Background. It only signals the supervisor and waits for the run folder's
    processes to end: a child interpreter for it cost its start and imports (~0.2 CPU s) for that."""

    def __init__(self, args: list[str], what: str, then: Any = None) -> None:
        from cinetransfer.deploy.cli import main as deploy_main  # imported here: not beside another thread

        self.args, self.what, self.then = args, what, then
        self.rc: int | None = None
        log.info("%s: cinetransfer deploy %s", what, " ".join(args))
        self._thread = threading.Thread(target=self._run, args=(deploy_main,), name="deploy-down", daemon=True)
        self._thread.start()

    def _run(self, deploy_main: Any) -> None:
        try:
            self.rc = deploy_main(self.args)
        except SystemExit as e:  # argparse's refusal: its exit code, as the command's
            self.rc = e.code if isinstance(e.code, int) else 1
        except BaseException as e:  # noqa: BLE001 - handed to wait(), which says it in one line
            log.error("%s: %s: %s", self.what, type(e).__name__, e)
            self.rc = 1

    def wait(self) -> None:
        """Wait for it to end (a Ctrl-C meanwhile does not cut it short); TransferError if it failed."""
        while True:
            try:
                self._thread.join()
                break
            except KeyboardInterrupt:  # the nodes are being stopped already; let it finish that
                continue
        if self.then is not None:
            self.then()
        if self.rc != 0:
            raise TransferError(f"{self.what} failed (exit {self.rc}): cinetransfer deploy {' '.join(self.args)}")


#: simulated seconds per wall second of the own deployment's simulation before the take: a step
#: (state, clock tick, a planner solve) every 5 s and a camera frame's truth every ~4 s. The take
#: never waits for it: a command ends the bridge's pacing sleep, and the flight asks for steps
IDLE_PACE = 0.01
#: the nodes of the whole job, each a separate process (see deploy/dataflow.yaml)
JOB_NODES = ("source", "detector", "smoother", "planner", "autopilot_bridge")
#: the nodes that extract the style, and the flags the transfer's own deployment gives them (the
#: style cache computes their effective settings from the same flags: cinetransfer/style_cache.py);
#: the smoother publishes no streaming window: the transfer flies the whole sequence only
EXTRACTION_ARGS = {"source": [], "detector": ["--input", "source"],
                   "smoother": ["--end-idle", "0", "--publish-period", "0"]}


def deploy_config(outdir: Path, port: int, rig: str, scene: str, *, realtime: bool = False,
                  subject: str | None = None, vehicle: str | None = None, extraction: bool = True) -> Path:
    """A deploy config for this run: a router on `port` and the five nodes of the dataflow (without
    the three extraction nodes when the style is known already: `extraction` False)."""
    # until the take resets it, the simulation has no audience: it renders no frame and goes at a slow
    # pace beside the extraction (it rendered 9 CPU s of frames nobody recorded while a 72-frame style
    # was extracted); the take itself runs at the transfer's pace
    # the scene's keep-out obstacles, derived once here: the planner keeps clear of them and the bridge's
    # safety layer counts the measured vehicle among them as outside its envelope
    obstacles = scene_obstacle_settings(scene, subject)
    # and its fixed surfaces (a hedge, a backdrop) and ground: the planner's map of how deep what it frames lies
    scene_map = scene_map_settings(scene, subject)
    bridge = ["--backend", "sim", "--scene", scene, *(["--subject", subject] if subject else []),
              *([] if realtime else ["--pace", str(IDLE_PACE), "--no-frames-before-reset"]),
              *(["--realtime"] if realtime else []), *(["--vehicle", vehicle] if vehicle else [])]
    cfg = {
        "description": "generated by cinetransfer transfer",
        "rig": rig,
        # the router keeps out of shared memory, so frames cross it as copies over TCP (~2.3-3.5 CPU s a
        # README run): with it, a camera frame was lost between the bridge and the transfer once, when two
        # transfers shared the loaded machine (a shared-memory chunk a starved receiver read late is dropped
        # silently), and the take waited for that frame until its stall timeout
        "routers": [{"name": "router", "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]}}],
        "defaults": {"zenoh": {"mode": "client", "connect": [f"tcp/127.0.0.1:{port}"], "shm": True}},
        "nodes": [
            *([{"name": n, "command": n, "args": list(a)} for n, a in EXTRACTION_ARGS.items()] if extraction else []),
            {"name": "autopilot_bridge", "command": "autopilot_bridge", "args": bridge,
             "settings": {"safety": {"obstacles_m": obstacles}}},
            {"name": "planner", "command": "planner", "args": ["--vehicle", vehicle] if vehicle else [],
             "settings": {"obstacles_m": [list(o) for o in obstacles], **scene_map}},
        ],
        "restart": {"backoff_initial_s": 0.5, "stop_grace_s": 10, "startup_timeout_s": 180},
    }
    path = outdir / "deploy" / "transfer.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def scene_obstacle_settings(scene: str, subject: str | None = None) -> list[list[float]]:
    """The keep-out obstacles of simulator scene `scene` (a name or a YAML file) as settings files write
    them (shared/obstacles.py)."""
    from cinetransfer.services.autopilot_bridge.sim.obstacles import scene_obstacles
    from cinetransfer.services.autopilot_bridge.sim.scene import load_scene

    return [o.as_list() for o in scene_obstacles(load_scene(scene, subject=subject))]


def scene_map_settings(scene: str, subject: str | None = None) -> dict[str, object]:
    """The planner's map of simulator scene `scene` (a name or a YAML file) as its settings: the fixed upright
    surfaces (`surfaces_m`, shared/surfaces.py) and the ground's height (`ground_z_m`, when the scene has one)."""
    from cinetransfer.services.autopilot_bridge.sim.scene import load_scene
    from cinetransfer.services.autopilot_bridge.sim.surfaces import scene_surfaces

    sc = load_scene(scene, subject=subject)
    out: dict[str, object] = {"surfaces_m": [s.as_list() for s in scene_surfaces(sc)]}
    if sc.ground is not None:
        out["ground_z_m"] = float(sc.ground.z_m)
    return out


@contextmanager
def deployment(args, out: Path, *, extraction: bool = True,
               stopping: list[DeployDown] | None = None) -> Iterator[zenoh_config.ZenohOptions]:
    """The session options of the transfer's deployment: `--deployment` or `--connect` join a
    running one; otherwise one is started under OUTDIR/deploy (without the extraction nodes when
    `extraction` is False) and stopped again on leaving: in the background when the caller gives
    a `stopping` list to wait on later (the evaluation needs no node), else before returning.

    The nodes start in parallel; this returns as soon as the router listens (the caller waits for
    the nodes it needs, when it needs them: `wait_alive`)."""
    if args.deployment:
        yield join.deployment_options(args.deployment, "operator", shared_memory=True)
        return
    if args.connect:
        yield zenoh_config.options_from_args(args, mode="client")
        return
    deploy_dir = out / "deploy"
    port = zenoh_config.free_tcp_port()
    cfg_path = deploy_config(out, port, args.rig, args.scene, realtime=args.realtime,
                             subject=args.subject, vehicle=args.vehicle, extraction=extraction)
    # the nodes end with this process even if it is killed outright (SIGKILL): no orphan deployment
    deploy_up(["up", str(cfg_path), "--run-dir", str(deploy_dir), "--owner-pid", str(os.getpid()), "--no-wait"])
    try:
        await_router(port, deploy_dir, 180.0)
        # the deployment is secure by default: join as the operator with its generated credentials
        yield join.deployment_options(cfg_path, "operator", run_dir=deploy_dir, shared_memory=True)
    finally:
        # the run's generated credentials are worthless once its router is gone: don't keep them
        down = DeployDown(["down", str(cfg_path), "--run-dir", str(deploy_dir)], "stopping nodes",
                          then=lambda: shutil.rmtree(deploy_dir / "secrets", ignore_errors=True))
        if stopping is None:
            down.wait()
        else:
            stopping.append(down)


def deploy_up(args: list[str]) -> None:
    """`cinetransfer deploy ARGS` (up --no-wait) in this process: it only starts the detached
    supervisor, and a child interpreter for it cost ~0.3 CPU s and its start-up's wall time before
    any node began; TransferError if it fails (it says why on stderr, as the command does)."""
    from cinetransfer.deploy.cli import main as deploy_main

    log.info("starting nodes: cinetransfer deploy %s", " ".join(args))
    rc = deploy_main(args)
    if rc != 0:
        raise TransferError(f"starting nodes failed (exit {rc}): cinetransfer deploy {' '.join(args)}")


def await_router(port: int, deploy_dir: Path, timeout: float) -> None:
    """Return once the deployment's router accepts connections on 127.0.0.1:`port`."""
    import socket

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.05)
    raise TransferError(f"the deployment's router did not listen within {timeout:.0f} s "
                        f"(see {deploy_dir}/router.log)")


def await_subscriber(publisher, timeout: float) -> bool:
    """Wait until a subscriber matches `publisher` (False after `timeout` s). A node's liveliness
    token can reach this session before its subscriptions do, and a command put in between is
    dropped: a command to a node that has just come up waits for this first."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            if publisher.matching_status.matching:
                return True
        except AttributeError:  # a zenoh without matching status: nothing to wait for
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)


#: how often `wait_alive` looks at the nodes' liveliness flags (no message: a flag read)
ALIVE_LOOK_S = 0.02


def wait_alive(session, rig: str, names: set[str], timeout: float) -> None:
    """Return once every node in `names` has its liveliness token up; TransferError after `timeout` s.
    The tokens are watched by subscribers (shared.node.Presence), not asked for: asking every 0.2 s
    saw a node up to 0.2 s late, at the nodes' start and again before the flight."""
    watch = {n: Presence(session, rig, n) for n in sorted(names)}
    try:
        deadline = time.monotonic() + timeout
        while not all(p.alive for p in watch.values()):
            if time.monotonic() >= deadline:
                missing = [n for n, p in watch.items() if not p.alive]
                raise TransferError(f"nodes not alive after {timeout:.0f}s: {', '.join(missing)}")
            time.sleep(ALIVE_LOOK_S)
    finally:
        for p in watch.values():
            p.undeclare()
