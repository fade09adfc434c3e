"""A package whose import fails part-way is forgotten whole and imported again: no submodule is left
holding the failed package object (what a concurrent import's deadlock error left behind for cvxpy)."""
import subprocess
import sys
import textwrap


def _package(root, name):
    pkg = root / name
    pkg.mkdir()
    # the first import runs its submodule, which keeps the package object, then fails before `late`
    (pkg / "__init__.py").write_text(textwrap.dedent(f"""
        import os
        from {name} import sub
        flag = os.path.join(os.path.dirname(__file__), "failed_once")
        if not os.path.exists(flag):
            open(flag, "w").close()
            raise RuntimeError("deadlock detected by _ModuleLock (as a concurrent import can)")
        late = 42
    """))
    (pkg / "sub.py").write_text(f"import {name} as parent\n\ndef reach():\n    return parent.late\n")


def _run(code, root):
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})
    return r.returncode, r.stdout + r.stderr


def test_a_plain_reimport_after_a_part_way_failure_leaves_a_stale_submodule(tmp_path):
    _package(tmp_path, "halfpkg")
    code = ("import importlib\n"
            "try:\n    importlib.import_module('halfpkg')\nexcept RuntimeError:\n    pass\n"
            "m = importlib.import_module('halfpkg')\n"
            "print(m.late, m.sub.parent is m)\n"
            "m.sub.reach()\n")
    rc, out = _run(code, tmp_path)
    # the premise of import_whole: the second import succeeds, its submodule reaches the dead package
    assert "42 False" in out and "AttributeError" in out and rc != 0, out


def test_import_whole_forgets_the_failed_package_and_imports_it_again(tmp_path):
    _package(tmp_path, "halfpkg")
    code = ("from cinetransfer.whole_import import import_whole\n"
            "m = import_whole('halfpkg')\n"
            "assert m.sub.parent is m and m.sub.reach() == 42\n"
            "print('whole')\n")
    rc, out = _run(code, tmp_path)
    assert rc == 0 and "whole" in out, out


def test_import_whole_raises_the_last_failure_with_the_package_forgotten(tmp_path):
    code = ("import sys\n"
            "from cinetransfer.whole_import import import_whole\n"
            "try:\n    import_whole('no_such_package_here.sub')\n"
            "except ImportError as e:\n    print('raised', e.name)\n"
            "assert not any(m.startswith('no_such_package_here') for m in sys.modules)\n")
    rc, out = _run(code, tmp_path)
    assert rc == 0 and "raised no_such_package_here" in out, out
