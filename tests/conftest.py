"""Shared fixtures: free loopback ports, Zenoh options, data paths, node processes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from cinetransfer.data import data_dir
from cinetransfer.shared.zenoh_config import ZenohOptions, free_tcp_port

REPO = Path(__file__).resolve().parents[1]

# Hypothesis judges wall time twice by default: a 200 ms deadline per example and a health check
# that fails when generating examples is slow. On a loaded CI machine both fail for speed alone;
# every property test states what it checks, and a test's own @settings still overrides this.
settings.register_profile("clock_free", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("clock_free")


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


def stop(proc: subprocess.Popen, timeout: float = 15.0, limit: float = 120.0) -> int:
    """SIGINT, then wait; a process that does not exit (its CPU time standing still for `timeout`
    seconds: a hang, not a loaded machine's slow shutdown; or `limit` seconds in all) gets SIGABRT,
    which makes a spawned one write every thread's stack into its log (the evidence of a hang), then
    SIGKILL; the caller fails on the return code (-6 or -9)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            wait_for(lambda: proc.poll() is not None, timeout, interval=0.05, what="exit",
                     progress=lambda: cpu_seconds(proc), limit=limit)
            return proc.wait()
        except AssertionError:
            proc.send_signal(signal.SIGABRT)
            try:
                return proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                return proc.wait()
    return proc.returncode


def wait_for(pred, timeout: float = 20.0, interval: float = 0.02, what: str = "condition", *, progress=None,
             limit: float = 1200.0):
    """Poll until `pred()` is true; return its value. Without `progress`: fail after `timeout` seconds.
    With `progress` (a function whose value changes while the awaited thing moves on: frames
    received, a file's size, a starting process's CPU seconds): fail when it has stood still for
    `timeout` seconds, or after `limit` seconds in all (a process spinning in a loop moves on
    forever). A loaded machine gets the time its work takes; a hang is still caught."""
    start = last_move = time.monotonic()
    seen = progress() if progress is not None else None
    while True:
        v = pred()
        if v:
            return v
        now = time.monotonic()
        if progress is not None and (p := progress()) != seen:
            seen, last_move = p, now
        if now - last_move >= timeout:
            still = " with no progress" if progress is not None else ""
            raise AssertionError(f"timed out after {timeout}s{still} waiting for {what}")
        if now - start >= limit:
            raise AssertionError(f"{what} still not there after {limit}s, though it kept moving")
        time.sleep(interval)


def cpu_seconds(proc: subprocess.Popen) -> float:
    """CPU seconds the process has used so far (0.0 once it is gone): the progress of a process that
    is starting up, however slowly a loaded machine lets it."""
    try:
        fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime (proc(5))
