"""A node whose shutdown hangs after SIGINT writes every thread's stack to its log (shared/node.py)."""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

from cinetransfer.shared.zenoh_config import ZenohOptions

SCRIPT = textwrap.dedent("""
    import sys, time
    from cinetransfer.shared import node as N
    from cinetransfer.shared.zenoh_config import ZenohOptions
    N.SHUTDOWN_STACKS_S = float(sys.argv[2])
    opts = ZenohOptions(mode="peer", listen=("tcp/127.0.0.1:0",), connect=("tcp/127.0.0.1:%s" % sys.argv[1],))
    with N.Node("hangs", "ht", opts) as node:
        node.ready()
        print("ready", flush=True)
        while node.running:
            node.sleep(0.05)
        time.sleep(float(sys.argv[3]))  # a shutdown step that takes its time
    print("exited", flush=True)
""")


def run(port: int, stacks_after: float, hang: float) -> tuple[int, str, str]:
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, str(port), str(stacks_after), str(hang)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(0.2)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    return p.returncode, out, err


def test_a_hanging_shutdown_dumps_the_stacks_and_a_quick_one_does_not(port):
    from cinetransfer.shared.zenoh_config import open_session

    with open_session(ZenohOptions(mode="peer", listen=(f"tcp/127.0.0.1:{port}",))):
        rc, out, err = run(port, stacks_after=0.5, hang=2.0)
        # the dump names the hanging line (the script's sleep), then the node still exits normally
        assert rc == 0 and "exited" in out
        assert "most recent call first" in err and 'File "<string>"' in err
        rc, out, err = run(port, stacks_after=5.0, hang=0.0)
        assert rc == 0 and "exited" in out and "most recent call first" not in err
