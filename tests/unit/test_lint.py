"""The tree passes ruff with the project's configuration (pyproject.toml [tool.ruff]: line length
120, pyflakes, pycodestyle, McCabe complexity <= 12). The README's test command runs this, so CI
enforces the lint; setup.sh installs ruff with the test extra, so a missing ruff is a failure."""
import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_ruff_passes_on_the_tree():
    assert importlib.util.find_spec("ruff") is not None, (
        "ruff is not installed in this environment: run ./setup.sh (it installs the `test` extra, "
        "which pins ruff) or `.venv/bin/pip install -e '.[test]'`")
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", str(ROOT)],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"ruff check found problems (exit {r.returncode}):\n{r.stdout}{r.stderr}"
