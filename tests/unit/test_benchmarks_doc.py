"""The benchmarks' harness (statistics, result head, atomic writes) and docs/benchmarks.md, which
is generated from benchmarks/results/*.json and must stay in step with them."""
import json
import math

import pytest

from conftest import REPO, load_benchmark


@pytest.fixture(scope="module")
def harness():
    return load_benchmark("harness")


def test_docs_benchmarks_md_is_generated_from_the_results(harness):
    committed = (REPO / "docs" / "benchmarks.md").read_text()
    assert committed == harness.render_docs(), \
        "docs/benchmarks.md is stale: run `.venv/bin/python benchmarks/harness.py docs`"
    for path in (REPO / "benchmarks" / "results").glob("*.json"):
        assert f"## {path.stem}\n" in committed


def test_stats_against_hand_computed_values(harness):
    s = harness.stats([4.0, 1.0, 3.0, 2.0, float("nan"), 10.0])  # NaN is left out
    assert s["n"] == 5 and s["mean"] == 4.0 and s["median"] == 3.0 and s["min"] == 1.0 and s["max"] == 10.0
    # numpy's linear percentile of [1, 2, 3, 4, 10]: rank 0.95 * 4 = 3.8 -> 4 + 0.8 * (10 - 4)
    assert s["p95"] == pytest.approx(8.8) and s["p99"] == pytest.approx(4 + 0.96 * 6)
    assert harness.stats([1.23456], digits=2)["median"] == 1.23
    empty = harness.stats([])
    assert empty["n"] == 0 and math.isnan(empty["median"])


def test_write_result_has_the_common_head_and_leaves_no_partial_file(harness, tmp_path):
    path = harness.write_result(tmp_path / "demo.json", {"rtt_ms": harness.stats([1, 2, 3]), "commit": "ignored"})
    doc = json.loads(path.read_text())
    assert list(doc)[:4] == ["benchmark", "commit", "recorded_utc", "machine"]
    assert doc["benchmark"] == "demo" and doc["rtt_ms"]["median"] == 2.0 and doc["commit"] != "ignored"
    assert doc["machine"]["cores"] >= 1 and len(doc["machine"]["load_avg"]) == 3
    with pytest.raises(TypeError):  # a figure that cannot be written: the old file stays, no temp file
        harness.write_result(path, {"bad": object.__new__(type("X", (), {"__str__": None}))})
    assert json.loads(path.read_text())["benchmark"] == "demo"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.json"]


def test_older_result_heads_are_read(harness):
    old = {"meta": {"commit": "abc", "cpus": 2, "load_avg_1min": 1.5, "time": "2026-11-23T01:00:00"}}
    assert harness.head_of(old) == {"commit": "abc", "recorded": "2026-11-23T01:00:00", "host": "", "cores": 2,
                                    "load_avg": 1.5}
    assert harness.head_of({"machine": "vm", "cpus": 2})["host"] == "vm"
