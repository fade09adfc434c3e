"""The arithmetic of a take's faults, against hand-computed values."""
from cinetransfer import take_faults as T
from cinetransfer.report.build import _judge_by_faults


def test_counter_increase_adds_what_each_run_counted_across_restarts():
    assert T.counter_increase([2, 2, 5]) == 2 + 3  # the first report counts whole: callers subtract it
    assert T.counter_increase([4, 6, 1, 3]) == 4 + 2 + 1 + 2  # a restart at the third report
    assert T.counter_increase([]) == 0
    assert T.counter_increase([True, "x", 3]) == 3  # not numbers: read as 0


def test_restarts_are_uptime_drops():
    assert T.restarts([1.0, 2.0, 3.0]) == 0
    assert T.restarts([10.0, 11.0, 0.4, 1.4, 0.2]) == 2


def test_judge_marks_long_holds_and_lost_planners():
    calm = T.judge(T.TakeFaults(take=0, hold_share=0.1), duration_s=4.0)
    assert not calm.degraded and calm.hold_s == 0.4  # exactly the threshold is not over it
    held = T.judge(T.TakeFaults(take=0, hold_share=0.6), duration_s=3.0)
    assert held.degraded and held.hold_s == 1.8 and "60%" in held.reasons[0]
    lost = T.judge(T.TakeFaults(take=1, planner_restarts=1), duration_s=3.0)
    assert lost.degraded and lost.reasons == ["the planner restarted 1 time(s)"]
    # a long silence is wall time (a loaded machine): reported, never judged
    assert not T.judge(T.TakeFaults(take=1, planner_silence_s=30.0), duration_s=3.0).degraded


def test_a_degraded_take_reports_no_goal_as_met():
    goals = [{"id": "a", "status": "met"}, {"id": "b", "status": "missed"}, {"id": "c", "status": "n/a"}]
    summary = {"headline": {"goals_met": "1/2", "goals": {}}, "goals": goals,
               "shots": [{"goals_met": "1/2"}, {"goals_met": "2/2"}]}
    takes = [T.judge(T.TakeFaults(take=0, planner_restarts=1), 2.0), T.judge(T.TakeFaults(take=1), 2.0)]
    _judge_by_faults(summary, T.summary(takes))
    head = summary["headline"]
    assert head["goals_met"] == "0/2 (degraded take)"
    assert head["goals"] == {"a": "void (degraded take)", "b": "missed", "c": "n/a"}
    assert head["take"]["degraded"] and head["take"]["planner_restarts"] == 1
    assert [s["goals_met"] for s in summary["shots"]] == ["0/2 (degraded)", "2/2"]


def test_an_undisturbed_take_keeps_its_goals():
    summary = {"headline": {"goals_met": "1/1", "goals": {"a": "met"}}, "goals": [{"id": "a", "status": "met"}]}
    _judge_by_faults(summary, T.summary([T.judge(T.TakeFaults(take=0), 2.0)]))
    assert summary["headline"]["goals_met"] == "1/1" and summary["headline"]["take"]["degraded"] is False


def test_the_facts_read_once_give_the_report_the_recordings_vehicle_states(tmp_path):
    import numpy as np

    from cinetransfer.report.build import read_vehicle_states
    from cinetransfer.runlog import RunReader, RunWriter
    from cinetransfer.shared import codec, keys
    from cinetransfer.shared import messages as M

    # given a recording with vehicle states among other messages of the rig
    rig = "r"
    with RunWriter(tmp_path / "run.mcap", {}) as w:
        for k in range(5):
            w.write(keys.VEHICLE_STATE.key(rig), codec.encode(M.VehicleState(
                stamp_ns=k * 50_000_000, position_m=np.array([k, 0.5, -2.0]), holding=k % 2 == 0)))
            w.write(keys.health(rig, "planner"), codec.encode(M.Health(stamp_ns=k, node="planner", uptime_s=k)))
    # then the states the faults were read from are the ones the report would read itself, in order
    facts = T.read_facts(tmp_path / "run.mcap", rig)
    mine = [m for _, m in facts[keys.VEHICLE_STATE.key(rig)]]
    theirs = read_vehicle_states(RunReader(tmp_path / "run.mcap"))
    assert [s.stamp_ns for s in mine] == [s.stamp_ns for s in theirs] == [k * 50_000_000 for k in range(5)]
    assert all(np.array_equal(a.position_m, b.position_m) and a.holding == b.holding for a, b in zip(mine, theirs))
    assert len(facts[keys.health(rig, "planner")]) == 5
