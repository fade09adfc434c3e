"""Shared fixtures: free loopback ports, Zenoh options, data paths, node processes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cinetransfer.data import data_dir
from cinetransfer.shared.zenoh_config import ZenohOptions, free_tcp_port

REPO = Path(__file__).resolve().parents[1]


free_port = free_tcp_port  # tests use the same helper as the transfer command


@pytest.fixture(autouse=True)
def _own_cache_dir(tmp_path_factory, monkeypatch):
    """Every test has its own cache folder ($CT_CACHE_DIR, inherited by the processes it starts):
    a style one test extracted is never another test's cache hit (cinetransfer/style_cache.py)."""
    monkeypatch.setenv("CT_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture
def port() -> int:
    return free_port()


@pytest.fixture
def data() -> Path:
    try:
        return data_dir()
    except FileNotFoundError as e:
        pytest.fail(str(e))


@pytest.fixture(scope="module")
def pose_detector():
    """The project's detector (MediaPipe pose, no focus map, one thread), one per test module."""
    try:
        from cinetransfer.services.detector.config import DetectorConfig
        from cinetransfer.services.detector.core import Detector
        det = Detector(DetectorConfig(focus=False, threads=1))
    except Exception as e:  # noqa: BLE001 - any backend failure means: cannot run this check here
        pytest.skip(f"detector backend unavailable: {e}")
    yield det
    det.close()


@pytest.fixture
def listener_opts(port: int) -> ZenohOptions:
    """Options for the test's own session: it listens, node processes connect to it."""
    return ZenohOptions(mode="peer", listen=(f"tcp/127.0.0.1:{port}",))


def connect_flags(port: int) -> list[str]:
    return ["--connect", f"tcp/127.0.0.1:{port}", "--listen", "tcp/127.0.0.1:0"]


def load_benchmark(name: str):
    """benchmarks/NAME.py as a module (the folder is scripts, not a package); registered in
    sys.modules so that its dataclasses can look their module up."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"bench_{name}", REPO / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def cli(*args: str, env: dict | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run `python -m cinetransfer ARGS...` to its end as a real process."""
    return subprocess.run([sys.executable, "-m", "cinetransfer", *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})


def mount_tmpfs(mnt: Path, options: str):
    """Yield `mnt` with a fresh tmpfs mounted on it (e.g. "size=2m", "ro,size=1m"), unmounted after;
    skips where mounting is not allowed (CI runs as root)."""
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def spawn(*args: str, log: Path | None = None, env: dict | None = None) -> subprocess.Popen:
    """Start `python -m cinetransfer ARGS...` as a real process."""
    out = open(log, "wb") if log else subprocess.DEVNULL
    try:
        # PYTHONFAULTHANDLER: a process that hangs at exit is made to print every thread's stack (see stop)
        return subprocess.Popen([sys.executable, "-m", "cinetransfer", *args], stdout=out, stderr=subprocess.STDOUT,
                                env={**os.environ, "PYTHONFAULTHANDLER": "1", **(env or {})})
    finally:
        if log:
            out.close()  # the child keeps its own descriptor


def stop(proc: subprocess.Popen, timeout: float = 15.0) -> int:
    """SIGINT, then wait; a process that does not exit gets SIGABRT, which makes a spawned one write
    every thread's stack into its log (the evidence of a hang), then SIGKILL; the caller fails on
    the return code (-6 or -9)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            try:
                return proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                return proc.wait()
    return proc.returncode


def wait_for(pred, timeout: float = 20.0, interval: float = 0.02, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout}s waiting for {what}")
