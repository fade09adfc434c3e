"""Every import in the product, at module level or inside a function, stays in its layer.

shared/ is the bottom and imports only shared/; a service imports shared/ and itself, never
another service; deploy/ imports shared/ and itself; cinetransfer/ integrates and may import
anything. A string naming a project module (importlib.import_module("cinetransfer.…")) counts
as an import too.
"""
from __future__ import annotations

import ast
from pathlib import Path

from conftest import REPO

#: source folder -> import-name prefix (pyproject.toml's package-dir)
ROOTS = {"cinetransfer": "cinetransfer", "shared": "cinetransfer.shared", "services": "cinetransfer.services",
         "deploy": "cinetransfer.deploy"}


def module_name(rel: Path) -> str:
    parts = [ROOTS[rel.parts[0]], *rel.with_suffix("").parts[1:]]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> str | None:
    """'shared', 'deploy', 'services.<node>', 'cinetransfer', or None outside the project."""
    parts = module.split(".")
    if parts[0] != "cinetransfer":
        return None
    if len(parts) > 1 and parts[1] in ("shared", "deploy"):
        return parts[1]
    if len(parts) > 2 and parts[1] == "services":
        return f"services.{parts[2]}"
    return "cinetransfer"


def allowed(src: str, dst: str) -> bool:
    if src == "cinetransfer" or dst == "shared":
        return True
    if dst == "services":  # the empty services/__init__.py
        return src.startswith("services.")
    return src == dst


def imports_of(path: Path, module: str, known: set[str]) -> list[tuple[int, str]]:
    """(line, imported module) for every import statement anywhere in the file, relative ones
    resolved (`from pkg import mod` counts as mod), plus dotted strings naming a project module
(the bare word "cinetransfer" is a log name or `python -m cinetransfer`, a process, not an import)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(pkg + ([node.module] if node.module else []))
            subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known]
            found += [(node.lineno, m) for m in subs or [base]]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and "." in node.value \
                and node.value in known:
            found.append((node.lineno, node.value))
    return found


def crossings(repo: Path) -> tuple[list[str], int]:
    """(one line per layer crossing, how many project imports were checked)."""
    files = {p: module_name(p.relative_to(repo)) for root in ROOTS for p in sorted((repo / root).rglob("*.py"))}
    known = set(files.values())
    bad, checked = [], 0
    for path, module in files.items():
        src = layer(module)
        for line, target in imports_of(path, module, known):
            dst = layer(target)
            if dst is None:
                continue
            checked += 1
            if not allowed(src, dst):
                bad.append(f"{path.relative_to(repo)}:{line}: {src} imports {target} ({dst})")
    return bad, checked


def test_no_import_crosses_a_layer():
    bad, checked = crossings(REPO)
    assert checked > 300, f"only {checked} project imports found: is the walk broken?"
    assert not bad, "layer crossings:\n" + "\n".join(bad)


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


def test_the_walk_finds_crossings_inside_functions_relative_and_dynamic(tmp_path):
    repo = _tree(tmp_path, {
        "shared/__init__.py": "",
        "shared/low.py": "def f():\n    from cinetransfer.deploy import supervisor\n",
        "deploy/__init__.py": "",
        "deploy/supervisor.py": "from ..services.a import core\n",
        "services/__init__.py": "",
        "services/a/__init__.py": "",
        "services/a/core.py": "from . import helper\nfrom cinetransfer.shared import low\n",
        "services/a/helper.py": "",
        "services/b/__init__.py": "",
        "services/b/core.py": "import importlib\nM = importlib.import_module('cinetransfer.services.a.core')\n",
        "cinetransfer/__init__.py": "",
        "cinetransfer/cli.py": "from cinetransfer.services.b import core\nfrom cinetransfer.deploy import supervisor\n",
    })
    bad, checked = crossings(repo)
    assert checked == 7
    assert sorted(b.split(":")[0] for b in bad) == ["deploy/supervisor.py", "services/b/core.py", "shared/low.py"]


def test_layer_names():
    assert layer("cinetransfer.shared.codec") == "shared"
    assert layer("cinetransfer.services.planner.core") == "services.planner"
    assert layer("cinetransfer.report.build") == "cinetransfer"
    assert layer("numpy") is None
    assert allowed("services.planner", "shared") and not allowed("services.planner", "services.smoother")
    assert not allowed("shared", "cinetransfer") and not allowed("deploy", "cinetransfer")
