"""The style cache: a style is reused only for the same clip content, frames, node settings, code
and models; entries are written whole and a damaged one is never used."""
import dataclasses
import json
import os
import shutil

import pytest

from cinetransfer import style_cache as C
from cinetransfer.job import EXTRACTION_ARGS
from cinetransfer.services.detector.config import DetectorConfig


@pytest.fixture
def clip(tmp_path, data):
    p = tmp_path / "clip.mp4"
    shutil.copyfile(data / "sam2_juggle_1280x720.mp4", p)
    return p


@pytest.fixture
def configs():
    return C.node_configs_local(EXTRACTION_ARGS)


def test_the_transfer_nodes_settings_are_the_ones_each_node_computes_from_its_flags(configs):
    # the detector node of the transfer runs `detector --input source`: the code defaults
    assert json.loads(configs["detector"]) == json.loads(C.config_json(DetectorConfig()))
    assert set(configs) == {"source", "detector", "smoother"}
    # a flag the node is given changes what it reports, and so the key
    other = C.node_configs_local({**EXTRACTION_ARGS, "detector": ["--input", "source", "--focus-width", "480"]})
    assert json.loads(other["detector"])["focus_work_width_px"] == 480


def test_the_key_follows_content_frames_settings_and_code(clip, configs, tmp_path, monkeypatch):
    k = C.style_key(clip, None, configs)
    assert C.style_key(clip, None, configs).digest == k.digest  # deterministic
    renamed = tmp_path / "renamed.mp4"
    shutil.copyfile(clip, renamed)
    assert C.style_key(renamed, None, configs).digest == k.digest  # the bytes count, not the name
    assert C.style_key(clip, 24, configs).digest != k.digest
    changed = dict(configs, detector=C.config_json(DetectorConfig(focus_work_width_px=480)))
    assert C.style_key(clip, None, changed).digest != k.digest
    with open(renamed, "r+b") as f:  # one byte of the clip changed
        f.seek(1000)
        b = f.read(1)
        f.seek(1000)
        f.write(bytes([b[0] ^ 1]))
    assert C.style_key(renamed, None, configs).digest != k.digest
    monkeypatch.setattr(C, "code_version", lambda: "other code")
    assert C.style_key(clip, None, configs).digest != k.digest


def test_store_then_lookup_and_damaged_entries_are_misses(clip, configs, tmp_path):
    key = C.style_key(clip, 24, configs)
    assert str(key.folder).startswith(os.environ["CT_CACHE_DIR"])  # its own per test (conftest)
    assert C.lookup(key) is None
    style = tmp_path / "style.json"
    from cinetransfer.report import synth
    from cinetransfer.shared.instructions import save_style

    save_style(style, synth.instructions(12))
    entry = C.store(key, style)
    assert entry == key.folder and C.lookup(key) == entry / "style.json"
    assert json.loads((entry / "key.json").read_text())["clip_sha256"] == C.file_sha256(clip)
    other = dataclasses.replace(key, digest="0" * 40)
    assert C.lookup(other) is None
    (entry / "style.json").write_text("{ not a style")  # damaged: never used
    assert C.lookup(key) is None
    C.store(key, style)  # ... and replaced by the next store
    assert C.lookup(key) == entry / "style.json"
    assert C.entry_detector(C.lookup(key)) is None  # stored without its detector: not known
    C.store(key, style, {"backend": "box_first", "fallback": None})
    assert C.entry_detector(C.lookup(key)) == {"backend": "box_first", "fallback": None}


def test_a_digest_is_computed_once_per_installed_version_of_its_files(tmp_path):
    files = [tmp_path / "a.py", tmp_path / "b.py"]
    files[0].write_text("x = 1\n")
    files[1].write_text("y = 2\n")
    calls = []

    def digest(fs):
        calls.append(list(fs))
        return C.hash_code(fs)

    first = C.remembered_digest("demo", files, digest)
    assert first == C.hash_code(files) and len(calls) == 1
    assert C.remembered_digest("demo", files, digest) == first and len(calls) == 1  # remembered, not read
    files[1].write_text("y = 3\n")  # an edit (same size): the new modification time gives it away
    os.utime(files[1], ns=(1, 1))
    second = C.remembered_digest("demo", files, digest)
    assert len(calls) == 2 and second == C.hash_code(files) != first
    (C.cache_dir("versions") / "demo.json").write_text("{not json")  # damaged memo: computed again
    assert C.remembered_digest("demo", files, digest) == second and len(calls) == 3


def test_the_code_and_model_digests_are_the_hashes_of_their_files():
    C.code_version.cache_clear()
    C.models_version.cache_clear()
    assert C.code_version() == C.hash_code(C.code_files())
    assert C.models_version() == C.hash_models(C.model_files())
    assert (C.cache_dir("versions") / "code.json").is_file()
