"""CPU seconds per stage of the job: read from /proc for real processes, booked to the stage
that ends at each mark."""
import json
import os
import subprocess
import sys
import time

from cinetransfer import stage_cpu as S


def burn(seconds: float) -> None:
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


def test_a_process_cpu_is_read_from_proc_and_a_gone_one_is_none():
    child = subprocess.Popen([sys.executable, "-c", "import time\nt=time.process_time()\n"
                              "while time.process_time()-t<0.3: pass\nimport sys; sys.stdin.read()"],
                             stdin=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while (S.proc_cpu_s(child.pid) or 0.0) < 0.3 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert S.proc_cpu_s(child.pid) >= 0.3
    finally:
        child.communicate(b"")
    assert S.proc_cpu_s(child.pid) is None  # reaped: gone
    assert S.proc_cpu_s(os.getpid()) > 0


def test_each_stage_gets_the_cpu_spent_since_the_last_mark(tmp_path):
    (tmp_path / "state.json").write_text(json.dumps({"procs": {"me_too": {"pid": os.getpid()}, "gone": {}}}))
    timings = {}
    clock = S.StageClock(timings, tmp_path)
    burn(0.2)
    clock.end("first_s")
    clock.end("second_s")
    first, second = clock.cpu.stages["first_s"], clock.cpu.stages["second_s"]
    # this process is both the transfer and a listed node: both see the same 0.2 s
    assert 0.19 <= first["transfer"] < 5 and 0.19 <= first["me_too"] < 5
    assert second.get("transfer", 0.0) < 0.1 and set(timings) == {"first_s", "second_s"}
    assert timings["first_s"] >= 0.0 and clock.cpu.totals()["first_s"] >= 0.38


def test_no_deployment_counts_only_the_transfer(tmp_path):
    assert S.deployment_pids(None) == {} and S.deployment_pids(tmp_path) == {}
    (tmp_path / "state.json").write_text("{half")
    assert S.deployment_pids(tmp_path) == {}
    cpu = S.StageCpu(tmp_path)
    burn(0.05)
    assert set(cpu.mark("only_s")) == {"transfer"}
