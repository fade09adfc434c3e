"""The style of the source, extracted by the dataflow's own nodes: the source clip is played into
a running deployment (source -> detector -> smoother) and the smoother's final whole-sequence
instructions are the style."""
from __future__ import annotations

import logging
import queue
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from cinetransfer import detector_backend, style_cache
from cinetransfer.job import EXTRACTION_ARGS, TransferError, await_subscriber
from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.instructions import load_style, save_style
from cinetransfer.shared.node import Presence

log = logging.getLogger("cinetransfer.transfer")
EXTRACTION_NODES = ("source", "detector", "smoother")


class StyleTap:
    """Listens to the extraction half of the dataflow: measurements (progress), the ends of the
    source and detector streams, and the smoother's instructions (the callbacks only enqueue)."""

    def __init__(self, session, rig: str) -> None:
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self.measured = 0
        self.played: int | None = None  #: frames the detector measured, from its end-of-stream message
        self.backend = ""  #: the detector's backend, as its first measurement names it
        self.unavailable = ""  #: why the configured backend does not run, from the detector's health
        #: the extraction's nodes, watched: one that dies is named at once, not after the stall timeout
        self.nodes = {n: Presence(session, rig, n) for n in EXTRACTION_NODES}
        topics = (keys.INSTRUCTIONS, keys.SOURCE_END, keys.DETECTOR_END)
        self._subs = [session.declare_subscriber(t.key(rig), lambda s, t=t: self.q.put((t, s.payload.to_bytes())))
                      for t in topics]
        self._subs.append(session.declare_subscriber(keys.MEASUREMENT.key(rig), self._on_measurement))
        self._subs.append(session.declare_subscriber(keys.health(rig, "detector"), self._on_health))

    def _on_measurement(self, sample) -> None:
        self.measured += 1
        if not self.backend:  # one decode: every measurement of the node names the same backend
            try:
                self.backend = codec.decode(sample.payload.to_bytes(), M.Measurement).detector or "?"
            except codec.DecodeError:
                pass

    def _on_health(self, sample) -> None:
        try:
            counters = codec.decode(sample.payload.to_bytes(), M.Health).counters
        except codec.DecodeError:
            return
        self.unavailable = str(counters.get("backend_unavailable") or "")

    def detector(self) -> dict:
        """meta.json's record of the extraction's detector pass (detector_backend.facts)."""
        return detector_backend.facts(self.backend or "?", self.unavailable)

    def next(self, timeout: float):
        try:
            topic, payload = self.q.get(timeout=timeout)
        except queue.Empty:
            return None, None
        try:
            return topic, codec.decode(payload, topic.msg_type)
        except codec.DecodeError as e:
            log.warning("undecodable message on %s: %s", topic.key("RIG"), e)
            return topic, None

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        for p in self.nodes.values():
            p.undeclare()


def extract_on_dataflow(session, rig: str, src: Path, stop: int | None, stall_s: float
                        ) -> tuple[M.Instructions, dict]:
    """Play the source into the dataflow (source -> detector -> smoother) and return the smoother's
    whole-sequence instructions for it, and which backend the detector measured it with
    (detector_backend.facts). TransferError when a stage fails or stalls."""
    path = str(src.resolve())
    tap = StyleTap(session, rig)
    cmd = session.declare_publisher(keys.SOURCE_COMMAND.key(rig))
    try:
        if not await_subscriber(cmd, 30.0):
            raise TransferError("the source node does not listen for commands (see OUTDIR/deploy/source.log)")
        args = {"path": path, **({"stop": int(stop)} if stop else {})}
        cmd.put(codec.encode(M.Command(stamp_ns=M.now_ns(), action="play", args=args)))
        style = _await_final(tap, path, stall_s)
        # the final instructions hold one row per measured frame; the detector's end message, on
        # another key from another node, may be dispatched after them on a loaded machine
        played = tap.played if tap.played is not None else int(style.image_targets.shape[0])
        problem = shortfall(played, declared_frames(src), stop)
        if problem:
            raise TransferError(f"{src}: {problem}")
        _await_reason(tap, 3.0)
        return style, tap.detector()
    finally:
        cmd.undeclare()
        tap.close()


def _await_reason(tap: StyleTap, timeout_s: float) -> None:
    """A fallback backend's reason comes in the detector's health (about every second), which a
    short extraction may end before: wait that long for it (the warning is vaguer without)."""
    from cinetransfer.services.detector.box_models import FALLBACK_SUFFIX

    end = time.monotonic() + timeout_s
    while tap.backend.endswith(FALLBACK_SUFFIX) and not tap.unavailable and time.monotonic() < end:
        time.sleep(0.1)


def _await_final(tap: StyleTap, path: str, stall_s: float) -> M.Instructions:
    """The smoother's final instructions for `path`; TransferError when the source fails or
    nothing arrives for `stall_s` wall seconds."""
    with tqdm(desc=f"extract {Path(path).name} (dataflow)", unit="frame", disable=None) as bar:
        last = time.monotonic()
        while True:
            topic, msg = tap.next(0.2)
            bar.n = tap.measured
            bar.refresh()
            dead = [n for n, p in tap.nodes.items() if p.losses]
            if dead:
                raise TransferError(f"extraction: the {dead[0]} node died (its liveliness token went away); "
                                    f"see OUTDIR/deploy/{dead[0]}.log")
            if topic is None:
                if time.monotonic() - last > stall_s:
                    raise TransferError(f"extraction stalled: nothing from the source, detector or smoother for "
                                        f"{stall_s:.0f} s (see OUTDIR/deploy/*.log)")
                continue
            last = time.monotonic()
            final = _final_instructions(tap, topic, msg, path)
            if final is not None:
                return final


def _final_instructions(tap: StyleTap, topic, msg, path: str) -> M.Instructions | None:
    """One message of the extraction: the final instructions for `path`, or None (keep waiting);
    TransferError when the source node could not play it."""
    if msg is None or msg.source.path != path:
        return None
    if topic is keys.SOURCE_END and not msg.valid:
        raise TransferError(f"the source node could not play {path}: {msg.reason}")
    if topic is keys.DETECTOR_END:
        log.info("detector: %d frames measured (%s)", msg.frames, msg.reason)
        tap.played = int(msg.frames)
    if topic is keys.INSTRUCTIONS and msg.final:
        return msg
    return None


def declared_frames(src: Path) -> int | None:
    """The frame count the video's container declares (its header, nothing decoded), or None."""
    import cv2

    cap = cv2.VideoCapture(str(src))
    try:
        n = cap.get(cv2.CAP_PROP_FRAME_COUNT) if cap.isOpened() else 0
    finally:
        cap.release()
    return int(n) if n and n > 0 else None


def shortfall(played: int | None, declared: int | None, stop: int | None) -> str | None:
    """What is wrong when the source delivered clearly fewer frames than its container declares (a
    truncated or damaged file): a style of the first rows only would be a silent partial result.
    Containers estimate their count (a frame or two, 2 %): within that, nothing is said."""
    if played is None or declared is None:
        return None
    expected = min(declared, stop) if stop else declared
    if expected - played <= max(2, 0.02 * expected):
        return None
    return (f"the video is truncated or damaged: {played} of the {expected} frames its header declares could be "
            f"read; repair it, or pass --max-frames {played} to use what can be read")


@dataclass
class CachedStyle:
    """The style cache's key for this transfer (None: not cached) and its entry (None: a miss)."""

    key: style_cache.StyleKey | None = None
    path: Path | None = None


def cached_style(args, src: Path) -> CachedStyle:
    """Look the source up in the style cache before anything starts: on the transfer's own
    deployment the extraction nodes' settings are known from their flags (a joined deployment's
    are asked once it is up: `source_style`)."""
    if args.style or args.no_cache or args.deployment or getattr(args, "connect", None):
        return CachedStyle()
    key = style_cache.style_key(src, args.max_frames or None, style_cache.node_configs_local(EXTRACTION_ARGS))
    return CachedStyle(key, style_cache.lookup(key))


def source_style(args, src: Path, out: Path, session, cache: CachedStyle | None = None
                 ) -> tuple[Path, M.Instructions, str, dict | None]:
    """The source's style, written to OUTDIR/style.json, where it came from: 'file' (--style),
    'cache' (the same clip extracted with the same settings and code before) or 'extracted' (by the
    dataflow's own services; then kept in the cache unless its detector ran a fallback backend),
    and which backend measured it (detector_backend.facts; None: not known, a --style file)."""
    style_path = out / "style.json"
    if args.style:
        shutil.copyfile(args.style, style_path)
        return style_path, load_style(style_path), "file", None
    cache = cache or CachedStyle()
    if cache.key is None and not args.no_cache:  # a joined deployment: its nodes say how they are set
        configs = style_cache.node_configs_remote(session, args.rig)
        if configs is not None:
            cache.key = style_cache.style_key(src, args.max_frames or None, configs)
            cache.path = style_cache.lookup(cache.key)
    if cache.path is not None:
        shutil.copyfile(cache.path, style_path)
        log.info("style: reusing the measurements of %s from the cache (same clip content sha256 %s..., same "
                 "node settings, code and models): %s; --no-cache extracts again", src.name,
                 cache.key.facts["clip_sha256"][:12], cache.path.parent)
        return style_path, load_style(style_path), "cache", style_cache.entry_detector(cache.path)
    style, det = extract_on_dataflow(session, args.rig, src, args.max_frames or None, args.stall_timeout)
    fallback = detector_backend.is_fallback(det)
    # the style file says it too: it is read (and flown with --style) without this run's log
    save_style(style_path, style, warnings=[detector_backend.warning("measured", det, "")] if fallback else ())
    print(f"wrote {style_path}: {style.image_targets.shape[0]} frames at {style.fps:g} fps (extracted by the "
          f"source, detector and smoother nodes)")
    if fallback:  # the cache's key names the models' files, not the backend that ran: never reused
        log.warning("%s", detector_backend.warning(
            "source style", det, ", so this style differs from the box-first one; it is not kept in the style cache"))
    elif cache.key is not None and style_cache.store(cache.key, style_path, det) is not None:
        log.info("style: kept in the cache for the next transfer of this clip: %s", cache.key.folder)
    return style_path, load_style(style_path), "extracted", det
