"""The smoother's streaming state and its publishing rule, without Zenoh or a clock."""
from __future__ import annotations

import pytest

from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.stream import StreamState, window_due
from cinetransfer.services.smoother.synthetic import walking_sequence


@pytest.mark.parametrize(("now", "last", "period", "dirty", "due"), [
    (10.25, 10.0, 0.25, True, True),    # a whole period since the last window, frames came
    (10.20, 10.0, 0.25, True, False),   # frames came, but the period is not over: they wait
    (10.00, 0.0, 0.25, False, False),   # nothing new: an idle stream publishes nothing
    (99.0, 0.0, 0.0, True, False),      # period 0: windows off
])
def test_window_due_by_hand(now, last, period, dirty, due):
    assert window_due(now, last, period, dirty=dirty) is due


def test_window_ends_at_the_newest_frame_held():
    state = StreamState(SmootherConfig(window_s=1.0, publish_period_s=0.2))
    ms = walking_sequence(30, flicker=True)
    for i in [*range(0, 24), 26, 25, 24]:  # 24 and 25 come late
        assert state.add(ms[i]) == ("late" if i in (24, 25) else "new")
    win = state.window()
    assert win.first_frame + win.image_targets.shape[0] - 1 == 26 and win.image_targets.shape[0] == 24
    assert win.valid and not win.final and not state.dirty
    # a duplicate changes nothing (no window due); the next new frame is in the next window
    assert state.add(ms[10]) == "duplicate" and not state.dirty
    assert state.add(ms[27]) == "new" and state.dirty
    assert state.window().first_frame + 23 == 27
    assert (state.counters.duplicates, state.counters.late, state.counters.windows) == (1, 2, 2)
