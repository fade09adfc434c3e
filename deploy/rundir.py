"""A deployment's run folder: where it is, its exclusive lock, and the processes it started.

One deployment, one run folder: RUN_DIR is `--run-dir`, else $CT_STATE_DIR/deploy/<config>
(default $XDG_STATE_HOME/cinetransfer, i.e. ~/.local/state/cinetransfer), the same wherever the
command runs. The supervisor holds an exclusive lock on RUN_DIR/lock for its whole life, and every
process it starts carries CT_DEPLOY_RUN_DIR in its environment: processes are found by that mark
and their command line, not by a state file.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
from pathlib import Path

from cinetransfer.deploy.config import DeployConfig
from cinetransfer.shared.atomic import atomic_write

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



#: a run folder with less free space than this is full: `up` refuses it, `status` says so
FULL_BYTES = 1 << 20


def free_bytes(path: Path) -> int | None:
    """Free space for an unprivileged writer under `path` (None: the folder cannot be looked at)."""
    try:
        st = os.statvfs(path)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def write_atomic(path: Path, text: str) -> None:
    """Write via a unique temporary file in the same folder and rename (readers never see half)."""
    with atomic_write(path, mode=0o600) as f:
        f.write(text)



def try_lock(run_dir: Path) -> int | None:
    """An fd holding the deployment's exclusive lock, or None if another process holds it."""
    fd = os.open(run_dir / "lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd



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
        if b"cinetransfer" not in cmd or not pid_alive(int(entry.name)):
            continue
        name = next((e.split(b"=", 1)[1].decode() for e in env if e.startswith(f"{ENV_PROC}=".encode())), "?")
        found[int(entry.name)] = name
    return found



def read_state(run_dir: Path) -> dict | None:
    try:
        return json.loads((run_dir / "state.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def pid_alive(pid: int | None) -> bool:
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
