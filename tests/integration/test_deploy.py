"""`cinetransfer deploy`: supervised processes, restart after a crash, clean shutdown."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cinetransfer.deploy.supervisor import ConfigError, _pid_alive, alive_nodes, load_config
from conftest import REPO, wait_for

RELAYS = REPO / "tests" / "data" / "deploy" / "relays.yaml"


def deploy(*args, env, cwd, timeout=150):
    return subprocess.run([sys.executable, "-m", "cinetransfer", "deploy", *args], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def test_shipped_configs_parse(monkeypatch):
    for name in ("local", "ground", "onboard"):
        cfg = load_config(name)
        assert cfg.routers and cfg.nodes
        assert all("--rig" in p.argv for p in cfg.nodes)
    monkeypatch.setenv("CT_ROUTER_PORT", "9999")
    assert "tcp/127.0.0.1:9999" in load_config("local").routers[0].argv
    with pytest.raises(ConfigError, match="no deploy config named 'nope'"):
        load_config("nope")


def test_bad_config_is_refused_with_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("nodes:\n  - command: relay\n")
    with pytest.raises(ConfigError, match=r"nodes\[0\] needs 'name'"):
        load_config(str(bad))


def run_supervised(config: Path, port: int, tmp_path: Path, kill_node: str):
    env = {**os.environ, "CT_ROUTER_PORT": str(port)}
    run_dir = tmp_path / "run"
    r = deploy("up", str(config), "--run-dir", str(run_dir), env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    try:
        cfg = load_config(str(config))
        state = json.loads((run_dir / "state.json").read_text())
        pids = {n: v["pid"] for n, v in state["procs"].items()}
        assert set(pids) == {p.name for p in cfg.procs} and all(_pid_alive(p) for p in pids.values())
        assert {p.name for p in cfg.nodes} <= alive_nodes(f"tcp/127.0.0.1:{port}", cfg.rig)

        # when a node is SIGKILLed, the supervisor restarts it and it is alive again within 5 s
        os.kill(pids[kill_node], signal.SIGKILL)
        t0 = time.monotonic()
        wait_for(lambda: kill_node not in alive_nodes(f"tcp/127.0.0.1:{port}", cfg.rig, 0.5), timeout=5,
                 what="token gone")
        wait_for(lambda: kill_node in alive_nodes(f"tcp/127.0.0.1:{port}", cfg.rig, 0.5), timeout=5,
                 what=f"{kill_node} restarted")
        restart_s = time.monotonic() - t0
        state = json.loads((run_dir / "state.json").read_text())
        assert state["procs"][kill_node]["restarts"] == 1 and state["procs"][kill_node]["pid"] != pids[kill_node]
        assert restart_s < 5.0
        st = deploy("status", str(config), "--run-dir", str(run_dir), env=env, cwd=tmp_path)
        assert st.returncode == 0 and kill_node in st.stdout
        lg = deploy("logs", str(config), kill_node, "--run-dir", str(run_dir), env=env, cwd=tmp_path)
        assert lg.returncode == 0 and lg.stdout.count("=== ") >= 2  # two starts logged
        all_pids = [state["supervisor_pid"], *(v["pid"] for v in state["procs"].values()), *pids.values()]
    finally:
        r = deploy("down", str(config), "--run-dir", str(run_dir), env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    # nothing is left behind
    assert not [p for p in all_pids if _pid_alive(p)]
    assert not (run_dir / "state.json").exists()
    return restart_s


def test_deploy_relays_restart_and_down(port, tmp_path):
    run_supervised(RELAYS, port, tmp_path, "relay_a")


@pytest.mark.slow
def test_deploy_local_real_nodes_restart_and_down(port, tmp_path):
    """The shipped local config: router + bridge(sim) + detector + smoother + planner."""
    from cinetransfer.deploy.supervisor import resolve_config_path

    restart_s = run_supervised(resolve_config_path("local"), port, tmp_path, "smoother")
    assert restart_s < 5.0
