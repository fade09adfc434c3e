"""CPU seconds of the transfer's processes per stage of the job. On a shared machine a stage's
wall time says as much about the other users as about the stage; the CPU each process spent in it
says what the stage costs, and where.

The transfer's own deployment lists its processes' pids in OUTDIR/deploy/state.json; each is read
from /proc (Linux) at every stage boundary. A joined deployment (`--deployment`, `--connect`) has
no such list: then only the transfer's own process is counted.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

#: the name of the transfer's own process in the breakdown
SELF = "transfer"


def proc_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process `pid` (None when it is gone or /proc is absent)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    # after the command's ')': state is field 3, utime and stime are fields 14 and 15 (proc(5))
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def own_cpu_s() -> float:
    """This process's CPU seconds (all threads) and those of its children that have ended."""
    t = os.times()
    return time.process_time() + t.children_user + t.children_system


def deployment_pids(deploy_dir: Path | None) -> dict[str, int]:
    """name -> pid of the own deployment's processes ({} when there is none or it is unreadable)."""
    if deploy_dir is None:
        return {}
    try:
        procs = json.loads((deploy_dir / "state.json").read_text()).get("procs", {})
        return {name: int(p["pid"]) for name, p in procs.items() if p.get("pid")}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}


class StageCpu:
    """Samples CPU time at the job's stage boundaries: `mark(stage)` ends `stage`."""

    def __init__(self, deploy_dir: Path | None) -> None:
        self.deploy_dir = deploy_dir
        self.stages: dict[str, dict[str, float]] = {}
        self._last = self._sample()

    def _sample(self) -> dict[str, float]:
        out = {SELF: own_cpu_s()}
        for name, pid in deployment_pids(self.deploy_dir).items():
            cpu = proc_cpu_s(pid)
            if cpu is not None:
                out[f"{name}:{pid}"] = cpu
        return out

    def mark(self, stage: str) -> dict[str, float]:
        """CPU seconds per process since the last mark, booked to `stage` (a process that started
        in between counts from zero; one that ended in between is not seen)."""
        now = self._sample()
        spent = {key.split(":")[0]: round(cpu - self._last.get(key, 0.0), 2) for key, cpu in now.items()}
        self.stages[stage] = {k: v for k, v in spent.items() if v > 0}
        self._last = now
        return self.stages[stage]

    def totals(self) -> dict[str, float]:
        """CPU seconds per stage, all processes together."""
        return {stage: round(sum(per.values()), 2) for stage, per in self.stages.items()}


class StageClock:
    """The job's stages back to back: `end(name)` books the wall seconds since the last end into
    `timings[name]` and the CPU seconds per process into `cpu.stages[name]`."""

    def __init__(self, timings: dict[str, float], deploy_dir: Path | None) -> None:
        self.timings = timings
        self.cpu = StageCpu(deploy_dir)
        self._t = time.monotonic()

    def end(self, name: str) -> None:
        now = time.monotonic()
        self.timings[name] = now - self._t
        self.cpu.mark(name)
        self._t = now
