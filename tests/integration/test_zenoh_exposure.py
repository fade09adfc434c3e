"""One exposure rule for every way to configure Zenoh, shown with real processes and sockets.

Flags, `--zenoh-config FILE`, $CT_ZENOH_CONFIG and deploy configs all reach the same check on the
effective configuration: no listener off loopback without mutual TLS, no peer off loopback. A
refused process prints one line and exits 2, and nothing answers on the address it would have
bound. "Another address" is 127.0.0.2: reachable through a 0.0.0.0 listener, not a 127.0.0.1 one.
"""
import json
import os
import subprocess
import sys

import pytest
import zenoh

from cinetransfer.shared.zenoh_config import ZenohOptions, open_session
from conftest import REPO, wait_for


def _from_other_address(port: int) -> zenoh.Session | None:
    """A client session to tcp/127.0.0.2:PORT (None when nothing accepts it there)."""
    try:
        return open_session(ZenohOptions(mode="client", connect=(f"tcp/127.0.0.2:{port}",),
                                         extra=(("connect/timeout_ms", "3000"),)))
    except zenoh.ZError:
        return None


def _run(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cinetransfer", *args], capture_output=True, text=True,
                          timeout=180, env={**os.environ, **(env or {})}, cwd=REPO)


def _peer_file(tmp_path, port: int):
    f = tmp_path / "open-peer.json5"
    f.write_text(json.dumps({"mode": "peer", "listen": {"endpoints": [f"tcp/0.0.0.0:{port}"]}}))
    return f


def test_the_file_would_expose_a_peer_to_another_address(tmp_path, port):
    """Control: Zenoh itself, given the file, listens where 127.0.0.2 reaches it (the old hole)."""
    with zenoh.open(zenoh.Config.from_file(str(_peer_file(tmp_path, port)))):
        s = wait_for(lambda: _from_other_address(port), timeout=30, what="a client from 127.0.0.2")
        s.close()


@pytest.mark.parametrize("way", ["flags", "--zenoh-config", "$CT_ZENOH_CONFIG"])
def test_a_node_refuses_a_listener_off_loopback_however_configured(tmp_path, port, way):
    f = _peer_file(tmp_path, port)
    args, env = {"flags": ([f"--listen=tcp/0.0.0.0:{port}"], {}),
                 "--zenoh-config": (["--zenoh-config", str(f)], {}),
                 "$CT_ZENOH_CONFIG": ([], {"CT_ZENOH_CONFIG": str(f)})}[way]
    r = _run("autopilot_bridge", *args, env=env)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "unauthenticated connections" in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert _from_other_address(port) is None


def test_a_node_refuses_peer_mode_off_loopback(tmp_path):
    f = tmp_path / "peer.json5"
    f.write_text(json.dumps({"mode": "peer", "connect": {"endpoints": ["tcp/192.0.2.10:7447"]}}))
    for args in (["--mode", "peer", "--connect", "tcp/192.0.2.10:7447"], ["--zenoh-config", str(f)]):
        r = _run("planner", *args)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "peer mode off loopback" in r.stderr, r.stderr


def test_a_router_refuses_tls_without_client_certificates():
    r = _run("router", "--listen", "tls/127.0.0.1:7999")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "client certificates" in r.stderr, r.stderr


@pytest.mark.parametrize("node", [
    "{name: planner, command: planner, zenoh: {mode: peer, listen: ['tcp/0.0.0.0:PORT']}}",
    "{name: planner, command: planner, args: [--listen, 'tcp/0.0.0.0:PORT']}",
    "{name: planner, command: planner, zenoh: {config: FILE}}",
    "{name: planner, command: planner, zenoh: {mode: peer, connect: ['tcp/192.0.2.10:7447']}}",
])
def test_deploy_refuses_a_config_that_would_expose_a_node(tmp_path, port, node):
    f = _peer_file(tmp_path, port)
    cfg = tmp_path / "exposed.yaml"
    cfg.write_text("nodes:\n  - " + node.replace("PORT", str(port)).replace("FILE", str(f)) + "\n")
    for cmd in ("up", "check"):
        r = _run("deploy", cmd, str(cfg), env={"CT_STATE_DIR": str(tmp_path / "state")})
        assert r.returncode == 2, r.stderr
        assert r.stderr.count("\n") == 1 and "nodes[0] (planner)" in r.stderr, r.stderr
    assert not (tmp_path / "state").exists()  # refused before a run folder or a process existed
    assert _from_other_address(port) is None
