"""The take assembler: slot assignment, gaps, tail, out-of-order and duplicate items."""
import pytest

from cinetransfer.recorder import Take, Window
from cinetransfer.take import MissingFramesError, TakeAssembler, require_complete


def slots(placed):
    return [(p.slot, p.item, p.repeat) for p in placed]


def test_exact_in_order_writes_each_slot_once():
    a = TakeAssembler(3, exact=True)
    out = []
    for k in range(3):
        out += a.add(k, f"f{k}")
    assert slots(out) == [(0, "f0", False), (1, "f1", False), (2, "f2", False)]
    s = a.finish()
    require_complete(s)
    assert s.written == 3 and s.repeated_slots == [] and s.complete


def test_exact_out_of_order_is_held_until_the_gap_fills():
    a = TakeAssembler(4, exact=True)
    assert a.add(1, "f1") == [] and a.add(3, "f3") == []
    assert slots(a.add(0, "f0")) == [(0, "f0", False), (1, "f1", False)]
    assert slots(a.add(2, "f2")) == [(2, "f2", False), (3, "f3", False)]
    assert a.done


def test_exact_duplicates_and_out_of_range_are_counted_and_ignored():
    a = TakeAssembler(2, exact=True)
    a.add(0, "a")
    assert a.add(0, "again") == []
    assert a.add(5, "x") == [] and a.add(-1, "y") == []
    a.add(1, "b")
    s = a.finish()
    assert (s.duplicates, s.out_of_range, s.written) == (1, 2, 2)


def test_exact_gap_fails_loudly_naming_the_slots():
    a = TakeAssembler(5, exact=True)
    for k in (0, 1, 3):
        a.add(k, k)
    s = a.finish()
    assert s.missing_slots == [2, 4] and s.written == 2
    with pytest.raises(MissingFramesError, match=r"2 of 5 frames .*slots 2, 4.*2 were recorded"):
        require_complete(s)


def test_exact_tail_missing_fails():
    a = TakeAssembler(3, exact=True)
    a.add(0, 0)
    a.add(1, 1)
    with pytest.raises(MissingFramesError, match="slots 2"):
        require_complete(a.finish())


def test_realtime_gap_repeats_previous_and_flags_it():
    a = TakeAssembler(5, exact=False)
    out = a.add(0, "f0") + a.add(3, "f3")
    assert slots(out) == [(0, "f0", False), (1, "f0", True), (2, "f0", True), (3, "f3", False)]
    assert a.add(2, "late") == []
    s = a.finish()
    assert s.repeated_slots == [1, 2] and s.late == 1 and s.missing_slots == [4] and not s.complete


def test_realtime_take_opening_between_frames_starts_on_the_first():
    a = TakeAssembler(3, exact=False)
    assert slots(a.add(1, "f1")) == [(0, "f1", True), (1, "f1", False)]


def test_window_slots_by_index_in_simulation_time_and_by_stamp_in_real_time():
    w = Window(exact=True, n_slots=10, fps=24.0, epoch_ns=1000, takes=(Take(first_index=48, slot0=0, n=10),))
    assert w.slot(999, 50) is None  # a frame of the timeline before the reset
    assert w.slot(5000, 48) == 0 and w.slot(5000, 57) == 9
    assert w.slot(5000, 47) is None and w.slot(5000, 58) is None  # the pre-roll, and after the take
    # two takes (two shots) with a settle phase between them: the edit joins them at the cut
    two = Window(exact=True, n_slots=10, fps=24.0, epoch_ns=0,
                 takes=(Take(first_index=24, slot0=0, n=4), Take(first_index=24 + 4 + 12, slot0=4, n=6)))
    assert [two.slot(1, i) for i in (23, 24, 27, 28, 39, 40, 45, 46)] == [None, 0, 3, None, None, 4, 9, None]
    r = Window(exact=False, n_slots=10, fps=25.0, t0_ns=10**9)
    assert r.slot(10**9 - 1, 0) is None
    assert r.slot(10**9 + 40_000_000, 0) == 1 and r.slot(10**9 + 59_000_000, 0) == 1
