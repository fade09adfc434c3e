"""The source's style, kept between transfers of the same clip: extracting it (source -> detector
-> smoother) is the largest single cost of a transfer, and a user iterating on a scene, subject or
planner setting extracts the very same clip again and again.

An entry is reused only when everything that decides the style is the same: the clip's content
(sha256 of its bytes, not its name or date), the frames used (`--max-frames`), the effective
settings of the source, detector and smoother nodes (as each node reports them), the code that
measures and smooths (a hash of the source files of shared/ and of every service but the
planner and the bridge), the
detector's model files, the versions of the numeric libraries, and the message schemas. Any
difference is another key, so stale data is never reused; an entry that cannot be read is
ignored (and replaced). A style whose detector ran a fallback backend (the box-first models
missing where it ran, cinetransfer/detector_backend.py) is never stored: the key holds the digest
of the model files found when the transfer started, not the backend that ran.

    CT_CACHE_DIR/styles/<key>/style.json    the style, as the extraction wrote it
    CT_CACHE_DIR/styles/<key>/key.json      what the key was made of (for a human reading it)
    CT_CACHE_DIR/versions/{code,models}.json the code's and the models' digests, with the stat
                                            signature of the files they were computed from

CT_CACHE_DIR defaults to $XDG_CACHE_HOME/cinetransfer (~/.cache/cinetransfer), shared/paths.py.
`transfer --no-cache` neither reads nor writes it; deleting the folder is always safe.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

from cinetransfer.shared.atomic import atomic_write
from cinetransfer.shared.paths import cache_dir

log = logging.getLogger("cinetransfer.transfer")

#: bump when the entry's layout changes
CACHE_FORMAT = 1
#: the nodes whose settings decide the style
STYLE_NODES = ("source", "detector", "smoother")
#: libraries whose numbers end up in the style (a new version may round differently)
LIBRARIES = ("numpy", "scipy", "opencv-python-headless", "ai-edge-litert", "mediapipe", "cvxpy", "osqp", "clarabel",
             "scs", "ecos")
_PACKAGE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class StyleKey:
    """The cache key of one extraction and what it was made of."""

    digest: str
    facts: dict[str, Any]

    @property
    def folder(self) -> Path:
        return cache_dir("styles", self.digest)


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


#: services whose code cannot change a style (they fly it); every other service counts, so that a
#: new measuring service is covered without being named here
FLIGHT_SERVICES = ("planner", "autopilot_bridge")


def _code_roots() -> list[Path]:
    """The installed source folders of the code that measures and smooths (the package layout maps
    cinetransfer.shared and cinetransfer.services onto shared/ and services/)."""
    from cinetransfer import services, shared

    top = Path(services.__file__).parent
    return [Path(shared.__file__).parent, *(p for p in sorted(top.iterdir())
                                           if p.is_dir() and p.name not in FLIGHT_SERVICES)]


def stat_signature(files: list[Path]) -> str:
    """What the file system says of `files` without reading them: path, size, modification time
    and inode. Any edit, copy, reinstall or checkout changes it (the test git's index relies on)."""
    h = hashlib.sha256()
    for p in files:
        st = p.stat()
        h.update(f"{p}\0{st.st_size}\0{st.st_mtime_ns}\0{st.st_ino}\n".encode())
    return h.hexdigest()


def remembered_digest(kind: str, files: list[Path], digest: Callable[[list[Path]], str]) -> str:
    """`digest(files)`, computed once per installed version of `files`: it is kept in
    CT_CACHE_DIR/versions/KIND.json with their `stat_signature` and read back while that holds.
    Hashing the code and the 43 MB of models took 0.3-0.7 s quiet and ~5 s on a loaded machine on
    every transfer; a stat of each file takes milliseconds."""
    sig = stat_signature(files)
    memo = cache_dir("versions", f"{kind}.json")
    try:
        kept = json.loads(memo.read_text())
        if kept.get("signature") == sig and isinstance(kept.get("digest"), str):
            return kept["digest"]
    except (OSError, ValueError, AttributeError):
        pass  # absent or unreadable: computed again and rewritten
    value = digest(files)
    try:
        memo.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(memo) as fh:
            json.dump({"signature": sig, "digest": value}, fh)
    except OSError as e:  # a cache that cannot be written costs time, never the transfer
        log.debug("style cache: could not keep the %s digest in %s (%s)", kind, memo, e)
    return value


def code_files() -> list[Path]:
    """The source files of shared/, every service but the flight's, and the extraction modules."""
    files = sorted(p for root in _code_roots() for p in root.rglob("*.py"))
    return files + [_PACKAGE / "extraction.py", _PACKAGE / "extract.py"]


def hash_code(files: list[Path]) -> str:
    """sha256 over the files by name and content (a file moved between folders counts as a change)."""
    h = hashlib.sha256()
    for p in files:
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


@lru_cache(maxsize=1)
def code_version() -> str:
    """The digest of `code_files()` (`hash_code`), remembered per installed version."""
    return remembered_digest("code", code_files(), hash_code)


def model_files() -> list[Path]:
    """The detector's installed model files ([] when none are installed)."""
    from cinetransfer.services.detector.box_models import models_dir

    root = models_dir()
    return sorted(p for p in root.iterdir() if p.is_file()) if root.is_dir() else []


def hash_models(files: list[Path]) -> str:
    """sha256 over the model files' names and contents ('' when there are none)."""
    if not files:
        return ""
    h = hashlib.sha256()
    for p in files:
        h.update(p.name.encode() + b"\0" + file_sha256(p).encode())
    return h.hexdigest()


@lru_cache(maxsize=1)
def models_version() -> str:
    """The digest of the detector's model files (`hash_models`), remembered per installed version."""
    return remembered_digest("models", model_files(), hash_models)


def library_versions() -> dict[str, str]:
    out = {}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = ""
    return out


def node_configs_local(node_args: dict[str, list[str]]) -> dict[str, str]:
    """The effective settings the transfer's own nodes run with (their flags `node_args`), computed
    by each node's own parser as the node computes them, as the JSON each node reports."""
    from cinetransfer.services.detector import service as detector
    from cinetransfer.services.detector.config import config_from_args as detector_config
    from cinetransfer.services.smoother import service as smoother
    from cinetransfer.services.source import service as source
    from cinetransfer.services.source.config import SourceConfig
    from cinetransfer.shared import nodeconfig

    def parsed(build, name):
        return build().parse_args(node_args.get(name, []))

    cfgs = {"source": nodeconfig.config_from_args(SourceConfig, parsed(source.build_parser, "source"), "source"),
            "detector": detector_config(parsed(detector.build_parser, "detector")),
            "smoother": smoother.node_config(parsed(smoother.build_parser, "smoother"))}
    return {name: config_json(cfg) for name, cfg in cfgs.items()}


def config_json(cfg: Any) -> str:
    """A config as a node reports it on its config key (shared/node.py)."""
    import dataclasses

    if dataclasses.is_dataclass(cfg):
        cfg = dataclasses.asdict(cfg)
    return json.dumps(cfg, default=str, sort_keys=True)


def node_configs_remote(session: Any, rig: str, timeout: float = 5.0) -> dict[str, str] | None:
    """The effective settings of a running deployment's style nodes, asked on their config keys
    (None when one does not answer: then nothing is cached)."""
    from cinetransfer.shared import keys

    out = {}
    for name in STYLE_NODES:
        replies = [r.ok.payload.to_string() for r in session.get(keys.config(rig, name), timeout=timeout)
                   if r.ok is not None]
        if len(replies) != 1:
            return None
        out[name] = replies[0]
    return out


def style_key(clip: Path, max_frames: int | None, node_configs: dict[str, str]) -> StyleKey:
    """The key of extracting `clip` (its first `max_frames` frames; None = all) with these settings."""
    from cinetransfer.shared import messages as M

    facts = {"format": CACHE_FORMAT, "clip_sha256": file_sha256(clip), "clip_name": clip.name,
             "max_frames": int(max_frames) if max_frames else None, "configs": dict(sorted(node_configs.items())),
             "code": code_version(), "models": models_version(), "libraries": library_versions(),
             "schemas": {"Measurement": M.Measurement.SCHEMA_VERSION, "Instructions": M.Instructions.SCHEMA_VERSION}}
    # the clip's name is for a human reading key.json: the same bytes under another name are the same clip
    keyed = {k: v for k, v in facts.items() if k != "clip_name"}
    digest = hashlib.sha256(json.dumps(keyed, sort_keys=True).encode()).hexdigest()[:40]
    return StyleKey(digest, facts)


def lookup(key: StyleKey) -> Path | None:
    """The cached style.json of `key`, or None (absent, or an entry that does not hold what its
    key says: ignored, and replaced by the next store)."""
    entry = key.folder
    style = entry / "style.json"
    try:
        stored = json.loads((entry / "key.json").read_text())
    except (OSError, ValueError):
        return None
    if stored.get("digest") != key.digest or not style.is_file():
        log.warning("style cache: entry %s is damaged; extracting again", entry)
        return None
    try:
        from cinetransfer.shared.instructions import load_style

        load_style(style)
    except Exception as e:  # noqa: BLE001 - any unreadable entry is a miss, never a failed run
        log.warning("style cache: %s cannot be read (%s); extracting again", style, e)
        return None
    return style


def entry_detector(style: Path) -> dict | None:
    """Which detector backend measured a cached style (`store`'s `detector`; None: not recorded)."""
    try:
        det = json.loads((style.parent / "key.json").read_text()).get("detector")
    except (OSError, ValueError, AttributeError):
        return None
    return det if isinstance(det, dict) else None


def store(key: StyleKey, style_path: Path, detector: dict | None = None) -> Path | None:
    """Keep `style_path` under `key` (written whole or not at all), with which detector backend
    measured it (`detector`, see cinetransfer/detector_backend.py; a style of a fallback backend
    is never stored: the caller's rule); None when the cache folder cannot be written (the
    transfer goes on: a cache is never a reason to fail)."""
    entry = key.folder
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key.digest}.", dir=entry.parent))
        shutil.copyfile(style_path, tmp / "style.json")
        kept = {"digest": key.digest, **key.facts, **({"detector": detector} if detector else {})}
        (tmp / "key.json").write_text(json.dumps(kept, indent=1) + "\n")
        if entry.exists():
            shutil.rmtree(entry, ignore_errors=True)
        os.replace(tmp, entry)
    except OSError as e:
        log.warning("style cache: could not store the style in %s (%s)", entry, e)
        shutil.rmtree(locals().get("tmp", entry.parent / ".none"), ignore_errors=True)
        return None
    return entry
