"""Packaging: namespaced imports in the wheel, the console script, generated docs in step."""
import subprocess
import sys
import zipfile

import pytest

from cinetransfer import docgen
from conftest import REPO


def test_message_reference_is_up_to_date():
    committed = (REPO / "docs" / "messages.md").read_text()
    assert committed == docgen.render(), \
        "docs/messages.md is stale: run `cinetransfer docs messages -o docs/messages.md`"


def test_console_script_lists_commands():
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    for cmd in ("detector", "smoother", "planner", "autopilot_bridge", "deploy", "monitor", "transfer"):
        assert f"  {cmd} " in r.stdout
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "nope"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "unknown command 'nope'" in r.stderr


@pytest.mark.slow
def test_wheel_is_namespaced_and_importable(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(REPO)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    (wheel,) = tmp_path.glob("cinetransfer-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    assert top <= {"cinetransfer", f"{wheel.name.split('-')[0]}-{wheel.name.split('-')[1]}.dist-info"}, top
    for must in ("cinetransfer/shared/codec.py", "cinetransfer/services/planner/__init__.py",
                 "cinetransfer/deploy/configs/local.yaml", "cinetransfer/cli.py"):
        assert must in names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import cinetransfer.shared.codec as c, "
            "cinetransfer.deploy.config as d; print(c.__file__); print(d.load_config('local').name)")
    r = subprocess.run([sys.executable, "-c", code, str(site)], capture_output=True, text=True, timeout=120,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0].startswith(str(site)) and r.stdout.splitlines()[1] == "local"


def test_readme_node_table_is_generated_from_the_dataflow():
    from cinetransfer import docgen

    text = (REPO / "README.md").read_text()
    assert text == docgen.readme_with_nodes(text), \
        "README's node table is stale: run `cinetransfer docs nodes --readme README.md`"
    assert "`source/frame`" in text  # the table is really there


def test_package_data_and_package_dirs_name_files_that_exist():
    import tomllib

    tool = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = tool["package-dir"]
    for pkg in tool["packages"]:
        top = next(k for k in sorted(dirs, key=len, reverse=True) if pkg == k or pkg.startswith(k + "."))
        folder = REPO / dirs[top] / pkg[len(top):].lstrip(".").replace(".", "/")
        assert (folder / "__init__.py").is_file(), f"package {pkg}: {folder}/__init__.py missing"
    for pkg, patterns in tool["package-data"].items():
        top = next(k for k in sorted(dirs, key=len, reverse=True) if pkg == k or pkg.startswith(k + "."))
        folder = REPO / dirs[top] / pkg[len(top):].lstrip(".").replace(".", "/")
        for pattern in patterns:
            assert list(folder.glob(pattern)), f"package-data {pkg}: {pattern} matches nothing in {folder}"
