"""One take at a time per deployment, and `transfer --deployment local` as documented: real
`deploy up local`, two real transfers on it."""
import os
import subprocess
import sys
import time

import pytest

from cinetransfer.shared.zenoh_config import free_tcp_port


def _cli(*args: str, env: dict, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cinetransfer", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.mark.slow
def test_a_second_take_on_a_busy_deployment_is_refused_and_local_uses_its_rig(data, tmp_path):
    clip = str(data / "sam2_juggle_1280x720.mp4")
    env = {**os.environ, "CT_STATE_DIR": str(tmp_path / "state"), "CT_ROUTER_PORT": str(free_tcp_port())}
    style = tmp_path / "style.json"
    r = _cli("extract", clip, "--stop", "24", "-o", str(style), "--quiet", env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    r = _cli("deploy", "up", "local", env=env, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    first = None
    try:
        # given a take under way on the local deployment (rig left out: the deployment's own, rig0)
        console = open(tmp_path / "first.log", "w")
        first = subprocess.Popen([sys.executable, "-m", "cinetransfer", "transfer", clip, "--deployment", "local",
                                  "--style", str(style), "-o", str(tmp_path / "first"), "--preroll", "10",
                                  "--pace", "0.5", "--no-eval"],  # 20 s of pre-roll or more: the second comes in it
                                 stdout=console, stderr=subprocess.STDOUT, text=True, env=env)
        deadline = time.monotonic() + 300
        while "simulation time:" not in (tmp_path / "first.log").read_text():
            assert first.poll() is None and time.monotonic() < deadline, (tmp_path / "first.log").read_text()[-3000:]
            time.sleep(0.2)
        # when a second transfer joins the same deployment
        second = _cli("transfer", clip, "--deployment", "local", "--style", str(style),
                      "-o", str(tmp_path / "second"), "--no-eval", env=env)
        # then it is refused in one line, exit 1, leaving nothing behind, and it took nothing over
        assert first.poll() is None, "the second transfer ended the first one's take"
        assert second.returncode == 1, second.stderr[-3000:]
        last = second.stderr.strip().splitlines()[-1]
        assert last.startswith("cinetransfer transfer: rig rig0 is busy: another take holds it"), second.stderr
        assert "Traceback" not in second.stderr
        assert not (tmp_path / "second").exists()
        # and the first take ends as if alone, on the deployment's rig
        assert first.wait(600) == 0, (tmp_path / "first.log").read_text()[-3000:]
        console.close()
        import json

        meta = json.loads((tmp_path / "first" / "meta.json").read_text())
        assert meta["rig"] == "rig0" and meta["recorded_frames"] == 24
        # and once it has ended, the rig is free again
        again = _cli("transfer", clip, "--deployment", "local", "--style", str(style), "-o", str(tmp_path / "again"),
                     "--preroll", "0.5", "--no-eval", env=env, timeout=600)
        assert again.returncode == 0, again.stderr[-3000:]
    finally:
        if first is not None and first.poll() is None:
            first.kill()
            first.wait()
        _cli("deploy", "down", "local", env=env, timeout=300)
