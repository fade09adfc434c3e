"""What every benchmark shares: the machine it ran on, the commit it measured, statistics of a
sample, and its result file written whole or not at all; plus docs/benchmarks.md, generated
from those files.

    from harness import stats, write_result      # (benchmarks.harness when imported as a package)
    write_result("bridge", {"rtt_ms": stats(rtts_ms)})   # -> benchmarks/results/bridge.json

Every result file has the same head: {"benchmark", "commit", "recorded_utc", "machine": {"host",
"cores", "load_avg", "platform", "python"}}, then the benchmark's own figures.
`python benchmarks/harness.py docs` rewrites docs/benchmarks.md; a test keeps it in step.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from cinetransfer.shared.atomic import atomic_write

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
DOC = REPO / "docs" / "benchmarks.md"
HEAD = ("benchmark", "commit", "recorded_utc", "machine")


def commit() -> str:
    """The measured commit (full hash, '+dirty' with uncommitted changes); '' outside git."""
    try:
        sha = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return f"{sha}+dirty" if sha and dirty else sha


def machine() -> dict[str, Any]:
    """Cores and load matter most: the machine is shared, and a loaded one measures slower."""
    return {"host": platform.node(), "cores": os.cpu_count(), "load_avg": [round(x, 2) for x in os.getloadavg()],
            "platform": platform.platform(), "python": platform.python_version()}


def stats(values: Iterable[float], *, digits: int | None = None) -> dict[str, float]:
    """n, mean, median, p95, p99, min and max of the finite values (NaN for an empty sample)."""
    a = np.asarray(list(values), dtype=float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"n": 0, **{k: float("nan") for k in ("mean", "median", "p95", "p99", "min", "max")}}
    out = {"mean": a.mean(), "median": np.median(a), "p95": np.percentile(a, 95), "p99": np.percentile(a, 99),
           "min": a.min(), "max": a.max()}
    return {"n": int(a.size), **{k: round(float(v), digits) if digits is not None else float(v)
                                 for k, v in out.items()}}


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that is free right now (a benchmark's MAVLink endpoints)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def result_path(name_or_path: str | os.PathLike) -> Path:
    p = Path(name_or_path)
    return p if p.suffix == ".json" else RESULTS / f"{p.name}.json"


def write_result(name_or_path: str | os.PathLike, figures: dict[str, Any]) -> Path:
    """The figures under the common head, written atomically (a crash leaves the old file)."""
    path = result_path(name_or_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    head = {"benchmark": path.stem, "commit": commit(),
            "recorded_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), "machine": machine()}
    with atomic_write(path) as fh:
        json.dump({**head, **{k: v for k, v in figures.items() if k not in HEAD}}, fh, indent=1, default=_plain)
        fh.write("\n")
    return path


def _plain(v: Any) -> Any:
    if isinstance(v, (np.integer, np.floating, np.bool_)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


# -- docs/benchmarks.md ------------------------------------------------------------------------

#: a result's list of more than this many entries is summarised by its length
_MAX_LIST = 6
#: characters of a text value shown
_MAX_TEXT = 100
#: rows shown per result (the file has the rest)
_MAX_ROWS = 60


def _leaves(v: Any, prefix: str = "") -> Iterable[tuple[str, str]]:
    if isinstance(v, dict):
        for k, x in v.items():
            yield from _leaves(x, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(v, list) and v and all(not isinstance(x, (dict, list)) for x in v) and len(v) <= _MAX_LIST:
        yield prefix, ", ".join(_fmt(x) for x in v)
    elif isinstance(v, list) and len(v) <= _MAX_LIST:
        for i, x in enumerate(v):
            yield from _leaves(x, f"{prefix}[{i}]")
    elif isinstance(v, list):
        yield prefix, f"({len(v)} entries)"
    else:
        yield prefix, _fmt(v)


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return "NaN" if math.isnan(x) else f"{x:.4g}"
    s = str(x).replace("|", "\\|").replace("\n", " ")
    return s if len(s) <= _MAX_TEXT else s[:_MAX_TEXT] + " …"


def head_of(doc: dict[str, Any]) -> dict[str, Any]:
    """The common head of a result, read from the harness's form or from the older ones."""
    meta = doc.get("meta") if isinstance(doc.get("meta"), dict) else {}
    m = doc.get("machine")
    m = m if isinstance(m, dict) else ({"host": m} if m else {})
    cores = m.get("cores", m.get("cpus", m.get("cpu_count", doc.get("cpus", meta.get("cpus")))))
    load = m.get("load_avg", m.get("loadavg", doc.get("load_avg", meta.get("load_avg_1min", meta.get("load_avg")))))
    return {"commit": doc.get("commit") or m.get("commit") or meta.get("commit") or "",
            "recorded": doc.get("recorded_utc") or m.get("time") or meta.get("time") or "",
            "host": m.get("host", m.get("node", meta.get("machine", ""))), "cores": cores, "load_avg": load}


def _script_of(stem: str) -> str | None:
    """The script that writes results/<stem>.json: <stem>.py, else the longest <script>_ prefix
    (eval_detector_focus.py writes eval_detector_focus_gt.json)."""
    names = sorted((p.stem for p in (REPO / "benchmarks").glob("*.py")), key=len, reverse=True)
    return next((n for n in names if stem == n or stem.startswith(n + "_")), None)


def render_docs(results: Path = RESULTS) -> str:
    """docs/benchmarks.md: one section per results/*.json, its head and its figures."""
    out = ["# Benchmark results", "",
           "Generated from `benchmarks/results/*.json` by `python benchmarks/harness.py docs`; do not edit by",
           "hand (tests/unit/test_benchmarks_doc.py keeps it in step). Each benchmark script says what it",
           "measures and its goal; run it to refresh its file, then regenerate this page. The machine is",
           "shared: compare figures only with the load they were measured under.", ""]
    for path in sorted(results.glob("*.json")):
        doc = json.loads(path.read_text())
        h = head_of(doc)
        script = _script_of(path.stem)
        out += [f"## {path.stem}", ""]
        src = f"[`benchmarks/{script}.py`](../benchmarks/{script}.py)" if script else "no script of that name"
        load = ", ".join(_fmt(x) for x in h["load_avg"]) if isinstance(h["load_avg"], list) else _fmt(h["load_avg"])
        out += [f"From {src}, file [`{path.name}`](../benchmarks/results/{path.name}): "
                f"commit {'`' + h['commit'][:12] + '`' if h['commit'] else 'not recorded'}; "
                f"recorded {h['recorded'] or '(date not recorded)'}; {h['cores'] or '?'} cores; "
                f"load average {load if h['load_avg'] is not None else 'not recorded'}.", ""]
        rows = [(k, v) for k, v in _leaves({k: v for k, v in doc.items() if k not in (*HEAD, "meta", "cpus",
                                                                                     "load_avg", "python")})]
        out += ["| figure | value |", "|---|---|"]
        out += [f"| `{k}` | {v} |" for k, v in rows[:_MAX_ROWS]]
        if len(rows) > _MAX_ROWS:
            out.append(f"| … | {len(rows) - _MAX_ROWS} more in the file |")
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks/harness.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["docs"], help="docs: rewrite docs/benchmarks.md from the result files")
    ap.add_argument("-o", "--output", type=Path, default=DOC)
    args = ap.parse_args(argv)
    with atomic_write(args.output) as fh:
        fh.write(render_docs())
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
