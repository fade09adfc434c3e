"""Streaming state of the smoother service (pure: no Zenoh, no clock).

Measurements arrive one by one, possibly out of order or twice. `StreamState` keeps the compact
features of every frame of the current sequence by frame index (a duplicate is counted and
ignored; a late frame is inserted where it belongs and is used by every later solve), and gives:

- `window()`: instructions for the newest `window_s` seconds, solved over the newest `history_s`
  seconds (final=False), always ending at the newest frame held. The service calls it when
  `window_due` says so: at most every `publish_period_s`, and at the first turn a period after
  the last window once a frame has come, so the newest frame is in the next window published,
  within that period plus one solve (the lag bound);
- `final()`: the whole-sequence result (final=True), at end of stream.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import SmootherInputError, feature_options, smooth_sequence
from cinetransfer.services.smoother.features import FrameFeatures, frame_features
from cinetransfer.shared.instructions import slice_instructions
from cinetransfer.shared import messages as M


def window_due(now_s: float, last_window_s: float, period_s: float, *, dirty: bool) -> bool:
    """Whether to solve and publish a window now: frames came since the last one (`dirty`) and a
    whole period has passed since it. A frame thus waits at most one period for its window, and
    an idle stream publishes nothing. `period_s` 0: windows off."""
    return period_s > 0 and dirty and now_s - last_window_s >= period_s


@dataclass
class StreamCounters:
    frames: int = 0
    duplicates: int = 0
    late: int = 0
    windows: int = 0
    finals: int = 0
    no_subject: int = 0


class StreamState:
    """Frames of the current sequence and the solves over them."""

    def __init__(self, cfg: SmootherConfig) -> None:
        self.cfg = cfg.validate()
        self.frames: dict[int, FrameFeatures] = {}
        self.source = ""
        self.newest = -1
        self.dirty = False  # frames arrived since the last window
        self.counters = StreamCounters()

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def fps(self) -> float:
        for f in self.frames.values():
            if math.isfinite(f.fps) and f.fps > 0:
                return float(f.fps)
        return float(self.cfg.default_fps)

    def is_new_source(self, m: M.Measurement) -> bool:
        """True when `m` belongs to another source than the frames held (the caller ends the
        current sequence first)."""
        return bool(self.frames) and m.source != self.source

    def add(self, m: M.Measurement) -> str:
        """Ingest one measurement: 'new', 'late' (older than the newest, inserted) or 'duplicate'."""
        i = int(m.frame_index)
        if i in self.frames:
            self.counters.duplicates += 1
            return "duplicate"
        self.frames[i] = frame_features(m, **feature_options(self.cfg))
        if not self.source:
            self.source = m.source
        self.counters.frames += 1
        self.dirty = True
        if i < self.newest:
            self.counters.late += 1
            return "late"
        self.newest = i
        return "new"

    def window(self) -> M.Instructions | None:
        """Instructions for the newest window (final=False); None when there is no subject yet."""
        if not self.frames:
            return None
        fps = self.fps
        hist = max(1, int(round(self.cfg.history_s * fps)))
        win = max(1, int(round(self.cfg.window_s * fps)))
        lo = self.newest - hist + 1
        feats = [f for i, f in self.frames.items() if i >= lo]
        self.dirty = False
        try:
            res = smooth_sequence(feats, self.cfg, final=False)
        except SmootherInputError:
            self.counters.no_subject += 1
            return None
        ins = res.instructions
        K = ins.image_targets.shape[0]
        self.counters.windows += 1
        return slice_instructions(ins, K - win, K, final=False)

    def final(self, source: M.SourceInfo | None = None) -> M.Instructions:
        """The whole-sequence result (final=True). Raises SmootherInputError without a subject."""
        res = smooth_sequence(list(self.frames.values()), self.cfg, source=source, final=True)
        self.counters.finals += 1
        return res.instructions

    def reset(self) -> None:
        self.frames.clear()
        self.source = ""
        self.newest = -1
        self.dirty = False
