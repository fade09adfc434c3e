"""The main job over a ground/onboard split, as the shipped configs join them: two routers on
loopback linked over mutual TLS, source/detector/smoother on the ground, planner/bridge onboard,
and `cinetransfer transfer --deployment ground` driving it as the operator."""
import json
import os
import subprocess
import sys

import pytest

from cinetransfer.shared.zenoh_config import free_tcp_port


def run(*args, env, timeout=300):
    return subprocess.run([sys.executable, "-m", "cinetransfer", *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


@pytest.mark.slow
def test_transfer_across_a_ground_onboard_split(data, tmp_path):
    secrets = tmp_path / "secrets"
    env = {**os.environ, "CT_RIG": "split", "CT_DRONE_ADDR": "127.0.0.1",
           "CT_ONBOARD_LISTEN": "127.0.0.1", "CT_ONBOARD_PORT": str(free_tcp_port()), "CT_SCENE": "lawn_juggler_25d"}
    # each host gets only its own folder of the deployment's credentials
    onboard_env = {**env, "CT_ROUTER_PORT": str(free_tcp_port()), "CT_SECRETS": str(secrets / "onboard")}
    ground_env = {**env, "CT_ROUTER_PORT": str(free_tcp_port()), "CT_SECRETS": str(secrets / "ground")}
    r = run("deploy", "certs", str(secrets), "--host", "127.0.0.1", env=env)
    assert r.returncode == 0, r.stderr
    up = []
    try:
        for name, e in (("onboard", onboard_env), ("ground", ground_env)):
            r = run("deploy", "up", name, "--run-dir", str(tmp_path / name), env=e)
            assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
            up.append((name, e))
        out = tmp_path / "run"
        r = run("transfer", str(data / "sam2_juggle_1280x720.mp4"), "--deployment", "ground", "--rig", "split",
                "-o", str(out), "--max-frames", "24", "--preroll", "1", "--no-eval", env=ground_env, timeout=600)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
    finally:
        logs = {name: run("deploy", "logs", name, "planner" if name == "onboard" else "smoother",
                          "--run-dir", str(tmp_path / name), env=e).stdout for name, e in up}
        for name, e in reversed(up):
            run("deploy", "down", name, "--run-dir", str(tmp_path / name), env=e)
    meta = json.loads((out / "meta.json").read_text())
    # the style came from the ground's nodes, the flight from the onboard ones, across the link
    assert meta["recorded_frames"] == 24 == meta["instruction_frames"] and meta["repeated_frames"] == 0
    assert meta["clock_mode"] == "lockstep"
    assert meta["health"]["planner"]["counters"]["solves"] > 0, logs
    assert meta["health"]["smoother"]["counters"]["finals"] >= 1, logs
    assert (out / "style.json").is_file() and (out / "output.mp4").stat().st_size > 10_000
